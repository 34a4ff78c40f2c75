"""The tile tasks' shared state and cache layout, and two of the three kinds of tile task: iterate, finalise.

Each task is a plain function of (scene, tile index, small state) that a Dask worker
(or a plain loop) runs.  ``prepare`` (:mod:`.prepare`) reads the inputs once and caches the tile's
compact observations (:mod:`.observations`) inside OUTDIR; ``iterate`` computes one
iteration's partial sums from them in one fused pass (:mod:`.kernels`); ``finalise`` writes the tile's outputs.  Global couplings
(exposures, phase coefficients, Q) leave a task only as small float64 sums.

Cache layout of a tile (``OUTDIR/checkpoint/cache/<tile>/``): one folder per block of
rows, ``block_0000/`` ... (a :func:`~lunaralbedo.io.cache.save_stack` entry each: the
block's observations in chunk-major runs (:func:`.runs.chunk_runs`: ``chunks``,
``run_start``, ``run_pixel`` relative to the block, ``run_image``, ``index``, then ``image``,
``weight`` and the model's layers; with a phase-angle layer, ``alpha_range``: the range of the block's
angles, which the iterations take as it is when no dynamic shadow test changes the weights; with the spatial
test in the prepare step, ``rejected``: the observations it rejected, :mod:`.robust`) and ``tile_*``
per-pixel arrays over the columns ``cols`` of the entry's meta, those its images' windows span), the tile's outputs known once it is
prepared (``DEM.tif``, ``weightsSum.tif``: :data:`KNOWN_OUTPUTS`), then ``meta.json`` (written last: the
tile is complete) with the initialisation sums, ``blocks``, ``spatial`` (the spatial test's per-image used and
rejected counts, and whether a pixel has three images; None when the prepare step did not run it), the ``[b0, b1]`` rows of each
block, ``observations`` (how many the blocks hold), and ``layout`` (:data:`CACHE_LAYOUT`; a cache of another layout is prepared again).
Iterate and finalise read one block at a time (:func:`iterate_block` is one block's work),
so memory is bounded by a block.  The order is the iteration's, so a block that does not
fit the memory budget is read as it is, memory-mapped, and never reordered again.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from ..io.cache import MemoryCache, discard, load_meta, load_stack
from ..io.geotiff import GeoTiffRows
from ..io.rasters import count_finite
from ..model import shadows, updates
from ..parallel.progress import ROWS
from . import kernels, robust_store, runs
from .finalise_kernels import finalise_runs, lost_fraction_runs
from ..runtime import STACK_MEMORY_MB
from .scene import Scene


@dataclass
class SolveState:
    """The global unknowns besides the albedo: exposures and the model's fitted parameters."""

    exposure: np.ndarray  # (K,) per image
    params: np.ndarray  # (P,) fitted parameters of the photometric model (Lunar-Lambert: c1, c2)
    robust: int = 0  # generation of the robust weights (:mod:`.robust`; 0: the cached weights as they are)
    haze: np.ndarray | None = None  # (K,) additive haze per image, DRG units (FLOAT_HAZE 1; None: no haze)
    haze_joint: bool = True  # the pass sums the joint exposure-haze step's terms (False: the haze is held)
    exposures_known: bool = False  # EXPOSURE_MODE fixed: the exposures are kept, no pass sums eq. 4

    def haze_of(self, index) -> np.ndarray:
        """The haze of the images ``index`` (float32; zeros without haze)."""
        if self.haze is None:
            return np.zeros(len(index), np.float32)
        return np.asarray(self.haze, np.float64)[np.asarray(index)].astype(np.float32)


