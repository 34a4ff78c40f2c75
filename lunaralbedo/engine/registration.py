"""Image-to-DEM registration (``REGISTER_IMAGES 1``): a ground shift per image found with the albedo and exposures.

SPICE pointing puts an image tens to hundreds of metres from where it really lies on the DEM.
Before the tile solve, :func:`estimate` finds per image the shift (east, north, metres) that,
added to its stated georeference, minimises the cost Q of eq. 1 of the PhotometryTK manual
jointly with the albedo and the exposures (:mod:`lunaralbedo.model.registration`: Gauss-Newton
in the exposures and shifts with the albedo eliminated, Levenberg-Marquardt damped).  The
reflectance comes from the DEM's normals, so the shading of the terrain anchors every image;
no image is the reference.

It works on an in-memory copy of the scene over SIMULATION_BOX: each image read once, averaged
over ``factor`` x ``factor`` pixels so that the observations stay under
:data:`MAX_OBSERVATIONS` (:func:`lunaralbedo.io.drg_levels.read_drg_decimated`), the DEM and the
geometry resampled onto a common lon/lat grid.  Coarse to fine: grids of 2^j of those pixels
(images smoothed to match) while 2^j does not exceed REGISTER_MAX_SHIFT, down to 1, each level
starting from the last one's shifts and exposures; sub-pixel by bilinear sampling.  Shadows:
the lit test of SHADOW_TYPE 1 and R > 0 (cast shadows are not modelled here).  Units: shifts
and their standard errors in metres on the ground; REGISTER_MAX_SHIFT in pixels of each image.

The shifted images then enter the solve through their georeference: :func:`shifted_scene` moves
each image's transform, and the DRG is resampled onto the tiles there
(:func:`lunaralbedo.io.drgs.read_drg_onto_grid`).  The run writes ``image_offsets.csv``.
Everything runs in the driver process in a fixed order: the same bytes for any ``--workers``.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
from rasterio.transform import Affine
from scipy import ndimage

from ..io.atomic import atomic_write_text
from ..io.drg_levels import read_drg_decimated
from ..io.rasters import geographic_crs, read_dem_onto_grid
from ..model import geometry, registration as reg, shadows
from .observations import saturation_of
from .photometry import solver_model
from .offsets import M_PER_DEG, Registration, metres_to_map, pixel_metres, shifted_scene, write_offsets_csv
from .scene import Scene

#: Most observations (image pixels over SIMULATION_BOX) of the finest level; more and the images are averaged.
MAX_OBSERVATIONS = 4_000_000
#: Gauss-Newton iterations per level, at most; a level stops once no shift moves by STOP_PX of its pixels.
ITERATIONS = 12
STOP_PX = 0.002
#: Order of the spline the images are sampled with: 3, cubic.  Bilinear sampling (as the solve resamples the images
#: onto the tiles) makes the cost piecewise smooth, with kinks at every pixel; its Gauss-Newton steps stalled on 3 of
#: 40 rough strips (seeds 20-39, clean and with 1 % outliers) with every image 0.5-1 px off, although the cost fell
#: all the way from there to the truth (``tests/test_registration.py``): RMS 0.027 px median, 0.60 px worst.  With
#: the cubic spline the cost is twice differentiable: 0.035 px median, 0.094 px worst, no failure.  At the finest
#: level the pixels are not smoothed (smoothing the images and not the DEM's shading moved the shifts along the
#: Sun's azimuth by up to 0.9 px), and each sample is weighted by the inverse of its noise variance after
#: interpolation (:func:`~lunaralbedo.model.registration.spline_noise_factor`): unweighted, the cost was 40 % lower
#: with every image half a pixel off, where interpolation averages the noise of neighbouring pixels.
ORDER = 3
#: Step (image pixels) of the central differences that give the derivatives of the interpolant the cost sees
#: (np.gradient of the pixels missed a third of the slope of the sharp detail that carries the sub-pixel shift).
DERIVATIVE_PX = 0.01
#: Passes of outlier rejection at most (``REJECT_OUTLIERS``): each drops the pixels that stand out at the last shifts
#: (:func:`_drop_outliers`) and finds the shifts again from none.
OUTLIER_PASSES = 2
FOLDER = "registration"  # under the solve's checkpoint folder


class _Image:
    """One image held for the registration: its averaged pixels, smoothed per level, and how to sample them."""

    def __init__(self, info, factor, thresh):
        self.info = info
        self.value, self.usable, self.transform = read_drg_decimated(info, factor, thresh, saturation_of(info.dtype))
        self.inv = ~self.transform
        self.m = metres_to_map(info)
        a = np.array([[self.inv.a, self.inv.b], [self.inv.d, self.inv.e]]) @ self.m  # (col,row) per metre (east,north)
        self.d_pix = a
        self._levels = {}

    def level(self, f: int):
        """Spline coefficients, usable mask (float) and whether the pixels are raw, at level factor ``f``
        (smoothed for f > 1)."""
        if f not in self._levels:
            u = self.usable.astype(np.float64)
            v = self.value.astype(np.float64) * u
            sigma = 0.5 * f if f > 1 else 0.0  # coarse levels: smoothed to their pixel
            if sigma > 0:
                wsum = ndimage.gaussian_filter(u, sigma, mode="constant")
                with np.errstate(invalid="ignore", divide="ignore"):
                    v = np.where(wsum > 1e-6, ndimage.gaussian_filter(v, sigma, mode="constant") / wsum, 0.0)
                u = ndimage.minimum_filter(u, size=2 * math.ceil(sigma) + 1, mode="constant")
            if not u.all() and u.any():  # unusable pixels take their nearest usable value: no edge rings the spline
                near = ndimage.distance_transform_edt(u == 0, return_distances=False, return_indices=True)
                v = v[tuple(near)]
            coef = ndimage.spline_filter(v, order=ORDER, mode="mirror") if ORDER > 1 else v
            u = ndimage.minimum_filter(u, size=ORDER + 2, mode="constant")  # the spline's neighbours are usable too
            self._levels[f] = (coef, u, sigma == 0)
        return self._levels[f]

    def rowcol(self, x, y, shift_m) -> tuple[np.ndarray, np.ndarray]:
        """The (row, column) in the averaged image (pixel centres at integers) of map points ``x, y`` moved back by
        ``shift_m``."""
        dx, dy = self.m @ shift_m
        inv = self.inv
        return (inv.d * (x - dx) + inv.e * (y - dy) + inv.f - 0.5, inv.a * (x - dx) + inv.b * (y - dy) + inv.c - 0.5)

    def drop(self, rows: np.ndarray, cols: np.ndarray) -> int:
        """Make the pixels ``(rows, cols)`` unusable (and their neighbours: the bilinear samples they enter); returns
        how many pixels were usable before."""
        bad = np.zeros(self.usable.shape, bool)
        inside = (rows >= 0) & (rows < bad.shape[0]) & (cols >= 0) & (cols < bad.shape[1])
        bad[rows[inside], cols[inside]] = True
        bad = ndimage.binary_dilation(bad, np.ones((3, 3), bool))
        n = int(np.count_nonzero(bad & self.usable))
        self.usable = self.usable & ~bad
        self._levels = {}
        return n

    def sample(self, f, x, y, shift_m, derivatives: bool = True):
        """Value, d/d(east), d/d(north) (per metre; None without ``derivatives``) and usable flag at map points
        ``x, y`` moved back by ``shift_m``: the spline of the level's image, its derivatives by central differences
        of the spline itself over :data:`DERIVATIVE_PX` (the derivative of the interpolant the cost sees)."""
        coef, u, _ = self.level(f)
        row, col = self.rowcol(x, y, shift_m)
        at = np.stack([row, col])
        spline = lambda pts: ndimage.map_coordinates(coef, pts, order=ORDER, mode="mirror", prefilter=False)  # noqa: E731
        val = spline(at)
        ok = ndimage.map_coordinates(u, at, order=1, mode="constant", cval=0.0) > 0.999
        raw = self._levels[f][2]  # raw pixels: every sample weighted by the inverse of its noise variance
        v_r, v_c = (reg.spline_noise_factor(row, ORDER), reg.spline_noise_factor(col, ORDER)) if raw else (1.0, 1.0)
        weight = np.ones(len(val)) / (v_r * v_c)
        if not derivatives:
            return val, None, None, ok, weight, None
        h = DERIVATIVE_PX
        g_r = (spline(at + [[h], [0.0]]) - spline(at - [[h], [0.0]])) / (2 * h)
        g_c = (spline(at + [[0.0], [h]]) - spline(at - [[0.0], [h]])) / (2 * h)
        # I(g - s): d/ds = -(dI/dcol dcol/dmap + dI/drow drow/dmap) dmap/ds
        d_e = -(g_c * self.d_pix[0, 0] + g_r * self.d_pix[1, 0])
        d_n = -(g_c * self.d_pix[0, 1] + g_r * self.d_pix[1, 1])
        dw = None
        if raw:  # d(1/(v_r v_c))/ds = -w (v_r'/v_r drow/ds + v_c'/v_c dcol/ds)
            lr = reg.spline_noise_factor(row, ORDER, derivative=True) / v_r
            lc = reg.spline_noise_factor(col, ORDER, derivative=True) / v_c
            dw = (weight * (lc * self.d_pix[0, 0] + lr * self.d_pix[1, 0]), weight * (lc * self.d_pix[0, 1] + lr * self.d_pix[1, 1]))
        return val, d_e, d_n, ok, weight, dw


class _Level:
    """The common grid of one level: its DEM, and per image a window, map coordinates and reflectance."""

    def __init__(self, scene: Scene, images: list[_Image], f: int, res: tuple[float, float], box, max_m, fine: int = 1):
        model = solver_model(scene.settings)
        self.f = f
        rx, ry = res[0] * f, res[1] * f
        west, south, east, north = box
        w, h = max(1, math.ceil((east - west) / rx - 1e-6)), max(1, math.ceil((north - south) / ry - 1e-6))
        self.shape = (h, w)
        t = Affine(rx, 0, west, 0, -ry, north)
        self.windows = []
        for k, im in enumerate(images):
            bw, bs, be, bn = im.info.lonlat_bounds
            pad_lon = max_m[k] / (M_PER_DEG * math.cos(math.radians((bs + bn) / 2))) + rx
            pad_lat = max_m[k] / M_PER_DEG + ry
            c0, c1 = max(0, int((bw - pad_lon - west) // rx)), min(w, math.ceil((be + pad_lon - west) / rx))
            r0, r1 = max(0, int((north - bn - pad_lat) // ry)), min(h, math.ceil((north - bs + pad_lat) / ry))
            if c1 <= c0 or r1 <= r0:
                self.windows.append(None)
                continue
            r, base = _reflectance(scene, model, k, t @ Affine.translation(c0, r0), (r1 - r0, c1 - c0), fine)
            lon, lat = geometry.lonlat_grid(t @ Affine.translation(c0, r0), (r1 - r0, c1 - c0))
            x, y = _map_coordinates(im.info, lon[0], lat[:, 0])
            rr, cc = np.nonzero(base)
            self.windows.append(dict(pix=((rr + r0) * w + cc + c0).astype(np.int64), x=x[rr, cc], y=y[rr, cc], r=r[rr, cc]))
        self.n_grid = h * w

    def observations(self, images, shifts, derivatives: bool = True) -> list[reg.ImageObs]:
        """Every image's observations at ``shifts`` (K, 2 metres); without ``derivatives`` (a trial step's cost)
        their ``d_east``, ``d_north`` are None."""
        out = []
        for im, win, s in zip(images, self.windows, shifts):
            if win is None:
                z = np.zeros(0)
                out.append(reg.ImageObs(np.zeros(0, np.int64), z, z, z, z, z))
                continue
            val, d_e, d_n, ok, weight, dw = im.sample(self.f, win["x"], win["y"], s, derivatives)
            pick = lambda v: None if v is None else v[ok]  # noqa: E731
            dw = dw or (None, None)
            out.append(reg.ImageObs(win["pix"][ok], val[ok], pick(d_e), pick(d_n), win["r"][ok], weight[ok],
                                    pick(dw[0]), pick(dw[1])))
        return out


def _reflectance(scene: Scene, model, k: int, transform: Affine, shape: tuple[int, int], fine: int):
    """Image ``k``'s reflectance over a window of a level grid (float64) and where it is usable (R > 0, lit, DEM).

    With ``fine`` > 1 (the images' pixels are averaged over ``fine`` x ``fine``: :func:`estimate`), R is computed
    on the images' own pixels and averaged likewise, so that it matches the averaged pixels (R taken at the block
    centres moved the shifts along the Sun's azimuth by 0.3 px on make bench item 14's strip).
    """
    s = scene.settings
    h, w = shape
    hf, wf = h * fine, w * fine
    outer = transform @ Affine.scale(1.0 / fine) @ Affine.translation(-1, -1)  # one pixel more all round: normals
    dem = read_dem_onto_grid(scene.dems, outer, (hf + 2, wf + 2), scene.crs, s.no_dem_data_val)
    lon, lat = geometry.lonlat_grid(outer, (hf + 2, wf + 2))
    pts = geometry.body_fixed(lon, lat, np.nan_to_num(dem))
    normals = geometry.dem_normals(pts)[1:-1, 1:-1]
    ci, ce, al = geometry.illumination(pts[1:-1, 1:-1], normals, scene.sun[k], scene.spacecraft[k])
    where = dict(lon=lon[1:-1, 1:-1], lat=lat[1:-1, 1:-1]) if model.needs_location else {}
    r = np.asarray(model.reflectance_from(model.layers(ci, ce, al, **where), s.initial_params), np.float64)
    ok = np.isfinite(dem[1:-1, 1:-1]) & (ci > 0) & np.isfinite(r) & (r > 0)
    if fine > 1:
        r = np.where(ok, r, 0.0).reshape(h, fine, w, fine).mean(axis=(1, 3))
        ok = ok.reshape(h, fine, w, fine).all(axis=(1, 3))
    return r, ok


def _map_coordinates(info, lon, lat):
    """The grid's lon/lat (1-D, degrees) in the DRG's CRS, as 2-D arrays (longitudes brought next to the DRG's)."""
    lo, la = np.meshgrid(lon, lat)
    if info.crs is None or info.crs.is_geographic:
        w, _, e, _ = info.bounds
        turn = 360.0 * np.round(((w + e) / 2 - lo) / 360.0)
        return lo + turn, la
    from rasterio.warp import transform

    xs, ys = transform(geographic_crs(info.crs), info.crs, lo.ravel(), la.ravel())
    return np.asarray(xs).reshape(lo.shape), np.asarray(ys).reshape(lo.shape)


def _box(scene: Scene, res: tuple[float, float]) -> tuple[float, float, float, float]:
    """SIMULATION_BOX cut to the images' footprints by whole pixels of ``res`` (degrees), so that the grid's pixels
    are the tiles' (which start at the box's north-west corner): ``(west, south, east, north)`` degrees."""
    b = np.array([im.lonlat_bounds for im in scene.images])
    lon0, lon1, lat0, lat1 = scene.settings.simulation_box
    west = lon0 + max(0, math.floor((b[:, 0].min() - lon0) / res[0])) * res[0]
    north = lat1 - max(0, math.floor((lat1 - b[:, 3].max()) / res[1])) * res[1]
    return west, max(lat0, b[:, 1].min()), min(lon1, b[:, 2].max()), north


def estimate(scene: Scene, progress=None) -> Registration:
    """The shift of every image of ``scene`` (module docstring); ``progress(str)`` hears each level's result."""
    s = scene.settings
    res = scene.images[0].lonlat_res
    box = _box(scene, res)
    n_obs = sum(im.width * im.height for im in scene.images)
    grid_px = (box[2] - box[0]) / res[0] * (box[3] - box[1]) / res[1]  # a box much larger than the images: its grid too
    factor = max(1, math.ceil(math.sqrt(n_obs / MAX_OBSERVATIONS)), math.ceil(math.sqrt(grid_px / (4 * MAX_OBSERVATIONS))))
    thresh = s.shadow_thresh if s.shadow_type == shadows.THRESHOLD else None
    images = [_Image(info, factor, thresh) for info in scene.images]
    pixel_m = np.array([pixel_metres(info) for info in scene.images])
    max_m = s.register_max_shift * pixel_m
    top = max(0, int(math.floor(math.log2(max(s.register_max_shift / factor, 1.0)))))
    shifts, exposure, levels, lv, a = _coarse_to_fine(scene, images, top, factor, res, box, max_m, pixel_m, progress)
    for _ in range(OUTLIER_PASSES if s.reject_outliers else 0):  # hot spots, dropout rows: left out, shifts found again
        dropped = _drop_outliers(images, lv, shifts, exposure, a)
        if not dropped:
            break
        shifts, exposure, more, lv, a = _coarse_to_fine(scene, images, top, factor, res, box, max_m, pixel_m, progress)
        more[0]["outlier_pixels_dropped"] = dropped  # the levels run again without them
        levels += more
    obs = lv.observations(images, shifts)
    loss = _loss(s)
    scales = reg.residual_scales(obs, exposure, a, lv.n_grid)
    normal = reg.normal_equations(reg.reweighted(obs, exposure, a, scales, *loss), exposure, a, lv.n_grid)
    se = reg.standard_errors(normal, exposure)
    se[[len(o.value) == 0 for o in obs]] = np.nan
    return Registration(scene.keys, shifts, se, pixel_m, factor, levels)


def _loss(s) -> tuple[str, float]:
    """The registration's robust loss: the solve's (``ROBUST_LOSS``, ``ROBUST_THRESHOLD``)."""
    return s.robust_loss, float(s.robust_threshold)


def _coarse_to_fine(scene, images, top, factor, res, box, max_m, pixel_m, progress):
    """The levels of :func:`estimate` from no shift: ``(shifts, exposure, levels, last level, albedo)``."""
    shifts, exposure, levels = np.zeros((len(images), 2)), None, []
    for j in range(top, -1, -1):
        t0 = time.perf_counter()
        lv = _Level(scene, images, 2**j, (res[0] * factor, res[1] * factor), box, max_m, fine=factor if j == 0 else 1)
        t1 = time.perf_counter()
        obs = lv.observations(images, shifts)
        if exposure is None:
            exposure = np.array([float(np.sum(o.value)) / max(float(np.sum(o.r)), 1e-300) if len(o.value) else 1.0 for o in obs])
            exposure /= np.exp(np.mean(np.log(exposure)))
        for _ in range(3):  # exposures and albedo of eqs. 3 and 4 at the level's first shifts
            exposure = reg.exposures(obs, reg.albedo(obs, exposure, lv.n_grid), exposure)
        shifts, exposure, obs, a, q, it, evals = _gauss_newton(lv, images, obs, shifts, exposure, max_m,
                                                               pixel_m * factor * 2**j, _loss(scene.settings))
        levels.append({"pixel_factor": factor * 2**j, "iterations": it, "evaluations": evals, "mean_sq_residual": q,
                       "observations": int(sum(len(o.value) for o in obs)), "setup_s": round(t1 - t0, 4),
                       "iterate_s": round(time.perf_counter() - t1, 4)})
        if progress:
            progress(f"registration level {factor * 2**j}: {it} iterations, mean squared residual {q:.4g}")
    return shifts, exposure, levels, lv, a


def _drop_outliers(images, lv, shifts, exposure, a) -> int:
    r"""Make unusable the image pixels whose log ratio :math:`e = \log(I / (T A R))` at the found shifts lies beyond the
    threshold of the solve's spatial test (:mod:`lunaralbedo.model.outliers`: :data:`~lunaralbedo.model.outliers.SIGMAS`
    robust standard deviations of the image's :math:`e`, at least :data:`~lunaralbedo.model.outliers.TAU_MIN`): defects
    of one image (hot spots, dropout rows) pulled the least-squares shifts by whole pixels.
    Returns the number of pixels dropped."""
    from ..model.outliers import standing_out

    dropped = 0
    for k, (im, win, o) in enumerate(zip(images, lv.windows, lv.observations(images, shifts, derivatives=False))):
        if win is None or not len(o.value):
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            bad = standing_out(np.log(o.value / (exposure[k] * np.nan_to_num(a[o.pix]) * o.r)))
        if bad.any():
            ok = np.isin(win["pix"], o.pix[bad])
            rows, cols = im.rowcol(win["x"][ok], win["y"][ok], shifts[k])
            dropped += im.drop(np.rint(rows).astype(np.int64), np.rint(cols).astype(np.int64))
    return dropped


def _gauss_newton(lv, images, obs, shifts, exposure, max_m, level_px, loss=("none", 1.0)):
    """Levenberg-Marquardt iterations of one level from ``shifts`` (K, 2 metres) and ``exposure``: returns the
    shifts, exposures, observations, albedo, mean cost per observation, iterations and cost evaluations.  The cost
    is the robust one of ``loss`` (``(ROBUST_LOSS, ROBUST_THRESHOLD)``, :func:`lunaralbedo.model.registration.robust_cost`)
    with each image's residual scale taken at the level's start; its steps are reweighted Gauss-Newton ones.
    A step is taken when the mean cost does not grow (the observations near image edges change with the shifts);
    the level ends when no shift moves by :data:`STOP_PX` of its pixels (``level_px``, metres per image)."""
    scales = reg.residual_scales(obs, exposure, reg.albedo(obs, exposure, lv.n_grid), lv.n_grid)
    a = reg.robust_albedo(obs, exposure, lv.n_grid, scales, *loss)
    q, n = reg.robust_cost(obs, exposure, a, scales, *loss)
    damping, it, evals = 1e-3, 0, 0
    for it in range(1, ITERATIONS + 1):
        if obs and obs[0].d_east is None:
            obs = lv.observations(images, shifts)  # the accepted step's, now with the derivatives
        normal = reg.normal_equations(reg.reweighted(obs, exposure, a, scales, *loss), exposure, a, lv.n_grid)
        accepted = False
        for _ in range(8):
            delta = reg.step(normal, exposure, damping)
            t_new = exposure + delta[:, 0]
            t_new = np.where(t_new > 0, t_new, exposure * np.exp(delta[:, 0] / exposure))
            s_new = np.clip(shifts + delta[:, 1:], -max_m[:, None], max_m[:, None])
            obs_new = lv.observations(images, s_new, derivatives=False)
            a_new = reg.robust_albedo(obs_new, t_new, lv.n_grid, scales, *loss)
            q_new, n_new = reg.robust_cost(obs_new, t_new, a_new, scales, *loss)
            evals += 1
            if q_new / max(n_new, 1) <= q / max(n, 1):
                moved = np.max(np.abs(s_new - shifts) / level_px[:, None])
                shifts, exposure, obs, a, q, n = s_new, t_new, obs_new, a_new, q_new, n_new
                damping, accepted = max(damping / 10, 1e-7), True
                break
            damping *= 10
        if not accepted or moved < STOP_PX:
            break
    return shifts, exposure, obs, a, q / max(n, 1), it, evals


def register_scene(scene: Scene, checkpoint: Path, resume: bool, timings: dict | None = None) -> Scene:
    """The scene with its images registered: the shifts of a resumed run's checkpoint (when it is this scene's),
    else :func:`estimate`'s, kept in ``checkpoint/registration/`` (``registration.json``, ``image_offsets.csv``);
    ``timings["register"]`` gets the seconds it took."""
    t0 = time.perf_counter()
    folder = Path(checkpoint) / FOLDER
    state = folder / "registration.json"
    fp = scene.fingerprint()
    r = None
    if resume and state.exists():
        saved = json.loads(state.read_text())
        if saved.get("fingerprint") == fp:
            r = Registration.from_dict(saved["registration"])
    if r is None:
        r = estimate(scene)
        folder.mkdir(parents=True, exist_ok=True)
        write_offsets_csv(folder / "image_offsets.csv", r)
        atomic_write_text(state, json.dumps({"fingerprint": fp, "registration": r.to_dict()}) + "\n")
    if timings is not None:
        timings["register"] = time.perf_counter() - t0
    return shifted_scene(scene, r.offsets_m)


def finish(checkpoint: Path, out: Path) -> dict | None:
    """Move ``image_offsets.csv`` into OUTDIR; the report's ``registration`` entry (None when not registered)."""
    folder = Path(checkpoint) / FOLDER
    if not (folder / "registration.json").exists():
        return None
    r = Registration.from_dict(json.loads((folder / "registration.json").read_text())["registration"])
    (folder / "image_offsets.csv").replace(Path(out) / "image_offsets.csv")
    return {"pixel_factor": r.factor, "levels": r.levels,
            "offsets_px": {k: (o / p).round(4).tolist() for k, o, p in zip(r.keys, r.offsets_m, r.pixel_m)}}
