"""``lunaralbedo photometry``: LROC/ISIS photometric corrections (lronacpho, lrowacphomap)."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import reports_errors


@click.command("photometry")
@click.argument("cube", type=click.Path(path_type=Path))
@click.option("--model", type=click.Choice(["lroc-empirical", "hapke-map"]), required=True,
              help="lroc-empirical: ISIS lronacpho; hapke-map: ISIS lrowacphomap (HapkeLROC + parameter map).")
@click.option("--params", required=True, type=click.Path(path_type=Path), help="Photometric parameter file (PVL).")
@click.option("--param-map", type=click.Path(path_type=Path), help="Hapke parameter cube (hapke-map).")
@click.option("--band", type=int, default=None, help="Correct only this band (1-based); default: every band.")
@click.option("--backplane", type=click.Path(path_type=Path),
              help="Angles from a backplane (ISIS phocube cube or `lunaralbedo backplanes` output) instead of the camera.")
@click.option("--dem", "dem", multiple=True, type=click.Path(path_type=Path),
              help="DEM for the camera geometry (local angles); default: the cube's ShapeModel when it resolves.")
@click.option("--ellipsoid", is_flag=True, help="Sphere geometry (ISIS usedem=no).")
@click.option("--isis-compat", is_flag=True,
              help="Reproduce ISIS lrowacphomap's numbers including its two band-matching defects (see docs).")
@click.option("--kernels", multiple=True, type=click.Path(path_type=Path), help="Extra kernel files or folders.")
@click.option("--isisdata", type=click.Path(path_type=Path), default=None, envvar="ISISDATA",
              help="ISIS data area for $base/$<mission> kernel paths (default: $ISISDATA).")
@click.option("-o", "--output", "out", required=True, type=click.Path(path_type=Path), help="GeoTIFF to write.")
@reports_errors
def command(cube, model, params, param_map, band, backplane, dem, ellipsoid, isis_compat, kernels, isisdata, out):
    """Write the photometrically corrected CUBE (float32, NaN where ISIS writes Null) and print statistics."""
    from ..errors import InputError
    from ..phocorr.run import correct
    from ..spice.kernels import expand_kernel_args

    if sum(map(bool, (dem, ellipsoid, backplane))) > 1:
        raise InputError("give only one of --backplane, --dem, --ellipsoid")
    results = correct(cube, out, model, params, band, param_map, backplane, list(dem) or None, ellipsoid,
                      isis_compat, kernels=expand_kernel_args(kernels), isisdata=isisdata)
    for r in results:
        click.echo(f"band {r.band} ({r.center:g} nm) via {r.geometry}: {r.count} valid pixels, mean {r.mean:.12g}, "
                   f"std {r.std:.12g}, min {r.minimum:.12g}, max {r.maximum:.12g}, sum {r.total:.12g}")
    click.echo(f"wrote {out}")