#: Version of the cache layout above (2: pixel-major observations; 3: the DEM and weight-sum
#: tiles as GeoTIFFs in the entry, no cached DEM; 4: chunk-major runs; 5: the spatial test's rejections);
#: ``meta.json`` records it.
CACHE_LAYOUT = 5
#: Folder of the cache root where finished tiles' blocks go to be deleted in the background.
TRASH = ".discarded"
#: GeoTIFF predictor of the error tiles: none (1).  Eq. 7's error has no smooth rows for the
#: floating-point predictor to use: without it the tiles are ~1 % smaller and 32 % faster to
#: write (15.8 against 23.3 ms per 1000 x 1000 tile, docs/performance-history.md section 0e).
ERROR_PREDICTOR = 1
#: GeoTIFF predictor of the weight-sum tiles: horizontal differencing (2).  Sums of blending
#: weights are smooth or constant, and the floating-point predictor gains nothing on them for
#: its cost (against it: the strip's 2000 x 2000 px tile 27 -> 15 ms, 0.13 -> 0.12 MB; the
#: 50-image scene's 1000 x 1000 px tile 21 -> 10 ms, 0.13 -> 0.14 MB; make bench item 10's
#: 4000 x 4000 px tile 176 -> 125 ms, 8.9 -> 5.8 MB).
WEIGHTS_SUM_PREDICTOR = 2
#: The tile outputs known once a tile is prepared (their output folders: the block's DEM and its blending
#: sums, assembled by :func:`.prepare._prepare_blocks`).  They are written into the tile's cache entry by the cache writer
#: (behind the computation of the next tiles in a one-process run) and moved into place by
#: finalise, ``weightsSum`` last.
KNOWN_OUTPUTS = ("DEM", "weightsSum")
#: GeoTIFF options (:func:`lunaralbedo.io.geotiff.geotiff_profile`) of each tile output.
OUTPUT_OPTIONS = {"albedo": {"nodata": float("nan")}, "error": {"nodata": float("nan"), "predictor": ERROR_PREDICTOR},
                  "DEM": {"nodata": float("nan")}, "weightsSum": {"predictor": WEIGHTS_SUM_PREDICTOR},
                  "outliers": {"nodata": float("nan")}}


def cache_dir(cache_root: Path, scene: Scene, t: int) -> Path:
    """The cache folder of tile ``t`` under ``cache_root``."""
    return Path(cache_root) / scene.tiles[t].name


def _split(arrays) -> tuple[dict, dict]:
    """Cached arrays as ``(observations, per-pixel arrays)`` (memory-mapped as loaded)."""
    obs = {k: v for k, v in arrays.items() if not k.startswith("tile_")}
    return obs, {k[5:]: v for k, v in arrays.items() if k.startswith("tile_")}


def _blocks(folder: Path, meta: dict):
    """``(b0, b1, observations, per-pixel arrays, their first column)`` of every cached block of a tile, in order (one
    in memory at a time; a block cached before the per-pixel arrays were cut to its windows' columns has them all)."""
    for i, (b0, b1) in enumerate(meta["blocks"]):
        arrays, block_meta = load_stack(folder / f"block_{i:04d}")
        yield (b0, b1, *_split(arrays), block_meta.get("cols", [0])[0])


# --------------------------------------------------------------------------- iterate
def tile_model(scene: Scene, obs, state: SolveState):
    """The model of a block's observations (chunk-major runs) for the given exposures and model parameters.

    Returns ``(R, w, T)``: R (float32 per observation), the weights with the dynamic shadow
    mask (eq. 1), and the exposures of the block's local images (float32; ``obs["run_image"]``
    numbers them), which :func:`.finalise_kernels.finalise_runs` takes.
    """
    return block_model(scene.settings, scene.model, obs, state)


def block_model(s, model, obs, state: SolveState):
    """:func:`tile_model` with the run's settings ``s`` and bound photometric ``model``."""
    texp = state.exposure[obs["index"]].astype(np.float32)
    r = np.asarray(model.reflectance_from(obs, state.params), dtype=np.float32)
    w = obs["weight"]
    if s.shadow_type in (shadows.LAMBERT_RATIO, shadows.LUNAR_LAMBERT_RATIO) and model.needs_geometry:
        rr = obs["cos_i"] if (s.shadow_type == shadows.LAMBERT_RATIO and "cos_i" in obs) else r
        t_obs = texp[runs.observation_images(obs)]
        w = np.where(shadows.dynamic_lit(obs["image"], rr, t_obs, s.shadow_thresh), w, 0.0).astype(np.float32)
    return r, w, texp


