"""Item 13 of ``make bench``: the floor of the strip's prepare step on one CPU (the "prepare <= 50 ns" target of docs/performance-history.md).

Whatever the code, preparing the strip of item 6 must at least

1. decode the DRG windows it reads (GDAL; two bands each: value and validity);
2. decode the DEM, once (the cheapest possible: the whole file in one read);
3. compute, per observation, the geometry the outputs keep bit for bit: the point and the
   normal from the DEM, cos i, cos e and the phase angle (3 square roots, 6 IEEE divisions and
   an arc cosine; a minimal numba loop here, no masks, no compaction);
4. keep its observations for the iterations: 16 bytes each (value, weight, two model layers),
   in memory the process has not used yet (into a new file, or into new anonymous memory:
   whichever is cheaper);
5. write the DEM and weight-sum tiles, which are outputs (the cheapest of the solver's
   GeoTIFF settings, LERC and no compression).

The floor is also given with the tiles written as the solver writes them (ZSTD 1 with a
predictor, whose files are 6-10 x smaller than uncompressed ones), and with the solver's own
features added at their cheapest (:func:`features_kernels`): the bracket of eq. 2 (a stored
model layer), the reflectance and the two logarithms of the exposure initialisation, and a cast-
shadow test by one sweep along each row (exact only for a Sun on the rows, as the strip's is).

Each part is measured alone, best of three, in a child process confined to one CPU, and
divided by the strip's observations.  Also measured: the price this machine asks for memory a
process touches for the first time, against the same memory touched again (a virtual machine
whose guest hands freed memory back to its host pays the first far more: docs/performance.md).
Needs item 6's scene and its output tiles (``bench_out/out_strip_after``): run item 6 first.
"""
from __future__ import annotations

import itertools
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def best(f, reps: int = 3) -> float:
    """Least thread CPU seconds of ``reps`` calls of ``f`` after one warm-up call (system time included)."""
    f()
    ts = []
    for _ in range(reps):
        t0 = time.thread_time()
        f()
        ts.append(time.thread_time() - t0)
    return min(ts)


def memory_price(mib: int = 512) -> dict:
    """ns per byte to touch ``mib`` MiB never touched by this process, and to touch the same memory again."""
    t0 = time.thread_time()
    a = np.ones(mib << 18, np.float32)
    first = time.thread_time() - t0
    t0 = time.thread_time()
    a.fill(2.0)
    again = time.thread_time() - t0
    return {"first_touch_ns_per_byte": 1e9 * first / a.nbytes, "again_ns_per_byte": 1e9 * again / a.nbytes}


def geometry_kernel():
    from numba import njit

    from lunaralbedo.model import vacos
    from lunaralbedo.model.geometry import _cosines_at, _normal_at, _point_at

    @njit(cache=True, nogil=True, error_model="numpy")
    def geometry(dem, cl, sl, cb, sb, radius, sun, sc, n_obs, strip, ci, ce, al):
        """cos i, cos e and the phase angle of ``n_obs`` pixels of ``dem`` (m), taken in column strips of ``strip``
        pixels (a DRG window's width) from the top (again when it has fewer): the solver's arithmetic (points,
        normals by central differences, eqs. 4-5, the arc cosine) in branch-free loops over whole rows of a strip,
        with no mask, no candidate test and no compaction."""
        h, w = dem.shape
        pts = np.empty((3, 3, strip + 2))
        o = 0
        while o < n_obs:
            for j0 in range(1, w - 1 - strip, strip):
                for r in range(1, h - 1):
                    if o >= n_obs:
                        return
                    for k in range(0 if r == 1 else 2, 3):  # a ring of three rows of points: one new row a row
                        q = (r - 1 + k) % 3
                        for j in range(strip + 2):
                            pts[q, 0, j], pts[q, 1, j], pts[q, 2, j] = _point_at(
                                dem[r - 1 + k, j0 - 1 + j], radius, cb[r - 1 + k], sb[r - 1 + k], cl[j0 - 1 + j], sl[j0 - 1 + j])
                    pn, pa, ps = pts[(r - 1) % 3], pts[r % 3], pts[(r + 1) % 3]
                    m = min(strip, n_obs - o)
                    for c in range(m):
                        nx, ny, nz = _normal_at(pa[0, c + 1], pa[1, c + 1], pa[2, c + 1], ps[0, c + 1], ps[1, c + 1],
                                                ps[2, c + 1], pn[0, c + 1], pn[1, c + 1], pn[2, c + 1],
                                                pa[0, c + 2], pa[1, c + 2], pa[2, c + 2], pa[0, c], pa[1, c], pa[2, c])
                        ci[o + c], ce[o + c], al[o + c] = _cosines_at(pa[0, c + 1], pa[1, c + 1], pa[2, c + 1], nx, ny,
                                                                      nz, sun[0], sun[1], sun[2], sc[0], sc[1], sc[2])
                    for c in range(m):
                        al[o + c] = vacos.acos(al[o + c])
                    o += m

    return geometry


