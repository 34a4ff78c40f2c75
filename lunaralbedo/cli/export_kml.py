"""``lunaralbedo export-kml RESULTS_DIR``: Google Earth and GIS products of a solved result."""
from __future__ import annotations

import json

import click

from ._common import parallel_options, pyramid_kwargs, pyramid_options, reports_errors


@click.command("export-kml")
@click.argument("results_dir", type=click.Path(file_okay=False, path_type=str))
@pyramid_options
@parallel_options("all cores, as threads: the tasks are GDAL reads and writes")
@click.option("--sub4-resampling", type=click.Choice(["average", "nearest"]), default="average", show_default=True,
              help="albedo_sub4 resampling; nearest reproduces PhotometryTK's values.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@reports_errors
def command(results_dir, levels, stretch, value_range, tile_size, workers, scheduler, sub4_resampling, as_json):
    """Write RESULTS_DIR/albedo_sub4/, RESULTS_DIR/kml/doc.kml (multi-level superoverlay
    for Google Earth, Moon) and RESULTS_DIR/albedo_mosaic.tif (COG, plus error_mosaic.tif)."""
    from ..export import export_kml

    summary = export_kml(
        results_dir,
        **pyramid_kwargs(levels, stretch, value_range, tile_size),
        workers=workers,
        scheduler=scheduler,
        sub4_resampling=sub4_resampling,
    )
    if as_json:
        click.echo(json.dumps(summary, indent=2))
        return
    st = summary["stretch"]
    how = f"percentiles {st['percentiles'][0]:g},{st['percentiles'][1]:g}" if st["method"] == "percentile" else "fixed range"
    w, s, e, n = summary["bounds"]
    per_level = " + ".join(map(str, summary["tiles_per_level"])) + " = " if summary["levels"] > 1 else ""
    click.echo(f"levels     {summary['levels']} ({per_level}{summary['tiles']} PNG tiles of at most {summary['tile_size']} px)")
    click.echo(f"extent     lon {w:g}..{e:g}, lat {s:g}..{n:g}; finest level {summary['kml_size'][0]} x {summary['kml_size'][1]} px")
    click.echo(f"stretch    {st['lo']:.6g} -> 0, {st['hi']:.6g} -> 255 ({how}); written to {summary['stretch_file']}")
    click.echo(f"kml        {summary['doc_kml']}")
    click.echo(f"sub4       {summary['sub4_tiles']} tiles in {summary['results_dir']}/albedo_sub4")
    for key in ("albedo_mosaic", "error_mosaic"):
        m = summary[key]
        if m:
            click.echo(f"{key.split('_')[0]:<10} {m['path']} ({m['width']} x {m['height']}, overviews {m['overviews'] or 'none'})")
    click.echo(f"time       {summary['seconds']:.2f} s")