#: The observations of the blocks this process iterates stay in memory within this
#: budget (bytes; the run's ``Runtime.stack_memory_mb``, default 512 MiB, set by each iterate task); blocks
#: beyond it are read from the memory-mapped cache every iteration (no reordering: the cache
#: holds the iteration's order).
STACKS = MemoryCache(int(STACK_MEMORY_MB * 2**20))


def pixel_stack(folder: Path, cache_root: Path, scene: Scene | None = None) -> dict:
    """The observations (chunk-major runs) of one cached block, from :data:`STACKS` (memory-mapped if over its budget).

    ``scene``: its run's ``Runtime.stack_memory_mb`` becomes the budget (a process serves one run at a time);
    every pass that reads blocks passes it, whichever runs first."""
    if scene is not None:
        STACKS.budget = scene.runtime.stack_bytes
    return STACKS.get(folder, lambda arrays, meta: _split(arrays)[0], group=cache_root)


def effective_weights(block: Path, arrays: dict, gen: int) -> np.ndarray:
    """The weights of a cached block's observations in generation ``gen`` of the robust weights
    (:mod:`.robust`; 0: the cached ones), memory-mapped like a block over :data:`STACKS`' budget
    (held by no cache of this process: memory stays bounded by the blocks; generation 1 of a block the prepare step
    tested, its ``rejected`` observations)."""
    if gen <= 0:
        return arrays["weight"]
    if gen == 1 and "rejected" in arrays:
        return robust_store.rejected(arrays["weight"], arrays["rejected"])
    return robust_store.load(block, arrays["weight"], gen)


def hazed(arrays: dict, state: "SolveState") -> dict:
    """A block's observations with each image's haze taken off their values (FLOAT_HAZE 1; as they are without)."""
    if state.haze is None:
        return arrays
    value = np.asarray(arrays["image"], np.float32) - state.haze_of(arrays["index"])[runs.observation_images(arrays)]
    return {**arrays, "image": value}


def _weighted(block: Path, arrays: dict, state: "SolveState") -> dict:
    """A block's observations with the state's effective weights (``cached_weight``: the weights they replace).

    A block held by :data:`STACKS` keeps the mapping of its weights of the current generation with it: mapping the
    file again in every pass cost ~1 ns per observation and pass in page faults."""
    if not state.robust:
        return arrays
    held = arrays.get("robust_weights")
    if held is not None and held[0] == state.robust:
        w = held[1]
    else:
        w = effective_weights(block, arrays, state.robust)
        arrays["robust_weights"] = (state.robust, w)
    return {**arrays, "weight": w, "cached_weight": arrays["weight"]}


def iterate_tile(t: int, *, scene: Scene, cache_root: Path, state: SolveState, want_phase: bool) -> updates.PassSums:
    """Partial sums of one iteration over tile ``t`` (eqs. 1, 3, 4, 5): its blocks' sums added in block order.

    Each block's observations, in chunk-major runs, come from :data:`STACKS` (kept in memory
    across iterations within its budget) and run through one fused kernel (:func:`iterate_block`).
    """
    folder = cache_dir(cache_root, scene, t)
    meta = load_meta(folder)  # parsed once per process (every pass asks)
    if meta is None:
        raise FileNotFoundError(f"{folder}: the prepared tile's meta.json is missing")
    idx = np.asarray(meta["index"], np.int32)
    model = scene.model
    phase = want_phase and bool(model.parameters)
    out = updates.PassSums(len(idx), len(model.parameters), index=idx)
    for i, (b0, b1) in enumerate(meta["blocks"]):
        arrays = pixel_stack(folder / f"block_{i:04d}", cache_root, scene)
        ROWS.advance(b1 - b0)
        if not len(arrays["index"]):
            continue
        arrays = _weighted(folder / f"block_{i:04d}", arrays, state)  # the haze is taken off inside the kernel
        part = updates.PassSums(len(arrays["index"]), out.n_params, index=arrays["index"])
        iterate_block(arrays, scene.settings, model, state, phase, part)
        out.add(part)  # blocks in order; without the phase step the normal equations stay zero
    return out


