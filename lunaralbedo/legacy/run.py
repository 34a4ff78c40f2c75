"""``solve_legacy``: the PhotometryTK 2012 pipeline as reconstruct.sh ran it.

Stages (reconstruct.sh numbering, MAX_NUM_ITER = N):

1. weights per image (``weight/<key>_weight.txt``);
2. DEM per tile (``DEM/``, albedo modes only);
3. sum of weights per tile (``weightsSum/``, USE_NORMALIZED_COST_FUN only);
4. initial exposure per image, ``TR_CONST / mean R`` (``exposure/``, albedo modes only);
5. initial albedo per tile (eq. 3);
then N times: exposure update (switched off, as reconstruct.sh had it), phase
coefficients per tile and combined (``phase/``, albedo modes only), albedo
update (eq. 6); finally, with COMPUTE_ERRORS, the error pass (eq. 7).  The last
pass drops tiles outside SIMULATION_BOX, multiplies the albedo by (1 + c2)
(with a reflectance model only: a plain mosaic is not scaled) and crops the
5-pixel padding.  Every intermediate albedo is stored as uint8, as
the legacy program stored and re-read it.
"""
from __future__ import annotations

import contextlib
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import SettingsError
from ..io.atomic import atomic_write_text, remove_stale_temporaries
from ..model import exposure_init
from ..settings import Settings
from . import outputs
from .catalog import gather, write_lists
from .dem import mean_dem_tile
from .exposure import reflectance_sum
from .reflect import surface
from .tilesolve import Params, solve_tile
from .vwgeo import boxes_overlap, legacy_box, unpadded_corners

#: Output entries of a legacy run (removed before a new run, like reconstruct.sh's ``rm -rf``).
LEGACY_ENTRIES = ("albedo", "albedo_sub4", "blank_tiles", "costFun", "DEM", "error", "exposure", "phase",
                  "weight", "weightsSum", "cache", "imagesList.txt", "tilesList.txt", "DEMTilesList.txt",
                  "albedoTilesList.txt", "summary.json",
                  # products export-kml derives from albedo/ (stale after a new run)
                  "kml", "albedo_mosaic.tif", "error_mosaic.tif")


#: Folders of the legacy tree, created even when a mode leaves them empty (e.g. DEM/ for a mosaic).
LEGACY_DIRS = ("albedo", "blank_tiles", "costFun", "DEM", "error", "exposure", "phase", "weight", "weightsSum")


def _kind(settings: Settings) -> tuple[int, bool]:
    """Effective reflectance kind and the legacy forceMosaic flag."""
    if settings.reflectance_type == 0 and settings.shadow_type in (2, 3):
        if settings.dem_dir is None or settings.sun_position_file is None or settings.spacecraft_position_file is None:
            raise SettingsError(f"{settings.source}: SHADOW_TYPE {settings.shadow_type} needs DEM_DIR and positions "
                                "(the legacy program computed a reflectance for the shadow test)")
        return settings.shadow_type - 1, True
    return settings.reflectance_type, False


def _check_out(settings: Settings, out: Path) -> None:
    """Refuse output folders inside an input folder, or containing one (a new run clears OUTDIR)."""
    for d in (settings.drg_dir, settings.dem_dir, settings.sun_position_file, settings.spacecraft_position_file):
        if d is None:
            continue
        d = Path(d).resolve()
        if out == d or d in out.parents:
            raise SettingsError(f"{out}: the output folder must not be inside the input folder {d}")
        if out in d.parents:
            raise SettingsError(f"{out}: the output folder must not contain the input {d} (a new run clears it)")


def _log(progress: bool, msg: str) -> None:
    if progress:
        print(f"[legacy] {msg}", file=sys.stderr, flush=True)


