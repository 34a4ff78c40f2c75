"""``lunaralbedo export-web RESULTS_DIR``: the web map and run report of a solved result."""
from __future__ import annotations

import json

import click

from ._common import parallel_options, pyramid_kwargs, pyramid_options, reports_errors


@click.command("export-web")
@click.argument("results_dir", type=click.Path(file_okay=False, path_type=str))
@click.option("-o", "--out", default=None, type=click.Path(file_okay=False, path_type=str),
              help="Site folder (default: RESULTS_DIR/web; replaced).")
@pyramid_options
@parallel_options("all cores, as threads: the tasks are GDAL reads and PNG writes")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@reports_errors
def command(results_dir, out, levels, stretch, value_range, tile_size, workers, scheduler, as_json):
    """Write a static web site (map of albedo, error and DEM hillshade, image footprints,
    values on click, run report) that opens from file:// or any static server."""
    from ..web import export_web

    summary = export_web(
        results_dir,
        out=out,
        **pyramid_kwargs(levels, stretch, value_range, tile_size),
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
