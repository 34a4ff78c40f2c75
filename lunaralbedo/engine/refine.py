"""``REFINE_DEM 1``: shape from shading as outer rounds around the albedo solve (docs/sfs.md).

Round ``r`` (``REFINE_DEM_ROUNDS`` of them):

1. the albedo solve (prepare, iterate, finalise: :func:`lunaralbedo.engine.solve._run`) with the
   heights ``sfs/dem_<r>/dem.tif``, into ``OUTDIR/sfs/round_<r>/``; its exposures and photometric
   parameters (global) are kept in ``sfs/round_<r>.json``;
2. per window (a tile, or a part of one of at most ``REFINE_DEM_WINDOW`` pixels a side), on the run's
   executor, the heights minimised with that albedo and those exposures held
   (:func:`.sfs_tile.refine_tile`) over the window and a margin; the windows blended with
   weights that fall to zero in the outer half of each margin, in tile order, into
   ``sfs/dem_<r+1>/dem.tif``.

The last solve, with the last heights, writes OUTDIR as a plain solve does (its ``DEM/`` holds the
heights the albedo was solved with), plus ``dem_change/`` (refined minus input) and ``dem_lit/``
(the number of images that see each pixel lit, outside any shadow: the observations that constrain
its heights in the last round).  All the heights live on one grid: the tiles' pixels over
SIMULATION_BOX with a border (:class:`.sfs_tile.HeightGrid`); ``sfs/dem_0`` is the input DEM
resampled onto it, holes filled from the surrounding heights (GDAL's fill, rasterio
``fillnodata``).  Each file is written atomically and reused by ``--resume``; ``sfs/`` is removed
once the run has succeeded.
"""
from __future__ import annotations

import dataclasses
import json
import shutil
import time
from pathlib import Path

import numpy as np
from rasterio.transform import Affine

from ..errors import InputError, ResumeError
from ..io.atomic import atomic_write_text
from ..io.geotiff import write_geotiff
from ..io.rasters import raster_info, read_dem_onto_grid
from ..model.cast_shadows import shadow_reach_km
from .sfs_tile import HeightGrid, fidelity_weight, pieces, refine_tile

SFS_DIR = "sfs"
PRODUCT_DIRS = ("dem_change", "dem_lit", "dem_input", "dem_sigma")
#: Rows of the input DEM resampled at a time onto the heights grid.
_ROWS = 512
_FILL_NEAR = 64  # pixels: GDAL's fill near the data
_FILL_COARSE = 16  # pixels a side of the blocks of the fill farther out


def height_grid(scene) -> HeightGrid:
    """The heights grid of ``scene``: its tiles' pixels, with a border of the margin plus the cast shadows' reach."""
    t0 = scene.tiles[0]
    a, e = t0.transform.a, t0.transform.e
    west = min(t.transform.c for t in scene.tiles)
    north = max(t.transform.f for t in scene.tiles)
    cols = int(round((max(t.transform.c + a * t.width for t in scene.tiles) - west) / a))
    rows = int(round((north - min(t.transform.f + e * t.height for t in scene.tiles)) / -e))
    s = scene.settings
    border = s.refine_dem_margin + 8
    if s.uses_cast_shadows:  # heights beyond the box may shade it: as far as a 2 km relief's shadow at the lowest Sun
        px_km = abs(a) * np.pi / 180 * 1737.4
        border += int(min(256, np.ceil(shadow_reach_km(2000.0, np.radians(10.0), 60.0) / px_km)))
    transform = Affine(a, 0.0, west - border * a, 0.0, e, north - border * e)
    return HeightGrid(transform, (rows + 2 * border, cols + 2 * border), border)


def write_given_dem(scene, grid: HeightGrid, path: Path) -> None:
    """The input DEM resampled (bilinear) onto ``grid``, holes filled from the surrounding heights; metres, float32."""
    h = np.empty(grid.shape, np.float32)
    for r in range(0, grid.shape[0], _ROWS):
        n = min(_ROWS, grid.shape[0] - r)
        h[r:r + n] = read_dem_onto_grid(scene.dems, grid.transform @ Affine.translation(0, r), (n, grid.shape[1]),
                                        scene.crs, scene.settings.no_dem_data_val)
    ok = np.isfinite(h)
    if not ok.any():
        raise InputError(f"{scene.settings.dem_dir}: the DEM has no heights over SIMULATION_BOX")
    if not ok.all():
        h = fill_holes(h, ok)
    write_geotiff(path, h.astype(np.float32), grid.transform, scene.crs)