def iterate_block(arrays: dict, s, model, state: SolveState, phase: bool, out: updates.PassSums) -> None:
    """Add one block of observations in chunk-major runs (all of a tile, or rows of it) to ``out``.

    The model's ``point`` runs inside the kernel (its ``point_kind``, :func:`.kernels.point_kind`); a model without
    one gives R and its derivatives as NumPy arrays (also when it fits more than two parameters:
    then the normal equations are NumPy sums).
    """
    n_par = len(model.parameters) if phase else 0
    params = np.asarray(state.params, np.float32)
    kind = kernels.point_kind(model) if len(model.parameters) <= 2 else None
    if kind is not None:
        layers = [arrays[n] for n in model.point_layers]
    else:
        kind = 0
        r = np.asarray(model.reflectance_from(arrays, state.params), np.float32)
        dr = [np.asarray(d, np.float32) for d in model.derivatives_from(arrays, state.params)] if n_par else []
        layers = [r, *dr[:2]]
    layers += [layers[0] if layers else arrays["image"]] * (3 - len(layers))
    n_cols = n_par + 1 if 0 < n_par <= 2 else 0
    texp = np.asarray(state.exposure, np.float64)[arrays["index"]].astype(np.float32)
    shadow, ratio = kernels.NO_SHADOW_TEST, arrays["image"][:0]
    if s.shadow_type in (shadows.LAMBERT_RATIO, shadows.LUNAR_LAMBERT_RATIO) and model.needs_geometry:
        if s.shadow_type == shadows.LAMBERT_RATIO and "cos_i" in arrays:
            shadow, ratio = kernels.SHADOW_ON_LAYER, arrays["cos_i"]
        else:
            shadow = kernels.SHADOW_ON_R
    # the phase-angle range of the used observations: stored by the prepare step when the weights are
    # those of the cache (no dynamic shadow test), else the kernel's (0.2-0.3 ns per observation and pass)
    known_range = shadow == kernels.NO_SHADOW_TEST and "alpha_range" in arrays
    alpha = arrays["alpha"] if (n_par and "alpha" in arrays and not known_range) else arrays["image"][:0]
    alb = np.full(runs.pixel_extent(arrays) if n_par > 2 else 0, np.nan, np.float32)
    jtj, jtr = np.zeros((n_cols, n_cols)), np.zeros(n_cols)
    # FLOAT_HAZE 1: the kernel takes each image's haze off and adds the joint (T, H) step's sums in the same sweep
    # (only while the haze settles, :func:`lunaralbedo.engine.pass_update.haze_settled`; after, it is held and only taken off)
    haze = state.haze_of(arrays["index"]) if state.haze is not None else np.empty(0, np.float32)
    n_h = len(haze) if state.haze_joint else 0
    base = arrays.get("cached_weight", arrays["weight"][:0]) if n_h else arrays["weight"][:0]  # for the robust factor
    hg, hs, hrss = np.zeros(2 * n_h), np.zeros((2 * n_h, 2 * n_h)), np.zeros(3)
    # eq. 4's sums; not with FLOAT_HAZE 1, whose exposures the joint step gives, or holds once the haze has settled,
    # nor with the exposures known (EXPOSURE_MODE fixed)
    eq4 = state.haze is None and not state.exposures_known
    exp_sums = (out.exp_num, out.exp_den) if eq4 else (np.zeros(0), np.zeros(0))
    q, n_obs, amin, amax = kernels.iterate_runs(
        kind, arrays["chunks"], arrays["run_start"], arrays["run_pixel"], arrays["run_image"], arrays["image"],
        arrays["weight"], *layers, params, texp, n_par, n_cols, shadow, ratio, np.float32(s.shadow_thresh), alpha,
        *exp_sums, jtj, jtr, alb, haze, base, hg, hs, hrss)
    if n_h:
        out.haze_g, out.haze_s, out.haze_rss = hg, hs, hrss
    if n_par > 2:  # no such model yet: the normal equations in NumPy
        jtj, jtr = _normal_equations(hazed(arrays, state), alb, texp, layers[0], dr, ratio if shadow == kernels.SHADOW_ON_LAYER else None,
                                     s.shadow_thresh if shadow != kernels.NO_SHADOW_TEST else None)
    if n_par:
        if known_range:
            amin, amax = (float(a) for a in arrays["alpha_range"])
        out.jtj += jtj
        out.jtr += jtr
        out.alpha_min, out.alpha_max = min(out.alpha_min, amin), max(out.alpha_max, amax)
    out.q += float(q)
    out.n_obs += int(n_obs)


