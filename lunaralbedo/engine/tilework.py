"""The three kinds of tile task: prepare, iterate, finalise.

Each task is a plain function of (scene, tile index, small state) that a Dask worker
(or a plain loop) runs.  ``prepare`` reads the inputs once and caches the tile's
observation stack inside OUTDIR; ``iterate`` computes one iteration's partial sums
from the cached stack; ``finalise`` writes the tile's outputs.  Global couplings
(exposures, phase coefficients, Q) leave a task only as small float64 sums.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io.cache import load_stack, save_stack
from ..io.rasters import read_dem_onto_grid, read_drg_onto_grid, write_geotiff
from ..constants import MIN_COS_INCIDENCE
from ..model import exposure_init, geometry, photometry, shadows, updates
from .scene import Scene


@dataclass
class SolveState:
    """The global unknowns besides the albedo: exposures and the model's fitted parameters."""

    exposure: np.ndarray  # (K,) per image
    params: np.ndarray  # (P,) fitted parameters of the photometric model (Lunar-Lambert: c1, c2)


@dataclass
class TileSums:
    """One tile's contribution to an iteration (float64, per local image where indexed).

    ``jtj``/``jtr`` are the normal equations of the P fitted parameters plus the global scale.
    """

    index: np.ndarray
    n_params: int = 0
    q: float = 0.0
    exp_num: np.ndarray | None = None
    exp_den: np.ndarray | None = None
    jtj: np.ndarray | None = None
    jtr: np.ndarray | None = None
    alpha_min: float = np.inf
    alpha_max: float = -np.inf
    n_obs: int = 0

    def __post_init__(self):
        if self.jtj is None:
            self.jtj = np.zeros((self.n_params + 1, self.n_params + 1))
        if self.jtr is None:
            self.jtr = np.zeros(self.n_params + 1)


def _cache_dir(cache_root: Path, scene: Scene, t: int) -> Path:
    return Path(cache_root) / scene.tiles[t].name


# --------------------------------------------------------------------------- prepare
def _geometry_stack(scene: Scene, tile):
    """DEM, body-fixed points, normals and the no-DEM mask of the unpadded tile.

    The DEM is read on the padded grid so that normals at the tile's edge see their
    neighbours, then everything is cropped to the tile.
    """
    s = scene.settings
    shape, transform = tile.padded_shape, tile.padded_transform
    dem = read_dem_onto_grid(scene.dems, transform, shape, scene.crs, s.no_dem_data_val)
    lon, lat = geometry.lonlat_grid(transform, shape)
    pts = geometry.body_fixed(lon, lat, np.nan_to_num(dem, nan=0.0))
    normals = geometry.dem_normals(pts)
    inner = tile.inner
    return dem[inner], pts[inner], normals[inner], ~np.isfinite(dem[inner])


