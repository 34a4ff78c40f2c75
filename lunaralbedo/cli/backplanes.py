"""``lunaralbedo backplanes``: per-pixel angles and ground point of a Level-1 cube (ISIS phocube names)."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import reports_errors


@click.command("backplanes")
@click.argument("cube", type=click.Path(path_type=Path))
@click.option("--band", type=int, default=1, show_default=True, help="Cube band (1-based) whose geometry is computed.")
@click.option("--dem", "dem", multiple=True, type=click.Path(path_type=Path),
              help="DEM file or folder (GeoTIFF or ISIS DEM cube); default: the cube's ShapeModel when it resolves.")
@click.option("--ellipsoid", is_flag=True, help="Intersect the 1737.4 km sphere (ISIS usedem=no / no DEM).")
@click.option("--kernels", multiple=True, type=click.Path(path_type=Path), help="Extra kernel files or folders.")
@click.option("--isisdata", type=click.Path(path_type=Path), default=None, envvar="ISISDATA",
              help="ISIS data area for $base/$<mission> kernel paths (default: $ISISDATA).")
@click.option("-o", "--output", "out", required=True, type=click.Path(path_type=Path), help="GeoTIFF to write.")
@reports_errors
def command(cube, band, dem, ellipsoid, kernels, isisdata, out):
    """Write 7 float32 bands: Phase, Emission, Incidence, Local Emission, Local Incidence Angle, Latitude, Longitude.

    Degrees; planetocentric latitude, longitude 0-360 east; NaN off the body.
    """
    import numpy as np

    from ..backplanes.run import write_backplanes
    from ..errors import InputError
    from ..spice.kernels import expand_kernel_args

    if dem and ellipsoid:
        raise InputError("give either --dem or --ellipsoid, not both")
    planes, shape = write_backplanes(cube, out, band, list(dem), ellipsoid, expand_kernel_args(kernels), isisdata)
    lat = planes["Latitude"]
    n = int(np.isfinite(lat).sum())
    click.echo(f"{cube}: band {band} on {shape.name}: {n} of {lat.size} pixels on the Moon; wrote {out}")
