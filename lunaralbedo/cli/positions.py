"""``lunaralbedo positions``: Sun and spacecraft positions of ISIS cubes or labels."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import reports_errors


@click.command("positions")
@click.argument("cubes", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--kernels", "kernels", multiple=True, type=click.Path(path_type=Path),
              help="Kernel file, folder or meta-kernel (repeatable); added to the label's Kernels group.")
@click.option("--isisdata", type=click.Path(path_type=Path), default=None, envvar="ISISDATA",
              help="ISIS data area for $base/$<mission> kernel paths (default: $ISISDATA).")
@click.option("--source", type=click.Choice(["auto", "table", "kernels"]), default="auto", show_default=True,
              help="auto: the cube's attached SPICE tables when present, else kernels.")
@click.option("--sun", "sun_file", required=True, type=click.Path(path_type=Path), help="Sun position file to write.")
@click.option("--spacecraft", "sc_file", required=True, type=click.Path(path_type=Path),
              help="Spacecraft position file to write.")
@reports_errors
def command(cubes, kernels, isisdata, source, sun_file, sc_file):
    """Write legacy position files (KEY x y z; km, Moon-centred body-fixed MOON_ME) for CUBES.

    Positions are at the centre pixel's time, as ISIS campt reports them; KEY is the
    file name up to its first '.', cut or padded ('_') to 11 characters, as ingest names
    its DRGs (a multi-band LRO WAC cube: one KEY per band, <8 characters>B01..).  Works on
    detached labels without pixels.
    """
    import numpy as np

    from ..ingest.positions import compute_positions, write_position_files

    results = compute_positions(list(cubes), kernels, isisdata, source)
    write_position_files(results, sun_file, sc_file)
    for r in results:
        alt = np.linalg.norm(r.spacecraft) - 1737.4
        click.echo(f"{r.key}  ET {r.et:.6f}  source {r.source:<7}  altitude {alt:9.3f} km  sun {np.linalg.norm(r.sun):.6g} km")
    click.echo(f"wrote {sun_file} and {sc_file} ({len(results)} images)")