def prepare_tile(t: int, *, scene: Scene, cache_root: Path) -> dict:
    """Read every image over tile ``t`` onto its grid, compute geometry, cache the stack.

    Returns the tile's initialisation sums (also stored in the cache's meta, so a
    resumed run does not recompute them): per-image reflectance sums for the seed
    exposure, and pairwise log-ratio sums for the overlap exposure.
    """
    folder = _cache_dir(cache_root, scene, t)
    cached = load_stack(folder)
    if cached is not None:
        return {**cached[1], "reused": True}
    s = scene.settings
    model = s.model
    tile = scene.tiles[t]
    geo = _geometry_stack(scene, tile) if model.needs_geometry else None
    thresh = s.shadow_thresh if s.shadow_type == shadows.THRESHOLD else None
    per_image: dict[str, list] = {name: [] for name in ("image", "wblend", "usable")}
    keep = []
    for k in scene.tile_images[t]:
        got = read_drg_onto_grid(scene.images[k], scene.profiles[k], tile.transform, (tile.height, tile.width), scene.crs, thresh)
        if got is None:
            continue
        val, ok, wt, use = got
        use &= val > 0
        layers = {}
        if geo is not None:
            dem, pts, normals, bad = geo
            ci, ce, al = geometry.illumination(pts, normals, scene.sun[k], scene.spacecraft[k])
            use &= ~bad & (ci >= MIN_COS_INCIDENCE) & (ce > 0)
            layers = model.layers(ci, ce, al)
            if s.shadow_type == shadows.LAMBERT_RATIO:
                layers["cos_i"] = ci
        if not use.any():
            continue
        keep.append(int(k))
        layers.update(image=val, wblend=wt if s.use_weights else ok, usable=use)
        for name, arr in layers.items():
            per_image.setdefault(name, []).append(arr)
    h, w = tile.height, tile.width
    arrays: dict[str, np.ndarray] = {"index": np.array(keep, np.int32)}
    for name, dtype in (("image", np.float32), ("wblend", np.float32), ("usable", bool)):
        arrays[name] = np.array(per_image[name], dtype).reshape(-1, h, w)
    arrays["weights_sum"] = arrays["wblend"].sum(axis=0, dtype=np.float64).astype(np.float32)
    if s.use_normalized_cost_fun:
        with np.errstate(invalid="ignore", divide="ignore"):
            wb = arrays["wblend"]
            arrays["wblend"] = np.where(wb > 0, wb / arrays["weights_sum"][None], 0.0).astype(np.float32)
    arrays["weight"] = np.where(arrays["usable"], arrays["wblend"], 0.0).astype(np.float32)
    if geo is not None:
        arrays["dem"] = geo[0]
        names = model.layer_names + (("cos_i",) if s.shadow_type == shadows.LAMBERT_RATIO else ())
        for name in names:  # the model's layers (float32), also for a tile without usable image
            arrays[name] = np.array(per_image.get(name, []), np.float32).reshape(-1, h, w)
    meta = _init_sums(scene, arrays)
    meta["tile"] = tile.name
    del arrays["usable"]  # folded into "weight"; only the initialisation needed it
    save_stack(folder, arrays, meta)
    return {**meta, "reused": False}


def _layers(arrays) -> dict:
    """The cached stack as in-memory arrays (the model's functions see plain ndarrays)."""
    return {k: np.asarray(v) for k, v in arrays.items()}


def _init_sums(scene: Scene, arrays) -> dict:
    s = scene.settings
    r = s.model.reflectance_from(_layers(arrays), s.initial_params)
    use = arrays["usable"] & (arrays["wblend"] > 0) & (r > 0)
    rs, n = exposure_init.mean_reflectance_sums(r, use)
    pairs = exposure_init.log_ratio_sums(arrays["image"], r, use, arrays["index"])
    return {
        "index": arrays["index"].tolist(),
        "r_sum": rs.tolist(),
        "r_count": n.tolist(),
        "pairs": [[j, k, n_, d] for (j, k), (n_, d) in sorted(pairs.items())],
    }


# --------------------------------------------------------------------------- iterate
def _weights(arrays, model, shadow_type, thresh, t_local, r):
    w = np.asarray(arrays["weight"])
    if shadow_type in (shadows.LAMBERT_RATIO, shadows.LUNAR_LAMBERT_RATIO) and model.needs_geometry:
        rr = arrays["cos_i"] if (shadow_type == shadows.LAMBERT_RATIO and "cos_i" in arrays) else r
        lit = shadows.dynamic_lit(arrays["image"], rr, t_local[:, None, None], thresh)
        w = np.where(lit, w, 0.0).astype(np.float32)
    return w


def tile_model(scene: Scene, arrays, state: SolveState):
    """Albedo of a cached tile stack for the given exposures and model parameters (eq. 3).

    Returns ``(albedo, R, w, T R, T)`` with ``arrays`` as plain ndarrays.
    """
    s = scene.settings
    layers = _layers(arrays)
    t_local = state.exposure[layers["index"]].astype(np.float32)
    r = s.model.reflectance_from(layers, state.params)
    w = _weights(layers, s.model, s.shadow_type, s.shadow_thresh, t_local, r)
    tr = t_local[:, None, None] * r
    alb = updates.albedo(layers["image"], tr, w)
    return alb, r, w, tr, t_local


