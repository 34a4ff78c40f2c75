"""``lunaralbedo ingest``: ISIS cubes -> DRGs, positions and settings for ``solve``."""
from __future__ import annotations

import sys
from pathlib import Path

import click

from ._common import INGEST_KERNELS, announce_compiling, parallel_options, reports_errors


@click.command("ingest")
@click.argument("cubes", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--dem", "dems", multiple=True, required=True, type=click.Path(path_type=Path),
              help="DEM GeoTIFF/ISIS cube or folder of them (repeatable).")
@click.option("-o", "--out", "workdir", required=True, type=click.Path(path_type=Path), help="Work folder to write.")
@click.option("--kernels", "kernels", multiple=True, type=click.Path(path_type=Path),
              help="Kernel file, folder or meta-kernel (repeatable); added to the labels' Kernels groups.")
@click.option("--isisdata", type=click.Path(path_type=Path), default=None, envvar="ISISDATA",
              help="ISIS data area for $base/$<mission> kernel paths (default: $ISISDATA).")
@click.option("--mpp", type=float, default=None,
              help="Output resolution in metres per pixel (default: the images' native resolution, as ISIS cam2map).")
@click.option("--match-dem", is_flag=True, default=False, help="Use the first DEM's grid instead of the native resolution.")
@click.option("--source", type=click.Choice(["auto", "table", "kernels"]), default="auto", show_default=True,
              help="Ephemeris source: attached SPICE tables when present (auto), or kernels.")
@click.option("--dem-values", type=click.Choice(["auto", "radius", "height"]), default="auto", show_default=True,
              help="Whether DEM values are radius (m, converted to height above 1737.4 km) or height.")
@click.option("--legacy-8bit", is_flag=True, default=False, help="Write 8-bit DRGs (stretch + alpha) as the legacy tools did.")
@click.option("--tile-size", type=float, default=None,
              help="TILE_SIZE (degrees) for settings.txt (default: tiles of ~2000 px at the output resolution).")
@parallel_options("1; cubes are processed in parallel")
@click.option("--dem-align", type=click.Path(path_type=Path), default=None,
              help="Align each DEM to these reference points (CSV lon,lat,radius km) or DEM first (see `align`).")
@click.option("--nac-mosaic", is_flag=True, default=False,
              help="Mosaic LE/RE cubes of one observation (NACL/NACR, same StartTime) into one ideal camera first.")
@click.option("--register", is_flag=True, default=False,
              help="Register the DRGs to the DEM (the solver's REGISTER_IMAGES estimate) and write them with their "
                   "georeference corrected; the shifts go to WORKDIR/image_offsets.csv.")
@click.option("--register-max-shift", type=float, default=None,
              help="Largest shift searched with --register, pixels [REGISTER_MAX_SHIFT's default, 5].")
@reports_errors
def command(cubes, dems, workdir, kernels, isisdata, mpp, match_dem, source, dem_values, legacy_8bit, tile_size,
            workers, scheduler, dem_align, nac_mosaic, register, register_max_shift):
    """Orthoproject CUBES onto the DEM and write WORKDIR/{DRG,DEM,meta,settings.txt}.

    DRGs are named <KEY>.tif, KEY = the cube name up to its first '.', cut or padded
    ('_') to 11 characters (duplicates get a 3-digit counter; a multi-band LRO WAC cube one
    DRG per band, <8 characters>B01..).  Positions are at the campt centre time, km,
    Moon-centred body-fixed (MOON_ME).  The output grid is the images' native resolution
    (as ISIS cam2map) and TILE_SIZE fits the solver's memory, unless --mpp / --tile-size.
    """
    from ..errors import InputError
    from ..ingest.run import check_grid_options, ingest

    check_grid_options(mpp, tile_size, match_dem)
    if register_max_shift is not None and not (register and 0 <= register_max_shift < float("inf")):
        raise InputError(f"--register-max-shift must be a number of pixels >= 0 given with --register, got {register_max_shift}")
    if dem_align is not None or nac_mosaic:
        from ..nac.api import prepare_ingest
        from ..spice.kernels import expand_kernel_args

        cubes, dems, notes = prepare_ingest(cubes, dems, workdir, dem_align, nac_mosaic, expand_kernel_args(kernels),
                                            isisdata, dem_values)
        if dem_align is not None:
            dem_values = "height"  # the aligned DEMs hold heights
        for n in notes:
            click.echo(n)
    compiling = announce_compiling(INGEST_KERNELS)
    report = ingest(list(cubes), list(dems), workdir, kernels, isisdata, mpp, source, dem_values,
                    legacy_8bit, tile_size, workers=workers or 1, scheduler=scheduler, progress=sys.stderr.isatty(),
                    match_dem=match_dem)
    for p in report.dem_radius_converted:
        click.echo(f"DEM {p}: values are radius, converted to height above 1737.4 km")
    for p in report.removed:
        click.echo(f"removed {p} (a DRG of an earlier run that this run did not produce)")
    for r in report.results:
        if r.skipped:
            click.echo(f"skipped {r.key} ({r.path}): {r.skipped}")
        else:
            w, s, e, n = r.box
            speed = "(compiling)" if compiling else f"{r.pixels_per_second:,.0f} px/s"
            compiling = False  # the first cube's time holds the compilation, not the others'
            click.echo(f"{r.key}  {r.kind:<12} {r.source:<7} lon {w:.4f}..{e:.4f}  lat {s:.4f}..{n:.4f}  "
                       f"{r.valid_pixels} px  {speed}")
    if register and report.done:
        from ..engine.register_workdir import register_workdir

        r = register_workdir(workdir, register_max_shift)
        for key, off, px in zip(r.keys, r.offsets_m, r.pixel_m):
            click.echo(f"{key}  registered: moved {off[0]:+.1f} m east, {off[1]:+.1f} m north ({off[0] / px:+.2f}, "
                       f"{off[1] / px:+.2f} px)")
    lo0, lo1, la0, la1 = report.box
    click.echo(f"resolution {report.mpp:.4g} m/px; TILE_SIZE {report.tile_size:g} degrees")
    click.echo(f"footprint union lon {lo0:.4f}..{lo1:.4f} lat {la0:.4f}..{la1:.4f}; "
               f"{len(report.done)} of {len(report.results)} cubes ingested; settings: {report.settings}")