def features_kernels():
    """Numba loops for what the solver adds to the floor, each at its cheapest (the same arithmetic as the solver's)."""
    from numba import njit

    from lunaralbedo.model.photometry import vexp
    from lunaralbedo.model.photometry.lunar_lambert import _DEGREES, _bracket_nb, _polynomial_nb

    @njit(cache=True, nogil=True, error_model="numpy")
    def bracket(ci, ce, al, out):
        """Eq. 2's bracket with L(alpha), the model layer the observations keep (float32, as stored)."""
        for o in range(out.shape[0]):
            out[o] = _bracket_nb(ci[o], ce[o], _polynomial_nb(al[o] * _DEGREES))

    @njit(cache=True, nogil=True, error_model="numpy")
    def reflectance(g, al, c1, c2, out):
        """R = (exp(-c1 alpha) + c2) G (eq. 2) for the exposure initialisation (float32, vectorised)."""
        for o in range(out.shape[0]):
            out[o] = (vexp.exp(-c1 * al[o]) + c2) * g[o]

    @njit(cache=True, nogil=True, error_model="numpy")
    def sweep(dem, n_obs, strip, margin, drop, shadow):
        """Cast shadows of ``n_obs`` pixels in column strips of ``strip`` px, a Sun in the east: each row swept
        from ``margin`` px beyond the strip's Sun side, the horizon falling ``drop`` m a pixel (no curvature)."""
        h, w = dem.shape
        o = 0
        while o < n_obs:
            for j0 in range(1, w - margin - strip, strip):
                for r in range(h):
                    if o >= n_obs:
                        return
                    m = min(strip, n_obs - o)
                    top = -np.inf
                    for j in range(j0 + strip + margin - 1, j0 - 1, -1):
                        z = dem[r, j]
                        top -= drop
                        if j < j0 + m:
                            shadow[o + j - j0] = z < top
                        top = max(top, z)
                    o += m

    return bracket, reflectance, sweep


def features(dem, ci, ce, al, n_obs: int, drop_m: float) -> dict:
    """Thread CPU seconds of each feature the solver adds to the floor, at its cheapest (:func:`features_kernels`)."""
    bracket, reflectance, sweep = features_kernels()
    g, r, a32 = np.empty(n_obs, np.float32), np.empty(n_obs, np.float32), al.astype(np.float32)
    values = np.random.default_rng(15).random(n_obs, dtype=np.float32) * 200 + 10  # DN > 0
    logs, logs2 = np.empty(n_obs, np.float32), np.empty(n_obs, np.float32)

    def log_sums():  # log(DN) - log(R), float32 (NumPy's vectorised logarithm), summed in float64
        np.log(values, out=logs)
        np.log(r, out=logs2)
        np.subtract(logs, logs2, out=logs)
        return float(logs.sum(dtype=np.float64))

    shadow = np.empty(n_obs, np.bool_)
    got = {"the model layer (eq. 2's bracket)": best(lambda: bracket(ci, ce, al, g))}
    got["the initialisation's reflectance and logarithms"] = (
        best(lambda: reflectance(g, a32, np.float32(1.4), np.float32(0.5), r)) + best(log_sums))
    got["cast shadows (a sweep along each row)"] = best(lambda: sweep(dem, n_obs, 320, 16, drop_m, shadow))
    return got