def _normal_equations(arrays, alb, texp, r, dr, ratio, thresh):
    """Eq. 5's sums in NumPy (chunk-major runs; ``alb`` per pixel of the block; ``thresh`` None: no dynamic shadow test)."""
    a = np.nan_to_num(alb)[runs.observation_pixels(arrays)]
    t_obs = texp[runs.observation_images(arrays)]
    w = arrays["weight"]
    if thresh is not None:
        w = np.where(shadows.dynamic_lit(arrays["image"], r if ratio is None else ratio, t_obs, thresh), w, 0).astype(np.float32)
    res = arrays["image"] - a * (t_obs * r)
    return updates.phase_sums(res, (a * t_obs)[None], np.ones(1, np.float32), list(dr), r, w)


# --------------------------------------------------------------------------- finalise
def _lost(obs: dict, effective: np.ndarray, rows: int, width: int) -> np.ndarray:
    """The ``outliers/`` rows of a block: per pixel the fraction of weight the robust weights took away
    (:func:`.finalise_kernels.lost_fraction_runs`)."""
    out = np.full(rows * width, np.nan, np.float32)
    if len(obs["index"]):
        lost_fraction_runs(obs["run_start"], obs["run_pixel"], obs["weight"], effective, np.empty(len(out)),
                           np.empty(len(out)), out)
    return out.reshape(rows, width)


def _tile_images(scene: Scene, t: int, used) -> dict:
    """Images used over tile ``t`` and those that overlap it without a usable pixel (shadow, no DEM, ...)."""
    used = set(int(k) for k in used)
    return {
        "tile": scene.tiles[t].name,
        "images": [scene.images[k].key for k in sorted(used)],
        "images_without_usable_pixels": [scene.images[k].key for k in scene.tile_images[t] if int(k) not in used],
    }