def fill_holes(h: np.ndarray, ok: np.ndarray, near: int = _FILL_NEAR, coarse: int = _FILL_COARSE) -> np.ndarray:
    """``h`` (float32) with the pixels where ``ok`` is False filled from the surrounding heights.

    GDAL's inverse-distance fill (rasterio ``fillnodata``) up to ``near`` pixels from the data, and
    farther out the same fill made on ``coarse``-pixel block means and interpolated back (bilinear).
    GDAL's fill costs the holes' area times its search distance: the grid of a 0.5 m/px NAC crop,
    ringed by its cast-shadow border, took 82 s with one fill over the whole grid, 2 s in two.
    """
    from rasterio.fill import fillnodata
    from scipy import ndimage

    mask = ok.astype(np.uint8)
    out = fillnodata(np.where(ok, h, np.nan).astype(np.float32), mask=mask, max_search_distance=float(near),
                     smoothing_iterations=0)
    left = np.isnan(out)
    if left.any():
        rows, cols = -(-h.shape[0] // coarse), -(-h.shape[1] // coarse)
        pad = np.full((rows * coarse, cols * coarse), np.nan, np.float32)
        pad[:h.shape[0], :h.shape[1]] = np.where(ok, h, np.nan)
        blocks = pad.reshape(rows, coarse, cols, coarse)
        count = np.isfinite(blocks).sum(axis=(1, 3))
        means = np.where(count > 0, np.nansum(blocks, axis=(1, 3), dtype=np.float64) / np.maximum(count, 1), np.nan)
        means = fillnodata(means.astype(np.float32), mask=(count > 0).astype(np.uint8),
                           max_search_distance=float(max(rows, cols)), smoothing_iterations=0)
        # block centres sit at (k + 0.5) * coarse - 0.5 fine pixels: interpolate there, clamped at the edges
        r = np.clip((np.arange(h.shape[0]) + 0.5) / coarse - 0.5, 0, rows - 1)
        c = np.clip((np.arange(h.shape[1]) + 0.5) / coarse - 0.5, 0, cols - 1)
        rr, cc = np.nonzero(left)
        out[rr, cc] = ndimage.map_coordinates(means, [r[rr], c[cc]], order=1, mode="nearest")
    return out


def input_blur_px(scene) -> float | None:
    """``REFINE_DEM_INPUT_BLUR`` (pixels of the heights grid), or None for ``auto`` (:func:`estimate_input_blur`)."""
    v = scene.settings.refine_dem_input_blur
    return None if v in (None, "auto") else float(v)


#: Candidate input blurs (sigma, pixels) of the first stage of :func:`estimate_input_blur`: a factor 1.5 apart.
BLUR_CANDIDATES = (0.67, 1.0, 1.5, 2.25, 3.4, 5.1, 7.6)
#: Windows the estimate is made on, at most (spread evenly over the window order): its cost does not grow with the box.
BLUR_WINDOWS = 8
#: Level of the estimate (blocks of 2**level pixels).
BLUR_LEVEL = 1
#: Blurs below this many pixels of the estimate's level are told apart on the fine level (blocks of 2 px
#: could not: 1.75 px was estimated for a blur of 1.5 px, and the heights came out x0.55 instead of x0.37).
BLUR_FINE_BELOW = 1.25
#: An input held pixel by pixel (sigma 0, ASP's form) is taken when its misfit is within this fraction of the best
#: blur's: more freedom always lowers the misfit a little (it fits the noise), so a sharp input's best blur is the
#: smallest tried, by 1 % (on the strip: 0.67 px held, heights 7.6 m off the true DEM given; held per pixel 0.6 m).
SHARP_TOLERANCE = 0.05
#: When the misfits of all the candidates lie within this fraction of the smallest, the images cannot tell the input's
#: blurs apart and the input is held as given (sigma 0): PhotometryTK's Apollo scene (one 1267 m pixel per frame and
#: DEM point) has a 1 % spread over 0.67-7.6 px, and the smallest (3.13 px) moved the heights 431 m RMS where held as
#: given they moved 43 m and more of the albedo's correlation with the shaded relief went (0.351 -> 0.261,
#: docs/sfs.md); the strip's blurred DEM spreads them x11.
FLAT_TOLERANCE = 0.05
#: L-BFGS iterations of each candidate's height step (None: REFINE_DEM_MAX_ITER): 10 gave 3.12 px on the strip of
#: docs/sfs.md (30: 3.17 px; the true blur 3 px) at a third of the cost.
BLUR_MAX_ITER = 10


def _vertex(x: np.ndarray, y: np.ndarray) -> float:
    """The abscissa of the minimum of the parabola through the three points ``(x, y)``, within ``[x[0], x[2]]``."""
    a = np.polyfit(x, y, 2)
    if a[0] <= 0:
        return float(x[int(np.argmin(y))])
    return float(np.clip(-a[1] / (2 * a[0]), x[0], x[2]))


def estimate_input_blur(executor, n_windows: int, levels: int, max_iter: int, **kw) -> dict:
    """The input DEM's resolution (``REFINE_DEM_INPUT_BLUR auto``): the Gaussian sigma (pixels) at which the heights,
    held to the input smoothed by it, best explain the images.

    Held at a blur finer than the input's, the heights cannot take the relief the input lost; held at a coarser one,
    they must invent relief to match the input at that scale: either way the images' misfit (the shading term after
    the height step, :func:`.sfs_tile.blur_misfits`) grows.  Its sum over up to :data:`BLUR_WINDOWS` windows is taken
    at :data:`BLUR_CANDIDATES`, then at the two geometric midpoints around the best (on the fine level, with the best
    itself, when the best is below :data:`BLUR_FINE_BELOW` pixels of the coarse level); the estimate is the vertex of
    the parabola in ``log sigma`` through the best candidate and its two neighbours.  Where the candidates' misfits
    lie within :data:`FLAT_TOLERANCE` of each other the images say nothing of the input's resolution, and it is held
    as given (sigma 0, ``"flat": True``).  Returns ``{"sigma_px", "sigmas",
    "misfits"}``."""
    from .sfs_tile import blur_misfits

    level = min(BLUR_LEVEL, levels - 1)
    max_iter = BLUR_MAX_ITER or max_iter
    chosen = [int(i) for i in np.unique(np.linspace(0, n_windows - 1, min(n_windows, BLUR_WINDOWS)).round())]

    def total(sigmas, lv):
        rows = executor.map(blur_misfits, chosen, "input DEM's resolution", shared=("scene",), sigmas=list(sigmas),
                            level=lv, max_iter=max_iter, **kw)
        return [float(sum(r[i] for r in rows)) for i in range(len(sigmas))]  # window order: any worker count

    sig = list(BLUR_CANDIDATES)
    mis = total(sig, level)
    if max(mis) <= (1.0 + FLAT_TOLERANCE) * min(mis):  # the images cannot tell the blurs apart: the input as given
        return {"sigma_px": 0.0, "sigmas": [round(x, 3) for x in sig], "misfits": mis, "level": level,
                "windows": len(chosen), "flat": True}
    k = int(np.argmin(mis))
    if sig[k] < BLUR_FINE_BELOW * 2**level:  # too fine for the coarse level to tell apart: three candidates on the fine
        level, step = 0, 1.5**0.5
        sig = [sig[k] / step, sig[k], sig[k] * step]
        mis = total(sig, level)
        for _ in range(3):  # the fine minimum at an end: one more candidate beyond it
            j = int(np.argmin(mis))
            nxt = sig[0] / step if j == 0 else sig[-1] * step
            if 0 < j < len(sig) - 1 or not BLUR_CANDIDATES[0] / step <= nxt <= BLUR_CANDIDATES[-1]:
                break
            sig, mis = ([nxt] + sig, total([nxt], level) + mis) if j == 0 else (sig + [nxt], mis + total([nxt], level))
    else:
        extra = [x for x in (sig[k] / 1.5**0.5, sig[k] * 1.5**0.5) if BLUR_CANDIDATES[0] <= x <= BLUR_CANDIDATES[-1]]
        sig, mis = sig + extra, mis + total(extra, level)
    order = np.argsort(sig)
    sig, mis = [sig[i] for i in order], [mis[i] for i in order]
    k = min(max(int(np.argmin(mis)), 1), len(sig) - 2)
    best = float(np.exp(_vertex(np.log(sig[k - 1:k + 2]), np.asarray(mis[k - 1:k + 2]))))
    if level == 0 and int(np.argmin(mis)) == 0:  # the finest blur tried is the best: is the input sharp?
        sharp = total([0.0], level)[0]
        sig, mis = [0.0] + sig, [sharp] + mis
        if sharp <= (1.0 + SHARP_TOLERANCE) * min(mis[1:]):
            best = 0.0
    return {"sigma_px": round(best, 3), "sigmas": [round(x, 3) for x in sig], "misfits": mis, "level": level,
            "windows": len(chosen)}


def _with_dem(scene, dem: Path):
    """``scene`` with its DEM replaced by the one file ``dem`` (the next round's heights)."""
    return dataclasses.replace(scene, settings=dataclasses.replace(scene.settings, dem_dir=dem.parent),
                               dems=[raster_info(dem)])


def _read(path: Path) -> np.ndarray:
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read(1)


def _crs(path: Path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.crs


def blend(grid: HeightGrid, current: Path, parts: list[dict], tiles_dir: Path, out: Path) -> dict:
    """Mosaic the tiles' refined windows (weighted mean, tile order) over ``current``; write ``out`` and its
    lit counts ``lit.tif``; returns the change's RMS (metres) over the pixels the tiles reached."""
    import rasterio

    h = _read(current).astype(np.float64)
    num, den = np.zeros(grid.shape), np.zeros(grid.shape)
    snum, sden = np.zeros(grid.shape), np.zeros(grid.shape)
    lit = np.zeros(grid.shape, np.int16)
    for t, part in enumerate(parts):  # fixed tile order: the same bytes for any number of workers
        r0, r1, c0, c1 = part["window"]
        with np.load(tiles_dir / f"tile_{t:04d}.npz") as z:
            num[r0:r1, c0:c1] += z["w"] * z["h"]
            den[r0:r1, c0:c1] += z["w"]
            lit[r0:r1, c0:c1] = np.maximum(lit[r0:r1, c0:c1], z["lit"])
            ok = np.isfinite(z["sigma"]) & (z["w"] > 0)
            snum[r0:r1, c0:c1] += np.where(ok, z["w"] * z["sigma"], 0.0)
            sden[r0:r1, c0:c1] += np.where(ok, z["w"], 0.0)
    new = np.where(den > 0, num / np.where(den > 0, den, 1.0), h)
    with np.errstate(invalid="ignore", divide="ignore"):
        write_geotiff(out.parent / "sigma.tif", np.where(sden > 0, snum / sden, np.nan).astype(np.float32),
                      grid.transform, _crs(current), nodata=float("nan"))
    change = (new - h)[den > 0]
    with rasterio.open(current) as ds:
        crs = ds.crs
    write_geotiff(out.parent / "lit.tif", lit, grid.transform, crs)
    write_geotiff(out, new.astype(np.float32), grid.transform, crs)  # last: its presence means the round is done
    return {"change_rms_m": float(np.sqrt(np.mean(change**2))) if change.size else 0.0}


def write_products(scene, grid: HeightGrid, given: Path, final: Path, lit: Path, out: Path) -> dict:
    """``dem_change/`` (final minus input heights, metres), ``dem_lit/`` (lit images), ``dem_sigma/`` (each height's
    standard error, metres: :func:`lunaralbedo.model.sfs.height_uncertainty`) and ``dem_input/`` (the input heights
    on the tile grid, holes filled: the web report's hillshade before) tiles; the change's RMS, the median error."""
    g, f, n = _read(given).astype(np.float64), _read(final).astype(np.float64), _read(lit)
    sig = _read(lit.parent / "sigma.tif")
    sigmas = []
    sq, count = 0.0, 0
    for tile in scene.tiles:
        r, c = grid.offset(tile)
        core = (slice(r, r + tile.height), slice(c, c + tile.width))
        d = f[core] - g[core]
        sq += float(np.sum(d * d))
        count += d.size
        write_geotiff(out / "dem_change" / f"{tile.name}.tif", d.astype(np.float32), tile.transform, scene.crs,
                      nodata=float("nan"))
        write_geotiff(out / "dem_lit" / f"{tile.name}.tif", n[core].astype(np.int16), tile.transform, scene.crs)
        write_geotiff(out / "dem_sigma" / f"{tile.name}.tif", sig[core].astype(np.float32), tile.transform, scene.crs,
                      nodata=float("nan"))
        sigmas.append(sig[core][np.isfinite(sig[core])])
        write_geotiff(out / "dem_input" / f"{tile.name}.tif", g[core].astype(np.float32), tile.transform, scene.crs,
                      nodata=float("nan"))
    allsig = np.concatenate(sigmas) if sigmas else np.zeros(0)
    return {"dem_change_rms_m": float(np.sqrt(sq / max(count, 1))),
            "dem_sigma_median_m": float(np.median(allsig)) if allsig.size else None}


def refine_solve(scene, out: Path, run_solve, executor, resume: bool):
    """The rounds of the module docstring; ``run_solve(scene, folder, extra_report)`` is one albedo solve.
    Returns the last solve's result (OUTDIR written)."""
    s = scene.settings
    t0 = time.perf_counter()
    sfs = out / SFS_DIR
    stamp = sfs / "fingerprint.txt"  # the rounds' files belong to these settings and inputs only
    if stamp.exists() and stamp.read_text() != scene.fingerprint():
        raise ResumeError(f"{sfs}: the refined heights belong to other settings or inputs; run without --resume")
    if not resume:
        shutil.rmtree(sfs, ignore_errors=True)
    atomic_write_text(stamp, scene.fingerprint())
    grid = height_grid(scene)
    given = sfs / "dem_0" / "dem.tif"
    if not given.exists():
        write_given_dem(scene, grid, given)
    sigma, blur_fit = input_blur_px(scene), None
    current, rounds = given, []
    for r in range(s.refine_dem_rounds):
        scene_r = _with_dem(scene, current)
        state = sfs / f"round_{r}.json"
        if not state.exists():
            res = run_solve(scene_r, sfs / f"round_{r}", None)
            atomic_write_text(state, json.dumps({"exposure": res.exposure.tolist(), "haze": res.report.get("haze"),
                                                 "params": list(res.parameters.values())}))
        got = json.loads(state.read_text())
        nxt = sfs / f"dem_{r + 1}" / "dem.tif"
        fit = sfs / "input_blur.json"
        if sigma is None and fit.exists():
            blur_fit = json.loads(fit.read_text())
            sigma = blur_fit["sigma_px"]
        info = json.loads((nxt.parent / "round.json").read_text()) if nxt.exists() else None
        if info is None:
            albedo = [(p, raster_info(p).lonlat_bounds) for p in sorted((sfs / f"round_{r}" / "albedo").glob("*.tif"))]
            windows = pieces(scene_r, s.refine_dem_window)
            kw = dict(scene=scene_r, windows=windows, grid=grid, current=current, given=given, albedo=albedo,
                      exposure=np.asarray(got["exposure"]), params=got["params"],
                      haze=None if got.get("haze") is None else np.asarray(list(got["haze"].values())))
            if sigma is None:  # auto: estimated once, from the first round's albedo (kept for --resume)
                atomic_write_text(fit, json.dumps(estimate_input_blur(executor, len(windows), s.refine_dem_levels,
                                                                      s.refine_dem_max_iter, **kw)))
                blur_fit = json.loads(fit.read_text())
                sigma = blur_fit["sigma_px"]
            parts = executor.map(refine_tile, range(len(windows)), f"refine heights {r + 1}", shared=("scene",),
                                 sigma_px=sigma, out_dir=sfs / f"tiles_{r + 1}", **kw)
            info = {"tiles": [{k: p[k] for k in ("tile", "reports", "lit_mean")} for p in parts]}
            info.update(blend(grid, current, parts, sfs / f"tiles_{r + 1}", nxt))
            atomic_write_text(nxt.parent / "round.json", json.dumps(info))
        reps = [rep for t in info["tiles"] for rep in t["reports"]]
        work = sum(rep["observations"] * rep["evaluations"] for rep in reps)
        rounds.append({"round": r + 1, "change_rms_m": info["change_rms_m"],
                       "lbfgs_iterations": [sum(rep["iterations"] for rep in t["reports"]) for t in info["tiles"]],
                       "cpu_s": round(sum(rep["cpu_s"] for rep in reps), 3),
                       # the finest level's terms at the end, summed over the windows (in window order)
                       "cost_parts": {k: float(sum(rep["parts"][k] for rep in reps if rep["level"] == 0))
                                      for k in (reps[0]["parts"] if reps else {})},
                       # CPU time per observation per evaluation of the cost and its gradient (one core)
                       "ns_per_observation_evaluation": round(1e9 * sum(rep["cpu_s"] for rep in reps) / work, 1)
                       if work else None})
        current = nxt
    report = {"settings": s.to_dict(), "refine_dem": {"rounds": rounds, "input_blur_px": sigma, "input_blur_fit": blur_fit,
                                                      "fidelity": fidelity_weight(s),
                                                      "pixel_m": grid.pixel_m(),
                                                      # the rounds before the last solve (this process's share, if resumed)
                                                      "seconds": round(time.perf_counter() - t0, 3),
                             **write_products(scene, grid, given, current, current.parent / "lit.tif", out)}}
    result = run_solve(_with_dem(scene, current), out, report)
    shutil.rmtree(sfs, ignore_errors=True)
    return result