def child(d: Path, out: Path, n_obs: int) -> dict:
    import rasterio
    from rasterio.windows import Window

    from lunaralbedo.constants import MOON_RADIUS_KM
    from lunaralbedo.engine import observations as ob
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.io.drgs import pixels_on_grid
    from lunaralbedo.engine.tilework import OUTPUT_OPTIONS
    from lunaralbedo.io.geotiff import geotiff_profile, write_rows
    from lunaralbedo.model import geometry
    from lunaralbedo.model.cast_shadows import sun_elevation
    from lunaralbedo.model.geometry import lonlat_axes
    from lunaralbedo.settings import load_settings

    figures = memory_price()
    scene = build_scene(load_settings(d / "settings.txt"), False, map_fn=lambda f, xs: list(map(f, xs)))
    parts = {}

    def drg_windows():
        for t, tile in enumerate(scene.tiles):
            for k, win in ob.tile_windows(scene, t):
                if win is None:
                    continue
                info = scene.images[k]
                r, _, c, _ = pixels_on_grid(info, tile.transform, (tile.height, tile.width), scene.crs)
                with rasterio.open(info.path) as ds:
                    ds.read((1, 2), window=Window(win[2] - c, win[0] - r, win[3] - win[2], win[1] - win[0]))

    def dem_once():
        for info in scene.dems:
            with rasterio.open(info.path) as ds:
                ds.read(1)

    parts["DRG windows decoded"] = best(drg_windows)
    parts["DEM decoded once"] = best(dem_once)
    with rasterio.open(scene.dems[0].path) as ds:  # heights (m), no-data as NaN (which the points count as 0)
        dem = ds.read(1, masked=True).astype(np.float32).filled(np.nan)
        lon, lat = lonlat_axes(ds.transform, ds.shape)
        res_lon = abs(ds.transform.a)
    trig = (np.cos(np.radians(lon)), np.sin(np.radians(lon)), np.cos(np.radians(lat)), np.sin(np.radians(lat)))
    sun, sc = np.asarray(scene.sun[0], np.float64), np.asarray(scene.spacecraft[0], np.float64)
    ci, ce, al = (np.empty(n_obs) for _ in range(3))  # float64, as the solver's candidates
    kernel = geometry_kernel()
    parts["geometry (3 sqrt, 6 divisions, arc cosine)"] = best(
        lambda: kernel(dem, *trig, MOON_RADIUS_KM, sun, sc, n_obs, 320, ci, ce, al))
    lon_c, lat_c = float(lon.mean()), float(lat.mean())
    px_m = 1000 * math.radians(res_lon) * MOON_RADIUS_KM * math.cos(math.radians(lat_c))  # a pixel along the rows (m)
    elevation = float(sun_elevation(geometry.body_fixed(lon_c, lat_c, 0.0), sun))
    # the observations kept: 16 bytes each into memory this process has not touched
    src = np.ones(4 * n_obs, np.float32)
    tmp = out / "floor_tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)

    held = []

    def new_file():
        f = tmp / f"obs{len(held)}.npy"
        np.save(f, src)
        held.append(f)  # kept until the end: the next call gets page-cache pages not used before

    def new_memory():
        dst = np.empty_like(src)
        np.copyto(dst, src)
        held.append(dst)  # likewise

    cold = {"cache": min(best(new_file), best(new_memory))}
    # the DEM and weight-sum tiles (outputs), as the solve wrote them
    tiles = []
    for kind, path in ((kind, p) for kind in ("DEM", "weightsSum") for p in sorted((out / "out_strip_after" / kind).glob("*.tif"))):
        with rasterio.open(path) as ds:
            tiles.append((kind, ds.read(1), ds.transform, ds.crs))
    calls = itertools.count()

    def write_tiles(options, new: bool):
        def go():  # new files each call (kept until the end, as a solve writes them), or the same files again
            call = next(calls) if new else "again"
            for i, (kind, a, transform, crs) in enumerate(tiles):
                if options is None:  # the solver's own settings, tile by kind
                    prof = geotiff_profile(1, *a.shape, "float32", transform, crs, **OUTPUT_OPTIONS[kind])
                else:
                    prof = geotiff_profile(1, *a.shape, "float32", transform, crs, compress=None)
                    prof.update(options)
                with rasterio.open(tmp / f"t{call}_{i}.tif", "w", **prof) as ds:
                    write_rows(ds, a[None], 0)  # as the solver does: blocks of no data only left to GDAL
        return go

    options = {SOLVERS: None,
               "LERC lossless": dict(compress="lerc", max_z_error=0), "no compression": {}}
    tiles_cold = {k: best(write_tiles(v, True)) for k, v in options.items()}
    warm = {"cache": best(lambda: np.save(tmp / "obs0.npy", src))}  # pages freed and taken again at once
    tiles_warm = {k: best(write_tiles(v, False)) for k, v in options.items()}
    del held[:]
    shutil.rmtree(tmp, ignore_errors=True)
    # the features last: the memory they free would otherwise serve the "new pages" above
    extra = features(dem, ci, ce, al, n_obs, px_m * math.tan(elevation))
    figures["features_ns_per_obs"] = {k: 1e9 * v / n_obs for k, v in extra.items()}
    del ci, ce, al
    cold["tiles"], warm["tiles"] = min(tiles_cold.values()), min(tiles_warm.values())
    figures["tile_options_ns_per_obs"] = {k: {"new pages": 1e9 * tiles_cold[k] / n_obs, "pages again": 1e9 * tiles_warm[k] / n_obs}
                                          for k in options}
    names = {"cache": "observations kept (16 B each)", "tiles": "DEM and weight-sum tiles written (cheapest option)"}
    for label, got in (("new pages", cold), ("pages again", warm)):
        these = {**{k: 1e9 * v / n_obs for k, v in parts.items()}, **{names[k]: 1e9 * v / n_obs for k, v in got.items()}}
        figures[label] = {"parts_ns_per_obs": these, "floor_ns_per_obs": sum(these.values())}
    return figures