def solve_legacy(settings: Settings, out: Path, progress: bool = True) -> dict:
    """Run the legacy pipeline on ``settings`` and write the legacy output tree in ``out``.

    Returns a summary: tiles written, exposures, phase coefficients per
    iteration, cost function per tile and timings.
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    out = Path(out).resolve()
    _check_out(settings, out)
    kind, force_mosaic = _kind(settings)
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(out)
    for name in LEGACY_ENTRIES:
        p = out / name
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    for name in LEGACY_DIRS:  # the legacy program created its whole tree up front
        (out / name).mkdir(exist_ok=True)
    label = out.name

    t = time.perf_counter()
    inp = gather(settings, kind, out / "cache")
    write_lists(out, label, inp)
    tiles = inp.tiles
    _log(progress, f"{len(inp.images)} images overlap the box ({len(inp.skipped)} skipped), {len(tiles)} tiles")
    c1, c2 = float(np.float32(settings.phase_coeff_c1)), float(np.float32(settings.phase_coeff_c2))
    phase_history = [(c1, c2)]
    outputs.append_line(out / "phase" / "phaseCoeffs.txt", outputs.fmt_phase(c1, c2))
    for tile in tiles:
        outputs.write_blank(out, tile, inp.crs)
    for im in inp.images:  # stage 1
        outputs.write_weights(out, im)
    timings["setup"] = time.perf_counter() - t

    surfaces = {}
    inner = {tl.name: unpadded_corners(tl.geo, settings.tile_size) for tl in tiles}
    if kind != 0:  # stage 2
        t = time.perf_counter()
        for tl in tiles:
            dems = [(h, g) for h, g, c, nd in inp.dems if boxes_overlap(c, tl.corners)]
            nodata = next((nd for h, g, c, nd in inp.dems if boxes_overlap(c, tl.corners)), inp.dem_nodata)
            dem = mean_dem_tile(tl.geo, dems, nodata)
            outputs.write_dem(out, tl, dem, nodata, inp.crs)
            surfaces[tl.name] = surface(dem, tl.geo, nodata)
        timings["dem"] = time.perf_counter() - t

    def params() -> Params:
        return Params(kind, force_mosaic, settings.shadow_type, settings.shadow_thresh, settings.tr_const, c1, c2,
                      bool(settings.use_weights), bool(settings.use_normalized_cost_fun), settings.tile_size)

    wsum = {}
    if settings.use_normalized_cost_fun:  # stage 3
        t = time.perf_counter()
        for tl in tiles:
            res = solve_tile("weights_sum", tl.geo, inner[tl.name], inp.images, {}, params(), surfaces.get(tl.name))
            wsum[tl.name] = res.value
            outputs.write_weights_sum(out, tl, res.value, inp.crs)
        timings["weights_sum"] = time.perf_counter() - t

    exposures = {im.key: 1.0 for im in inp.images}
    if kind != 0:  # stage 4
        t = time.perf_counter()
        tile_surf = [(tl.geo, inner[tl.name], surfaces[tl.name]) for tl in tiles]
        for im in inp.images:
            r_sum, n = reflectance_sum(im, tile_surf, params())
            # No usable pixel: the legacy program divided by zero and printed nan; so do we, and the
            # image is then left out of the albedo passes (the legacy run would spread NaNs).
            t_seed = exposure_init.seed_exposure(settings.tr_const, r_sum, n, dtype=np.float32)
            exposures[im.key] = float(t_seed) if n else float("nan")
            outputs.append_line(out / "exposure" / f"{im.key}_exposure.txt", f"{exposures[im.key]:f}")
            exposures[im.key] = outputs.reread_float(exposures[im.key])
        unusable = [k for k, v in exposures.items() if not np.isfinite(v)]
        if unusable:
            _log(progress, f"no usable pixel (exposure undefined), left out: {', '.join(unusable)}")
        timings["exposure"] = time.perf_counter() - t

    n_iter = settings.max_num_iter
    passes = ["init"] + ["update"] * n_iter + (["errors"] if settings.compute_errors else [])
    box = legacy_box(settings.simulation_box)
    costs: dict[str, list[float]] = {tl.name: [] for tl in tiles}
    written: list[str] = []
    t = time.perf_counter()
    for ip, mode in enumerate(passes):
        last = ip == len(passes) - 1
        # The phase stages (7, 8) precede each albedo update.  Only the Lunar-Lambertian model has a
        # phase angle; the legacy code fed an unset angle to the update in Lambertian mode (NaN).
        if mode == "update" and kind == 2:
            c1, c2 = _phase_stage(out, tiles, inner, inp, exposures, params(), surfaces, wsum, costs, c1, c2)
            phase_history.append((c1, c2))
        for tl in tiles:
            albedo_path = out / "albedo" / f"{tl.name}.tif"
            if last and not boxes_overlap(tl.corners, box):
                with contextlib.suppress(FileNotFoundError):
                    albedo_path.unlink()
                continue
            albedo_in = None
            if mode != "init":
                albedo_in = outputs.read_albedo(albedo_path)
                if albedo_in is None:  # the legacy program returned 0 when the tile had no albedo file
                    costs[tl.name].append(0.0)
                    outputs.append_line(out / "costFun" / f"{tl.name}.txt", outputs.fmt_cost(0.0))
                    continue
            res = solve_tile(mode, tl.geo, inner[tl.name], inp.images, exposures, params(), surfaces.get(tl.name),
                             wsum.get(tl.name), albedo_in)
            if mode != "init":
                costs[tl.name].append(res.cost)
                outputs.append_line(out / "costFun" / f"{tl.name}.txt", outputs.fmt_cost(res.cost))
            if outputs.write_albedo(out, tl, res, last, c2, inp.crs, scale=kind != 0) and last:
                written.append(tl.name)
    timings["albedo"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_start
    summary = {
        "legacy": True,
        "out": str(out),
        "out_dir": str(out),
        "images": [im.key for im in inp.images],
        "images_skipped": inp.skipped,
        "grid_reference": str(inp.ref_path),
        "tiles": [tl.name for tl in tiles],
        "tiles_written": written,
        "exposures": {k: (v if np.isfinite(v) else None) for k, v in exposures.items()},
        "images_without_exposure": [k for k, v in exposures.items() if not np.isfinite(v)],
        "phase_coefficients": [list(pc) for pc in phase_history],
        "cost_function": costs,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    atomic_write_text(out / "summary.json", outputs.to_json(summary))
    _log(progress, f"wrote {len(written)} albedo tiles to {out / 'albedo'} in {timings['total']:.1f} s")
    return summary


def _phase_stage(out, tiles, inner, inp, exposures, p, surfaces, wsum, costs, c1, c2):
    """Stages 7 and 8: per-tile phase sums (and cost), then the combined update of c1, c2."""
    sums = np.zeros(4)
    for tl in tiles:
        albedo_in = outputs.read_albedo(out / "albedo" / f"{tl.name}.tif")
        if albedo_in is None:
            pcd, cost = (0.0, 0.0, 0.0, 0.0), 0.0
        else:
            res = solve_tile("phase", tl.geo, inner[tl.name], inp.images, exposures, p, surfaces[tl.name],
                             wsum.get(tl.name), albedo_in)
            pcd, cost = res.phase, res.cost
        pcd = outputs.write_phase_tile(out, tl, pcd)
        costs[tl.name].append(cost)
        outputs.append_line(out / "costFun" / f"{tl.name}.txt", outputs.fmt_cost(cost))
        sums += np.array(pcd)
    n1 = c1 + (sums[0] / sums[1] if sums[1] != 0 else 0.0)
    n2 = c2 + (sums[2] / sums[3] if sums[3] != 0 else 0.0)
    line = outputs.fmt_phase(float(np.float32(n1)), float(np.float32(n2)))
    outputs.append_line(out / "phase" / "phaseCoeffs.txt", line)
    a, b = (float(np.float32(v)) for v in line.split())  # re-read from the printed line, as the legacy runs did
    return a, b
