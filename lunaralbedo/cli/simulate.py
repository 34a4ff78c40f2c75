"""``lunaralbedo simulate OUTDIR``: render a forward-model scene in the solver's input contract."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import reports_errors


@click.command("simulate")
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--images", "n_images", type=int, default=6, show_default=True, help="Number of images in the strip.")
@click.option("--size", "image_px", type=int, default=120, show_default=True, help="Image size in pixels (square).")
@click.option("--res", "res_deg", type=float, default=0.01, show_default=True, help="Pixel size in degrees.")
@click.option("--spread", "exposure_spread", type=float, default=0.4, show_default=True, help="Exposures within 1 +- spread.")
@click.option("--reflectance", "reflectance_type", type=click.IntRange(0, 3), default=2, show_default=True)
@click.option("--tile-size", type=float, default=1.0, show_default=True, help="TILE_SIZE of the written settings (degrees).")
@click.option("--noise", "noise_dn", type=float, default=1.0, show_default=True, help="Gaussian noise, DN.")
@click.option("--seed", type=int, default=7, show_default=True)
@reports_errors
def command(out_dir, **kwargs):
    """Render a strip of overlapping images from a known albedo, DEM, geometry and exposures."""
    from ..simulate import SceneSpec, render_scene

    truth = render_scene(out_dir, SceneSpec(**kwargs))
    click.echo(f"rendered {len(truth['keys'])} images into {out_dir}/ (settings: {out_dir}/settings.txt, truth: {out_dir}/truth/)")
