"""``lunaralbedo export-web RESULTS_DIR``: the web map and run report of a solved result."""
from __future__ import annotations

import json

import click

from ..errors import InputError
from ._common import parallel_options, reports_errors
from .export_kml import _pair


@click.command("export-web")
@click.argument("results_dir", type=click.Path(file_okay=False, path_type=str))
@click.option("-o", "--out", default=None, type=click.Path(file_okay=False, path_type=str),
              help="Site folder (default: RESULTS_DIR/web; replaced).")
@click.option("--levels", type=int, default=None, help="Pyramid levels (default: as many as the data needs).")
@click.option("--stretch", "stretch", default=None, metavar="pLO,pHI", help="Albedo percentile stretch, e.g. p2,p98 (default).")
@click.option("--range", "value_range", default=None, metavar="LO,HI", help="Fixed albedo stretch: LO -> black, HI -> white.")
@click.option("--tile-size", type=int, default=256, show_default=True, help="PNG tile size in pixels.")
@parallel_options("all cores, as threads: the tasks are GDAL reads and PNG writes")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@reports_errors
def command(results_dir, out, levels, stretch, value_range, tile_size, workers, scheduler, as_json):
    """Write a static web site (map of albedo, error and DEM hillshade, image footprints,
    values on click, run report) that opens from file:// or any static server."""
    from ..web import export_web

    if stretch is not None and value_range is not None:
        raise InputError("give either --stretch or --range, not both")
    summary = export_web(
        results_dir,
        out=out,
        levels=levels,
        stretch=_pair(stretch, "--stretch") or (2.0, 98.0),
        value_range=_pair(value_range, "--range"),
        tile_size=tile_size,
        workers=workers,
        scheduler=scheduler,
    )
    if as_json:
        click.echo(json.dumps(summary, indent=2))
        return
    w, s, e, n = summary["bounds"]
    click.echo(f"layers     {', '.join(summary['layers'])}: {summary['levels']} levels, {summary['tiles_per_layer']} tiles each")
    click.echo(f"extent     lon {w:g}..{e:g}, lat {s:g}..{n:g}")
    click.echo(f"values     {summary['value_tiles']} tiles; footprints of {summary['footprints']} images")
    click.echo(f"time       {summary['seconds']:.2f} s")
    click.echo(f"open       {summary['index']}  (or: lunaralbedo view {summary['results_dir']})")