#: The tiles written as the solver writes them (``tilework.OUTPUT_OPTIONS``).
SOLVERS = "the solver's (ZSTD 1; floating-point predictor on the DEM, horizontal on the weight sums)"


def with_solver_tiles(got: dict, label: str) -> float:
    """The floor of ``label`` (new pages, pages again) with the DEM and weight-sum tiles written as the solver writes
    them (:data:`SOLVERS`: 6-10 x smaller files) instead of the cheapest way measured."""
    parts = got[label]["parts_ns_per_obs"]
    cheapest = parts["DEM and weight-sum tiles written (cheapest option)"]
    return got[label]["floor_ns_per_obs"] - cheapest + got["tile_options_ns_per_obs"][SOLVERS][label]


def prepare_floor(root: Path, q: bool, figures: dict) -> None:
    """Item 13 (run by run_all.py): the child on one CPU, its figures printed and stored."""
    d = root / ("strip_400" if q else "strip_2000")  # item 6's scene
    if not ((d / "spec.json").is_file() and (root / "out_strip_after" / "DEM").is_dir()):
        print("13. prepare floor: skipped (run item 6 first: it makes the strip's scene and output tiles)", flush=True)
        return
    spec = json.loads((d / "spec.json").read_text())
    n_obs = spec["n_images"] * spec["image_px"] * spec["image_rows"]
    first = min(os.sched_getaffinity(0))
    res = subprocess.run([sys.executable, __file__, str(d), str(root), str(n_obs)], capture_output=True, text=True,
                         preexec_fn=lambda: os.sched_setaffinity(0, {first}))
    if res.returncode:
        raise RuntimeError(res.stderr[-3000:])
    got = json.loads(res.stdout.strip().splitlines()[-1])
    figures["prepare_floor"] = got
    print(f"13. memory: first touch {got['first_touch_ns_per_byte']:.2f} ns/byte, touched again "
          f"{got['again_ns_per_byte']:.2f} ns/byte", flush=True)
    for k, v in got["tile_options_ns_per_obs"].items():
        print(f"13.   DEM and weight-sum tiles, {k}: {v['new pages']:.1f} ns/obs into new pages, "
              f"{v['pages again']:.1f} into pages again", flush=True)
    one = figures.get("strip", {}).get("after_one_cpu", {}).get("prepare_ns_per_obs")
    for label in ("new pages", "pages again"):
        parts = ", ".join(f"{k} {v:.1f}" for k, v in got[label]["parts_ns_per_obs"].items())
        print(f"13. strip, prepare floor on one CPU, {label}: {got[label]['floor_ns_per_obs']:.1f} ns/obs ({parts})", flush=True)
    own = {label: with_solver_tiles(got, label) for label in ("new pages", "pages again")}
    figures["prepare_floor"]["with_solver_tiles_ns_per_obs"] = own
    print(f"13. strip, the same floor with the tiles as the solver writes them: "
          f"{own['new pages']:.1f} ns/obs into new pages, {own['pages again']:.1f} into pages again", flush=True)
    feats = got["features_ns_per_obs"]
    added = sum(feats.values())
    figures["prepare_floor"]["with_features_ns_per_obs"] = {k: v + added for k, v in own.items()}
    print("13. the solver's features at their cheapest: " + ", ".join(f"{k} {v:.1f}" for k, v in feats.items())
          + f"; the floor with them and the solver's tiles: {own['new pages'] + added:.1f} ns/obs into new pages, "
          f"{own['pages again'] + added:.1f} into pages again", flush=True)
    print("13. (target 50 ns/obs" + (f"; the solve's prepare stage on one CPU {one:.0f})" if one else ")"), flush=True)


if __name__ == "__main__":
    print(json.dumps(child(Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]))))
