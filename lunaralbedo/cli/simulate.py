"""``lunaralbedo simulate OUTDIR``: render a forward-model scene (solver DRGs, or ISIS cubes with kernels)."""
from __future__ import annotations

from pathlib import Path

import click

from ..camera.instruments import CHANDRAYAAN2_TMC2, CLEMENTINE_UVVIS, KAGUYA_MI, KAGUYA_TC
from ._common import reports_errors

#: ``--instrument`` values: the instrument names of ``camera.instruments`` with hyphens
INSTRUMENT_CHOICES = {n.replace("_", "-"): n for n in (KAGUYA_MI, KAGUYA_TC, CLEMENTINE_UVVIS, CHANDRAYAAN2_TMC2)}

#: Options of the DRG strip that the ISIS mission does not take.
_STRIP_ONLY = {"image_px": "--size", "res_deg": "--res", "exposure_spread": "--spread", "reflectance_type": "--reflectance",
               "tile_size": "--tile-size", "noise_dn": "--noise",
               "misregister_px": "--misregister", "fresh_craters": "--craters", "haze": "--haze",
               "outlier_fraction": "--outliers", "calibrated": "--calibrated", "dem_blur_px": "--dem-blur",
               "sun_azimuths": "--azimuths", "overlap": "--overlap"}


@click.command("simulate")
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["drg", "isis"]), default="drg", show_default=True,
              help="drg: a strip of DRGs in the input contract of `solve`; isis: Level-1 ISIS cubes, SPICE kernels "
                   "and a DEM in the input contract of `ingest` (the sample_data mission).")
@click.option("--instrument", type=click.Choice(list(INSTRUMENT_CHOICES)), default=None,
              help="Render the ISIS mission as this lunar camera sees it: its labels, IK and detector conventions "
                   "(kaguya-mi: 4-band NIR line scanner; kaguya-tc: TC1 NOMINAL-swath crop; clementine-uvvis: frames, "
                   "filters A/B; chandrayaan2-tmc2: 2x summed line scanner). Implies --format isis.")
@click.option("--images", "n_images", type=int, default=None,
              help="Number of images [drg: 6, isis: 5 frames, --instrument: 3 cubes].")
@click.option("--size", "image_px", type=int, default=120, show_default=True, help="Image size in pixels (square; drg).")
@click.option("--res", "res_deg", type=float, default=0.01, show_default=True, help="Pixel size in degrees (drg).")
@click.option("--spread", "exposure_spread", type=float, default=0.4, show_default=True, help="Exposures within 1 +- spread (drg).")
@click.option("--reflectance", "reflectance_type", type=click.IntRange(0, 3), default=2, show_default=True,
              help="REFLECTANCE_TYPE of the photometric model (drg; isis is Lunar-Lambertian).")
@click.option("--tile-size", type=float, default=1.0, show_default=True, help="TILE_SIZE of the written settings (degrees; drg).")
@click.option("--noise", "noise_dn", type=float, default=1.0, show_default=True, help="Gaussian noise, DN (drg).")
@click.option("--misregister", "misregister_px", type=float, default=0.0, show_default=True,
              help="Each DRG's georeference off by a random shift of up to this many pixels east and north (drg; "
                   "the truth in truth.json: images.KEY.offset_east_m/offset_north_m).")
@click.option("--haze", default=None, metavar="LO:HI",
              help="Additive haze per image, drawn uniformly in LO..HI DN (drg; e.g. 5:15).")
@click.option("--outliers", "outlier_fraction", type=float, default=0.0, show_default=True,
              help="Fraction of each image's pixels in hot spots (x1.6-3) and dark dropout rows (x0.3) (drg).")
@click.option("--calibrated", is_flag=True, help="Float32 I/F DRGs with every exposure 1, as from ISIS lronaccal (drg).")
@click.option("--craters", "fresh_craters", type=float, default=0.0, show_default=True,
              help="Rough terrain: small fresh bowl craters (0.6-2.4 km radius) per square degree (drg).")
@click.option("--dem-blur", "dem_blur_px", type=float, default=0.0, show_default=True,
              help="Give a blurred DEM: DEM/ holds the true heights blurred by a Gaussian of this sigma in pixels, "
                   "truth/dem.tif the true heights (drg; for REFINE_DEM).")
@click.option("--azimuths", "sun_azimuths", type=str, default="90", show_default=True,
              help="Sun azimuths in degrees clockwise from north, comma-separated, cycled over the images (drg).")
@click.option("--overlap", type=float, default=0.5, show_default=True,
              help="Fraction of an image shared with the next (drg; 2/3: each column seen by about 3 images).")
@click.option("--seed", type=int, default=None,
              help="Random seed [drg: 7, isis: 20240601, the sample_data mission; --instrument: 4601].")
@reports_errors
def command(out_dir, fmt, instrument, n_images, seed, **kwargs):
    """Render a scene from a known albedo, DEM, Sun/spacecraft geometry and exposures; the truth goes to OUT_DIR/truth/."""
    from ..errors import InputError

    ctx = click.get_current_context()
    if instrument is not None:
        if ctx.get_parameter_source("fmt") != click.core.ParameterSource.DEFAULT and fmt != "isis":
            raise InputError(f"--instrument renders ISIS cubes: not with --format {fmt}")
        fmt = "isis"
    if fmt == "isis":
        given = [flag for name, flag in _STRIP_ONLY.items() if ctx.get_parameter_source(name) != click.core.ParameterSource.DEFAULT]
        if given:
            what = "--instrument" if instrument else "--format isis"
            raise InputError(f"{', '.join(given)}: not an option of {what} (only --images and --seed)")
        from ..simulate import render_instrument_mission, render_mission

        if instrument is not None:
            truth = render_instrument_mission(out_dir, INSTRUMENT_CHOICES[instrument], seed=4601 if seed is None else seed,
                                              n_images=3 if n_images is None else n_images)
        else:
            truth = render_mission(out_dir, seed=20240601 if seed is None else seed,
                                   n_frames=5 if n_images is None else n_images)
        cubes = len({im["cube"] for im in truth["images"].values()})
        click.echo(f"rendered {cubes} ISIS cubes into {out_dir}/cubes/ (kernels: {out_dir}/kernels/, "
                   f"DEM: {out_dir}/dem/, truth: {out_dir}/truth/); next: lunaralbedo ingest")
        return
    from ..simulate import SceneSpec, render_scene

    haze = kwargs.pop("haze")
    if haze is not None:
        try:
            lo, hi = (float(x) for x in haze.split(":"))
        except ValueError:
            raise InputError(f"--haze must be LO:HI in DN (e.g. 5:15), got {haze!r}") from None
        kwargs["haze_dn"] = (lo, hi)

    try:
        kwargs["sun_azimuths"] = tuple(float(a) for a in kwargs["sun_azimuths"].split(","))
    except ValueError:
        raise InputError(f"--azimuths: comma-separated numbers (degrees), got {kwargs['sun_azimuths']!r}") from None
    truth = render_scene(out_dir, SceneSpec(n_images=6 if n_images is None else n_images, seed=7 if seed is None else seed,
                                            **kwargs))
    click.echo(f"rendered {len(truth['images'])} images into {out_dir}/ (settings: {out_dir}/settings.txt, truth: {out_dir}/truth/)")
