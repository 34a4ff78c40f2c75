"""``lunaralbedo align``: ICP of a DEM onto LOLA points or a reference DEM (as ASP ``pc_align``)."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import reports_errors


@click.command("align")
@click.argument("source", type=click.Path(path_type=Path))
@click.option("--reference", required=True, type=click.Path(path_type=Path),
              help="CSV lon,lat,radius (degrees, degrees, km from the Moon's centre) or a reference DEM.")
@click.option("-o", "--output-prefix", "prefix", required=True, type=click.Path(path_type=Path),
              help="Writes PREFIX-transform.txt, -inverse-transform.txt, -beg_errors.csv, -end_errors.csv, "
                   "-trans_dem.tif, -report.json, -log.txt, -errors.png.")
@click.option("--max-displacement", type=float, default=float("inf"),
              help="Reference points farther than this (m) from the DEM at the start are outliers.")
@click.option("--method", type=click.Choice(["point-to-plane", "point-to-point"]), default="point-to-plane",
              show_default=True)
@click.option("--translation-only", is_flag=True, default=False, help="Solve for a translation only.")
@click.option("--outlier-ratio", type=float, default=0.75, show_default=True,
              help="Fraction of closest pairs kept in each iteration (as pc_align).")
@click.option("--dem-values", type=click.Choice(["auto", "radius", "height"]), default="auto", show_default=True,
              help="Whether DEM values are radius (m) or height above 1737.4 km.")
@reports_errors
def command(source, reference, prefix, max_displacement, method, translation_only, outlier_ratio, dem_values):
    """Rigid transform (Moon body-fixed metres) that moves the SOURCE DEM onto the reference."""
    import sys

    from ..nac.align_files import align_files

    def progress(iteration, distance):  # one line rewritten in place on a terminal
        click.echo(f"\r  ICP iteration {iteration}: mean distance {distance:,.3f} m", err=True, nl=False)

    tty = sys.stderr.isatty()
    align_files(source, reference, prefix, max_displacement, method, translation_only, outlier_ratio, dem_values,
                on_iteration=progress if tty else None)
    if tty:
        click.echo("", err=True)
    click.echo(Path(f"{prefix}-log.txt").read_text().rstrip())
