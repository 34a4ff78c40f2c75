"""The shape-from-shading tile task: one window's heights refined with the albedo and exposures held.

The windows are the tiles, each cut into parts of at most ``REFINE_DEM_WINDOW`` pixels a side
(:func:`pieces`). :func:`refine_tile` reads, over a window and a margin of ``REFINE_DEM_MARGIN`` pixels on
every side (the window), the heights the albedo was solved with, the input DEM, the solved
albedo and every image that meets the window; it builds the cost of :mod:`lunaralbedo.model.sfs`
(shading + smoothness + fidelity) and minimises it coarse to fine (``REFINE_DEM_LEVELS``
levels of a factor 2: the coarse solution's change of the heights, interpolated, starts the
finer level).  The refined window and its blending weights are written to one ``.npz`` file
(atomically), which :mod:`.refine` mosaics; a file already there is reused (``--resume``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rasterio.transform import Affine

from ..constants import MOON_RADIUS_KM
from ..io.atomic import atomic_path
from ..io.cache import HEADER_LOCK
from ..io.drgs import read_drg_onto_grid
from ..io.rasters import intersects_lon, raster_info, read_onto_grid
from ..model import geometry, outliers, shadows
from ..model.cast_shadows import cast_shadow_mask
from ..model.grid import Grid
from ..model.sfs import Cost, height_uncertainty, minimise
from ..model.sfs.fidelity import Fidelity
from ..model.sfs.shading import Shading, observation, unit_up
from ..model.sfs.smoothness import Smoothness
from .observations import saturation_of
from .photometry import solver_model


@dataclass(frozen=True)
class HeightGrid:
    """The grid of the refined heights: the tiles' pixels over the box, ``border`` more pixels all round."""

    transform: Affine
    shape: tuple[int, int]
    border: int

    def offset(self, tile) -> tuple[int, int]:
        """Row and column of ``tile``'s first (unpadded) pixel on this grid."""
        return (int(round((self.transform.f - tile.transform.f) / -self.transform.e)),
                int(round((tile.transform.c - self.transform.c) / self.transform.a)))

    def window(self, tile, margin: int) -> tuple[int, int, int, int]:
        """``(r0, r1, c0, c1)`` of the tile with ``margin`` pixels all round, within the grid."""
        r, c = self.offset(tile)
        return (max(r - margin, 0), min(r + tile.height + margin, self.shape[0]),
                max(c - margin, 0), min(c + tile.width + margin, self.shape[1]))

    def pixel_m(self) -> float:
        """Mean ground size of a pixel (metres) at the grid's centre latitude."""
        lat = np.radians(self.transform.f + self.transform.e * self.shape[0] / 2)
        k = np.radians(1.0) * MOON_RADIUS_KM * 1000.0
        return float(0.5 * (abs(self.transform.a) * np.cos(lat) + abs(self.transform.e)) * k)


@dataclass(frozen=True)
class Piece:
    """A window of the height step: a tile, or a part of one (``REFINE_DEM_WINDOW``), and the images over its tile."""

    name: str
    transform: Affine
    height: int
    width: int
    images: tuple