def iterate_tile(t: int, *, scene: Scene, cache_root: Path, state: SolveState, want_phase: bool) -> TileSums:
    """Partial sums of one iteration over tile ``t`` (eqs. 1, 3, 4, 5)."""
    loaded = load_stack(_cache_dir(cache_root, scene, t))
    arrays = loaded[0]
    idx = np.asarray(arrays["index"])
    model = scene.settings.model
    out = TileSums(index=idx, n_params=len(model.parameters), exp_num=np.zeros(len(idx)), exp_den=np.zeros(len(idx)))
    if len(idx) == 0:
        return out
    alb, r, w, tr, t_local = tile_model(scene, arrays, state)
    image = arrays["image"]
    res = updates.residuals(image, alb, tr, w)
    out.q = updates.cost(res, w)
    out.exp_num, out.exp_den = updates.exposure_sums(image, alb, r, w)
    out.n_obs = int(np.count_nonzero(w))
    if want_phase and model.parameters:
        layers = _layers(arrays)
        dr = model.derivatives_from(layers, state.params)
        out.jtj, out.jtr = updates.phase_sums(res, alb, t_local, dr, r, w)
        used = layers["alpha"][w > 0]
        if used.size:
            out.alpha_min, out.alpha_max = float(used.min()), float(used.max())
    return out


# --------------------------------------------------------------------------- finalise
def _tile_images(scene: Scene, t: int, used) -> dict:
    """Images used over tile ``t`` and those that overlap it without a usable pixel (shadow, no DEM, ...)."""
    used = set(int(k) for k in used)
    return {
        "tile": scene.tiles[t].name,
        "images": [scene.images[k].key for k in sorted(used)],
        "images_without_usable_pixels": [scene.images[k].key for k in scene.tile_images[t] if int(k) not in used],
    }


def finalize_tile(t: int, *, scene: Scene, cache_root: Path, out_dir: Path, state: SolveState, skip_done: bool = False) -> dict:
    """Write the albedo, error, DEM and weight-sum tiles of tile ``t``; return a small report.

    ``weightsSum`` is written last, so with ``skip_done`` (a resumed run whose final
    state was already fixed) a tile that has it is complete and is not redone.
    """
    s = scene.settings
    tile = scene.tiles[t]
    arrays, _ = load_stack(_cache_dir(cache_root, scene, t))
    idx = np.asarray(arrays["index"])
    h, w_ = tile.height, tile.width
    name = f"{tile.name}.tif"
    if skip_done and (out_dir / "weightsSum" / name).exists():
        import rasterio

        with rasterio.open(out_dir / "albedo" / name) as ds:
            valid = int(np.count_nonzero(np.isfinite(ds.read(1))))
        return {**_tile_images(scene, t, idx), "valid_pixels": valid, "reused": True}
    if len(idx):
        alb, r, w, tr, _ = tile_model(scene, arrays, state)
    else:
        alb = np.full((h, w_), np.nan, np.float32)
    write_geotiff(out_dir / "albedo" / name, alb, tile.transform, scene.crs, nodata=float("nan"))
    if s.compute_errors and len(idx):
        err = updates.error_map(arrays["image"], alb, tr, w, np.asarray(arrays["wblend"]))
        write_geotiff(out_dir / "error" / name, err, tile.transform, scene.crs, nodata=float("nan"))
    if "dem" in arrays:
        write_geotiff(out_dir / "DEM" / name, np.asarray(arrays["dem"]), tile.transform, scene.crs, nodata=float("nan"))
    write_geotiff(out_dir / "weightsSum" / name, np.asarray(arrays["weights_sum"]), tile.transform, scene.crs)
    return {
        **_tile_images(scene, t, idx),
        "valid_pixels": int(np.count_nonzero(np.isfinite(alb))),
        "reused": False,
    }