def finalize_tile(t: int, *, scene: Scene, cache_root: Path, out_dir: Path, state: SolveState, skip_done: bool = False,
                  write_threads: int = 1) -> dict:
    """Write the albedo and error tiles of tile ``t``, move its DEM and weight-sum tiles (written with its
    cache entry: :data:`KNOWN_OUTPUTS`) into place; return a small report.

    ``write_threads``: threads GDAL may compress each tile with (the executor's ``cpus_per_task``).

    ``weightsSum`` is moved last, so with ``skip_done`` (a resumed run whose final
    state was already fixed) a tile that has it is complete and is not redone.  The
    blocks are read one at a time, and each output written a block of rows at a time
    (:class:`~lunaralbedo.io.geotiff.GeoTiffRows`: the block's rows of albedo and error
    held, 8 bytes per pixel, never the whole tile's).  Once the tile is
    complete its cached blocks are discarded (nothing reads them again, a resumed run
    neither): moved into :data:`TRASH` at once and deleted on a background thread
    (:func:`lunaralbedo.io.cache.discard`), so the cache goes in parallel over the workers
    and no task waits for the disk; the tile's ``meta.json`` stays for the report.  A task that runs
    again after that (a retried Dask task) finds the tile complete and its blocks gone,
    and reports it as reused.
    """
    s = scene.settings
    tile = scene.tiles[t]
    folder = cache_dir(cache_root, scene, t)
    meta = load_stack(folder)[1]
    idx = np.asarray(meta["index"], np.int32)
    for i in range(len(meta["blocks"])):
        STACKS.discard(folder / f"block_{i:04d}")  # the iterations are over: free the memory
    h, w_ = tile.height, tile.width
    name = f"{tile.name}.tif"
    if (out_dir / "weightsSum" / name).exists() and (skip_done or not (folder / "block_0000").exists()):
        return {**_tile_images(scene, t, idx), "valid_pixels": count_finite(out_dir / "albedo" / name), "reused": True}
    want_err = bool(s.compute_errors and len(idx))
    r0, r1, x0, x1 = meta.get("box", (0, h, 0, w_))  # the part of the tile its blocks cover (observations.footprint)
    rows_file = partial(GeoTiffRows, shape=(h, w_), transform=tile.transform, crs=scene.crs, threads=write_threads,
                        sparse=[r0, r1, x0, x1] != [0, h, 0, w_])  # blocks outside a part: not stored
    files = {"albedo": rows_file(out_dir / "albedo" / name, **OUTPUT_OPTIONS["albedo"])}
    if want_err:
        files["error"] = rows_file(out_dir / "error" / name, **OUTPUT_OPTIONS["error"])
    if state.robust:
        files["outliers"] = rows_file(out_dir / "outliers" / name, **OUTPUT_OPTIONS["outliers"])
    valid = 0
    no_err = np.empty(0, np.float32)
    try:
        if h - (r1 - r0):  # the rows no image reaches (observations.footprint): no-data
            for f in files.values():
                f.skip(h - (r1 - r0))
            ROWS.advance(h - (r1 - r0))
        for i, (b0, b1, obs, per_pixel, c0) in enumerate(_blocks(folder, meta)):  # one block's rows held at a time
            alb = np.empty((b1 - b0, x1 - x0), np.float32)
            err = np.empty((b1 - b0, x1 - x0), np.float32) if want_err else no_err
            if state.robust:
                base = obs
                obs = _weighted(folder / f"block_{i:04d}", obs, state) if len(obs["index"]) else obs
                files["outliers"].write(_lost(base, obs["weight"], b1 - b0, x1 - x0), r0 + b0, x0)
            if len(obs["index"]):
                obs = hazed(obs, state)
                r, w, texp = tile_model(scene, obs, state)
                finalise_runs(obs["chunks"], obs["run_start"], obs["run_pixel"], obs["run_image"], obs["image"],
                              texp, r, w, per_pixel.get("wblend_sum", per_pixel["weights_sum"]),
                              c0, alb.reshape(-1), err.reshape(-1))  # eq. 7's sum of blending weights
            else:
                alb[:], err[:] = np.nan, np.nan
            valid += int(np.count_nonzero(np.isfinite(alb)))
            files["albedo"].write(alb, r0 + b0, x0)
            if want_err:
                files["error"].write(err, r0 + b0, x0)
            del alb, err
            ROWS.advance(b1 - b0)
        for f in files.values():  # each renamed into place complete
            f.close()
    except BaseException:
        for f in files.values():
            f.abort()
        raise
    for kind in KNOWN_OUTPUTS:  # written at prepare: moved into place (weightsSum last: the tile is complete)
        src, dst = folder / f"{kind}.tif", out_dir / kind / name
        if src.exists():
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, dst)
        elif not dst.exists() and kind == "weightsSum":  # not moved by an earlier try of this task either
            raise FileNotFoundError(f"{src}: the cached weight-sum tile is missing")
    # the tile is complete: its observations are not needed again (deleted in the background)
    discard([folder / f"block_{i:04d}" for i in range(len(meta["blocks"]))], cache_root / TRASH)
    return {**_tile_images(scene, t, idx), "valid_pixels": valid, "reused": False}