def pieces(scene, size: int) -> list[Piece]:
    """Each tile cut into the fewest near-equal parts of at most ``size`` pixels a side (row-major, tile order):
    the height step's memory does not grow with TILE_SIZE."""
    out = []
    for t, tile in enumerate(scene.tiles):
        rows = np.linspace(0, tile.height, -(-tile.height // size) + 1).round().astype(int)
        cols = np.linspace(0, tile.width, -(-tile.width // size) + 1).round().astype(int)
        for i in range(len(rows) - 1):
            for j in range(len(cols) - 1):
                name = tile.name if len(rows) == len(cols) == 2 else f"{tile.name}_{i}_{j}"
                out.append(Piece(name, tile.transform @ Affine.translation(cols[j], rows[i]), int(rows[i + 1] - rows[i]),
                                 int(cols[j + 1] - cols[j]), tuple(int(k) for k in scene.tile_images[t])))
    return out


def ramp(n: int, lo_gap: int, hi_gap: int, margin: int) -> np.ndarray:
    """Blending weights along one axis of a window of ``n`` pixels: 0 within ``margin / 4`` of an edge that has a
    margin (``lo_gap``/``hi_gap``: pixels of margin on each side), rising linearly to 1 at ``3 margin / 4``."""
    d = np.arange(n, dtype=np.float64)
    w = np.ones(n)
    for gap, dist in ((lo_gap, d), (hi_gap, n - 1 - d)):
        if gap > 0:
            w = np.minimum(w, np.clip((dist + 0.5 - margin / 4) / (margin / 2), 0.0, 1.0))
    return w


def fidelity_weight(s) -> float:
    """``REFINE_DEM_FIDELITY`` (lambda; 1 when empty): the weight of the input DEM at its own resolution."""
    return 1.0 if s.refine_dem_fidelity is None else float(s.refine_dem_fidelity)


def _coarsen(a: np.ndarray, f: int, how: str = "mean") -> np.ndarray:
    """``f x f`` blocks of ``a`` (rows and columns beyond a multiple of ``f`` dropped): their mean (NaN if any is
    NaN) or, ``how="all"``, whether all are true."""
    if f == 1:
        return a
    h, w = (a.shape[0] // f) * f, (a.shape[1] // f) * f
    b = a[:h, :w].reshape(h // f, f, w // f, f, *a.shape[2:])
    return b.all(axis=(1, 3)) if how == "all" else b.mean(axis=(1, 3))


def _level_cost(level_data, s, pixel_m: float, sigma_px: float, h: np.ndarray, f: int, fidelity: float):
    """The cost of :mod:`lunaralbedo.model.sfs` on level ``f`` (blocks of ``f x f`` pixels) and its start heights."""
    lon, lat, _h, h0, images, model, params = level_data
    hc, h0c = _coarsen(h, f), _coarsen(h0, f)
    lo, la = _coarsen(lon, f), _coarsen(lat, f)
    up = unit_up(lo, la)
    pts = geometry.body_fixed(lo, la, hc)
    obs = [observation(_coarsen(j, f)[1:-1, 1:-1], _coarsen(ok, f, "all")[1:-1, 1:-1].astype(float), pts, sun, sc)
           for j, ok, sun, sc in images]
    cost = Cost([Shading(1.0, up, MOON_RADIUS_KM, obs, model.reflectance, params, bool(s.refine_dem_float_albedo)),
                 Smoothness(s.refine_dem_smoothness, pixel_m * f),
                 Fidelity(fidelity, pixel_m * f, h0c, sigma_px / f)])
    return cost, hc, int(sum(np.count_nonzero(o.w) for o in obs))


def _refine(level_data, s, pixel_m: float, sigma_px: float) -> tuple[np.ndarray, list]:
    """Coarse to fine over the levels; returns the fine heights and each level's optimiser report."""
    h = level_data[2].astype(np.float64)
    reports = []
    for level in reversed(range(s.refine_dem_levels)):
        f = 2**level
        if min(h.shape) // f < 8:
            continue
        cost, hc, n_obs = _level_cost(level_data, s, pixel_m, sigma_px, h, f, fidelity_weight(s))
        t0 = time.process_time()
        hr, rep = minimise(cost, hc, pixel_m * f, s.refine_dem_max_iter)
        reports.append({"level": level, **rep, "cpu_s": time.process_time() - t0, "parts": cost.parts(hr),
                        "observations": n_obs})
        if f == 1:
            h = hr
            reports[-1]["sigma"], _ = height_uncertainty(cost, hr)
        else:  # the coarse change of the heights, interpolated onto the finer grid
            from scipy.ndimage import zoom

            dz = zoom(hr - hc, f, order=1, mode="nearest", grid_mode=True)
            full = np.zeros_like(h)
            full[:dz.shape[0], :dz.shape[1]] = dz
            h = h + full
    return h, reports


def _load(t: int, scene, windows: list[Piece], grid: HeightGrid, current: Path, given: Path, albedo: list, exposure,
          params, haze=None):
    """Everything :func:`refine_tile` reads for ``windows[t]`` and its margin: ``(window, level_data, lit)`` with
    ``level_data = (lon, lat, h_cur, h0, images, model)`` (``images``: ``(J, usable, sun, spacecraft)``,
    :math:`J = (I - H_k)/(T_k A)` with each image's haze :math:`H_k` of ``FLOAT_HAZE``, DRG units).

    With ``REJECT_OUTLIERS`` the albedo solve's spatial test (:mod:`lunaralbedo.model.outliers`) leaves out the
    observations of one image that stand out from their neighbourhood and from the other images (hot spots, dropout
    rows): their single-image albedo :math:`(I - H_k)/(T_k R_k)` with the heights the window starts from."""
    s = scene.settings
    tile = windows[t]
    r0, r1, c0, c1 = grid.window(tile, s.refine_dem_margin)
    transform = grid.transform @ Affine.translation(c0, r0)
    shape = (r1 - r0, c1 - c0)
    h_cur = _window(current, r0, r1, c0, c1)
    h0 = _window(given, r0, r1, c0, c1)
    a = np.full(shape, np.nan, np.float32)
    box = Grid(transform, shape).bounds
    for p, bounds in albedo:
        if not intersects_lon(bounds, box):
            continue
        got = read_onto_grid(raster_info(p), 1, transform, shape, scene.crs)
        a = np.where(np.isfinite(a), a, got)
    lon, lat = geometry.lonlat_grid(transform, shape)
    pts = geometry.body_fixed(lon, lat, h_cur)
    normals = geometry.dem_normals(pts)
    thresh = s.shadow_thresh if s.shadow_type == shadows.THRESHOLD else None
    model = solver_model(s)
    images, lit, logs = [], np.zeros(shape, np.int32), []
    for k in tile.images:
        info = scene.images[k]
        got = read_drg_onto_grid(info, scene.profiles[k], transform, shape, scene.crs, thresh,
                                 saturation=saturation_of(info.dtype))
        if got is None:
            continue
        val, valid, _w, use = got
        sun, sc = scene.sun[k], scene.spacecraft[k]
        ci, ce, alpha = geometry.illumination(pts, normals, sun, sc)
        signal = val - (haze[k] if haze is not None else 0.0)
        ok = valid & use & (signal > 0) & (ci > 0) & np.isfinite(a) & (a > 0)
        if s.uses_cast_shadows:
            ok &= ~cast_shadow_mask(h_cur, transform, sun)
        if not ok.any():
            continue
        with np.errstate(invalid="ignore", divide="ignore"):
            j = np.where(ok, signal / (exposure[k] * a), np.nan)
            if s.reject_outliers:
                refl = model.reflectance(ci, ce, alpha, tuple(params))
                logs.append(np.where(ok & (refl > 0), np.log(signal / (exposure[k] * refl)), np.nan))
        images.append((j, ok, sun, sc))
    if logs:
        images = _without_outliers(images, logs)
    for _j, ok, _sun, _sc in images:
        lit += ok
    return (r0, r1, c0, c1), (lon, lat, h_cur, h0, images, model), lit


def _without_outliers(images: list, logs: list) -> list:
    """``images`` less the observations the spatial test of :mod:`lunaralbedo.model.outliers` rejects (``logs``: each
    image's log single-image albedo, NaN where unused), as the albedo solve's first robust pass does."""
    e, pix, tau = [], [], []
    for lg in logs:
        rows, cols = np.nonzero(np.isfinite(lg))
        ek, tk = outliers.neighbourhood_deviation(lg, rows, cols)
        e.append(ek)
        pix.append(rows * lg.shape[1] + cols)
        tau.append(np.full(len(ek), tk))
    bad = outliers.spatial_outliers(np.concatenate(e), np.concatenate(pix), np.concatenate(tau))
    out, start = [], 0
    for (j, ok, sun, sc), p in zip(images, pix):
        drop = bad[start:start + len(p)]
        start += len(p)
        ok = ok.copy()
        ok.flat[p[drop]] = False
        out.append((np.where(ok, j, np.nan), ok, sun, sc))
    return out


def _cropped(level_data, lit: np.ndarray, pad: int, params):
    """``level_data`` over the pixels the images see and ``pad`` more (no work on empty ground), with ``params``."""
    box = _data_box(lit > 0, pad)
    if box is None:
        return None, None
    lon, lat, h_cur, h0, images, model = level_data
    crop = lambda a: a[box]  # noqa: E731
    return box, (crop(lon), crop(lat), crop(h_cur), crop(h0), [(crop(j), crop(ok), sun, sc) for j, ok, sun, sc in images],
                 model, tuple(params))


def refine_tile(t: int, *, scene, windows: list[Piece], grid: HeightGrid, current: Path, given: Path, albedo: list,
                exposure, params, sigma_px: float, out_dir: Path, haze=None) -> dict:
    """Refine the heights of ``windows[t]`` (module docstring); returns its window, optimiser reports, lit counts' mean.

    ``current``: the heights the albedo was solved with (metres, on ``grid``); ``given``: the input DEM on
    ``grid`` (holes filled); ``albedo``: the solved albedo tiles, ``(path, lon/lat bounds)``; ``exposure``: every image's T (global);
    ``params``: the photometric parameters; ``sigma_px``: the input DEM's resolution (pixels of ``grid``); ``haze``:
    every image's haze (DRG units; None without ``FLOAT_HAZE``).
    """
    s = scene.settings
    tile = windows[t]
    path = out_dir / f"tile_{t:04d}.npz"
    r0, r1, c0, c1 = grid.window(tile, s.refine_dem_margin)
    if path.exists():
        with HEADER_LOCK, np.load(path) as z:  # .npy headers parsed one at a time (io/cache.HEADER_LOCK)
            return {"tile": tile.name, "window": [r0, r1, c0, c1], "reports": [], "reused": True,
                    "lit_mean": float(z["lit"].mean())}
    _, data, lit = _load(t, scene, windows, grid, current, given, albedo, exposure, params, haze)
    shape = lit.shape
    h, reports = data[2].copy(), []
    sigma = np.full(shape, np.nan)
    box, cropped = _cropped(data, lit, s.refine_dem_margin, params)
    if box is not None:  # the heights are solved where images see the ground, and a margin around
        h[box], reports = _refine(cropped, s, grid.pixel_m(), sigma_px)
        if reports and "sigma" in reports[-1]:
            sigma[box] = reports[-1].pop("sigma")
    wy = ramp(shape[0], s.refine_dem_margin if r0 > 0 else 0, s.refine_dem_margin if r1 < grid.shape[0] else 0,
              s.refine_dem_margin)
    wx = ramp(shape[1], s.refine_dem_margin if c0 > 0 else 0, s.refine_dem_margin if c1 < grid.shape[1] else 0,
              s.refine_dem_margin)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, h=h.astype(np.float32), w=np.outer(wy, wx).astype(np.float32), lit=lit.astype(np.int16),
                     sigma=sigma.astype(np.float32))
    return {"tile": tile.name, "window": [r0, r1, c0, c1], "reports": reports, "reused": False,
            "lit_mean": float(lit.mean())}


def blur_misfits(t: int, *, scene, windows: list[Piece], grid: HeightGrid, current: Path, given: Path, albedo: list,
                 exposure, params, sigmas: list[float], level: int, max_iter: int, haze=None) -> list[float]:
    """The shading term (:mod:`lunaralbedo.model.sfs.shading`) of ``windows[t]`` after the height step on level
    ``level`` (blocks of ``2**level`` pixels, ``max_iter`` L-BFGS iterations) with each input blur of ``sigmas`` (pixels) held at
    :func:`fidelity_weight`: the images' misfit at each candidate resolution of the input DEM (engine/refine.py
    ``estimate_input_blur``)."""
    s = scene.settings
    _, data, lit = _load(t, scene, windows, grid, current, given, albedo, exposure, params, haze)
    box, cropped = _cropped(data, lit, s.refine_dem_margin, params)
    f = 2**level
    if box is None or min(cropped[2].shape) // f < 8:
        return [0.0] * len(sigmas)
    out = []
    for sigma in sigmas:
        cost, hc, _ = _level_cost(cropped, s, grid.pixel_m(), sigma, cropped[2], f, fidelity_weight(s))
        hr, _ = minimise(cost, hc, grid.pixel_m() * f, max_iter)
        out.append(cost.parts(hr)["shading"])
    return out


def _data_box(seen: np.ndarray, pad: int) -> tuple[slice, slice] | None:
    """Rows and columns of the pixels ``seen``, ``pad`` more all round (within the array); None if none is."""
    rows, cols = np.flatnonzero(seen.any(axis=1)), np.flatnonzero(seen.any(axis=0))
    if not len(rows):
        return None
    return (slice(max(rows[0] - pad, 0), min(rows[-1] + 1 + pad, seen.shape[0])),
            slice(max(cols[0] - pad, 0), min(cols[-1] + 1 + pad, seen.shape[1])))


def _window(path: Path, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """Rows ``r0:r1``, columns ``c0:c1`` of a heights file on the :class:`HeightGrid` (float64 metres)."""
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(path) as ds:
        return ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0)).astype(np.float64)
