"""Forward model: render a scene from a known albedo, DEM, Sun/spacecraft geometry and exposures.

The scene is written in the exact input contract of ``lunaralbedo solve``:

* ``DRG/<KEY>_drg.tif`` — uint8 gray + alpha band (255 = data), geographic Moon CRS;
* ``DEM/dem.tif`` — float32 heights in metres above the 1737.4 km sphere;
* ``meta/sunpos.txt``, ``meta/spacecraftpos.txt`` — ``KEY x y z`` in km, body-fixed;
* ``settings.txt`` — a legacy settings file for the scene;
* ``truth/albedo.tif`` and ``truth/truth.json`` — the truth to compare against.

Images are :math:`I = \\mathrm{round}(A\\,T\\,R + n)` clipped to 0..255 (eq. 1's model),
with :math:`R` from the photometric model (:mod:`lunaralbedo.model.photometry`), Gaussian noise
``n`` and 8-bit quantisation.  Geometry: a strip of images along longitude near
the equator, each with its own Sun and spacecraft position.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from rasterio.transform import Affine

from .constants import MOON_RADIUS_KM
from .io.atomic import atomic_write_text
from .io.positions import write_positions
from .io.rasters import MOON_CRS, write_geotiff
from .model import geometry
from .model import photometry
from .settings import legacy_text


@dataclass
class SceneSpec:
    """Parameters of a synthetic strip (degrees, pixels, metres, km)."""

    n_images: int = 6
    image_px: int = 120  # image width (and height unless image_rows is set), pixels
    image_rows: int = 0  # image height, pixels (0: square images)
    res_deg: float = 0.01  # pixel size, degrees
    overlap: float = 0.5  # fraction of an image shared with the next
    lon0: float = 10.0  # west edge of the strip, degrees
    lat0: float = -5.0  # south edge, degrees
    exposure_spread: float = 0.4  # exposures in 1 +- spread
    reflectance_type: int = 2
    c1: float = 1.4
    c2: float = 0.5
    noise_dn: float = 1.0
    dem_relief_m: float = 600.0
    sun_incidence_deg: float = 35.0
    altitude_km: float = 100.0
    tile_size: float = 1.0
    max_num_iter: int = 10
    use_normalized_cost_fun: int = 0
    shadow_thresh: float = 10.0
    seed: int = 7

    @property
    def step_px(self) -> int:
        return max(1, int(round(self.image_px * (1 - self.overlap))))

    @property
    def rows_px(self) -> int:
        return self.image_rows or self.image_px

    @property
    def width_px(self) -> int:
        return self.image_px + self.step_px * (self.n_images - 1)


def _features(extent, per_square_degree, seed):
    """Random blobs ``(cx, cy, r, sign)`` over ``extent`` (lon_min, lon_max, lat_min, lat_max), degrees."""
    rng = np.random.default_rng(seed)
    area = (extent[1] - extent[0]) * (extent[3] - extent[2])
    n = max(3, int(round(per_square_degree * area)))
    return [(rng.uniform(extent[0], extent[1]), rng.uniform(extent[2], extent[3]), rng.uniform(0.05, 0.2), rng.choice([-1.0, 1.0]))
            for _ in range(n)]


def _near(features, lon, lat, reach):
    """The features within ``reach`` radii of the window (the others add less than 1e-5 there)."""
    lo0, lo1, la0, la1 = np.min(lon), np.max(lon), np.min(lat), np.max(lat)
    return [f for f in features if lo0 - reach * f[2] <= f[0] <= lo1 + reach * f[2] and la0 - reach * f[2] <= f[1] <= la1 + reach * f[2]]


def truth_albedo(lon, lat, extent, seed=3):
    """A textured albedo field (dimensionless, 0.3..1.8) of lon/lat (degrees) over ``extent``.

    A pure function of position: any window of the scene can be evaluated alone.
    """
    rng = np.random.default_rng(seed)
    a = np.ones(np.broadcast(lon, lat).shape, dtype=np.float64)
    for _ in range(6):
        kx, ky = rng.uniform(2, 9, 2)
        ph = rng.uniform(0, 2 * np.pi, 2)
        a += 0.06 * np.sin(kx * lon + ph[0]) * np.cos(ky * lat + ph[1])
    for cx, cy, r, sign in _near(_features(extent, 4.0, seed + 100), lon, lat, 5):  # bright ejecta / dark patches
        a += (0.3 if sign > 0 else -0.25) * np.exp(-((lon - cx) ** 2 + (lat - cy) ** 2) / (2 * r * r))
    return np.clip(a, 0.3, 1.8)


def truth_dem(lon, lat, extent, relief_m, seed=5):
    """Heights (metres above the 1737.4 km sphere) with gentle hills and craters over ``extent``."""
    h = relief_m * 0.3 * np.sin(2.5 * lon) * np.cos(3.1 * lat)
    for cx, cy, r, _ in _near(_features(extent, 2.5, seed), lon, lat, 3):
        d2 = ((lon - cx) ** 2 + (lat - cy) ** 2) / (r * r)
        h = h + relief_m * (-np.exp(-d2 * 2) + 0.4 * np.exp(-((np.sqrt(d2) - 1) ** 2) * 8))
    return h


def _write_field(path: Path, fn, transform: Affine, shape: tuple[int, int], nodata=None, chunk: int = 512) -> None:
    """Write ``fn(lon, lat)`` (float32) over a grid in column chunks, atomically."""
    import rasterio
    from rasterio.windows import Window

    from .io.atomic import atomic_path

    h, w = shape
    with atomic_path(path) as tmp:
        profile = dict(driver="GTiff", width=w, height=h, count=1, dtype="float32", crs=MOON_CRS, transform=transform,
                       nodata=nodata, compress="deflate", tiled=True)
        with rasterio.open(tmp, "w", **profile) as dst:
            for c0 in range(0, w, chunk):
                cw = min(chunk, w - c0)
                lon, lat = geometry.lonlat_grid(transform @ Affine.translation(c0, 0), (h, cw))
                dst.write(fn(lon, lat).astype(np.float32), 1, window=Window(c0, 0, cw, h))


def _sun_and_spacecraft(spec: SceneSpec, k: int, lon_c: float, lat_c: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Sun 1 AU away at the given incidence from the east-west plane; spacecraft above the centre."""
    inc = np.radians(spec.sun_incidence_deg + rng.uniform(-3, 3))
    up = geometry.body_fixed(lon_c, lat_c, 0.0) / MOON_RADIUS_KM
    east = np.array([-np.sin(np.radians(lon_c)), np.cos(np.radians(lon_c)), 0.0])
    sun_dir = np.cos(inc) * up + np.sin(inc) * east
    sun = sun_dir * 1.496e8
    off = rng.uniform(-0.08, 0.08, 2)  # a little off-nadir, degrees of arc
    sc = geometry.body_fixed(lon_c + off[0], lat_c + off[1], spec.altitude_km * 1000.0)
    return sun, sc


def render_scene(out_dir: str | Path, spec: SceneSpec | None = None) -> dict:
    """Render the scene of ``spec`` into ``out_dir`` (see module docstring); return the truth."""
    spec = spec or SceneSpec()
    out = Path(out_dir)
    rng = np.random.default_rng(spec.seed)
    res = spec.res_deg
    width, height = spec.width_px, spec.rows_px
    # Global truth grid, with a margin of 8 px for the DEM; evaluated window by window.
    m = 8
    gt = Affine(res, 0, spec.lon0 - m * res, 0, -res, spec.lat0 + height * res + m * res)
    extent = (spec.lon0, spec.lon0 + width * res, spec.lat0, spec.lat0 + height * res)
    def dem_fn(lo, la):
        return truth_dem(lo, la, extent, spec.dem_relief_m)

    def albedo_fn(lo, la):
        return truth_albedo(lo, la, extent)

    _write_field(out / "DEM" / "dem.tif", dem_fn, gt, (height + 2 * m, width + 2 * m), nodata=-32767.0)
    _write_field(out / "truth" / "albedo.tif", albedo_fn, gt @ Affine.translation(m, m), (height, width))
    u = np.linspace(-1, 1, spec.n_images)
    exposures = 1.0 + spec.exposure_spread * rng.permutation(u)
    # Scale so the brightest pixels stay below 255: DN = gain * A * T * R.
    gain = 120.0
    sun_pos, sc_pos, keys = {}, {}, []
    for k in range(spec.n_images):
        key = f"SIM-IMG-{k:03d}"
        c0 = m + k * spec.step_px
        transform = gt @ Affine.translation(c0, m)
        # the image window plus one pixel all round, so normals use the same neighbours as the solver
        lon, lat = geometry.lonlat_grid(transform @ Affine.translation(-1, -1), (height + 2, spec.image_px + 2))
        pts = geometry.body_fixed(lon, lat, dem_fn(lon, lat))
        normals = geometry.dem_normals(pts)[1:-1, 1:-1]
        pts, lon, lat = pts[1:-1, 1:-1], lon[1:-1, 1:-1], lat[1:-1, 1:-1]
        sun, sc = _sun_and_spacecraft(spec, k, float(lon.mean()), float(lat.mean()), rng)
        ci, ce, al = geometry.illumination(pts, normals, sun, sc)
        model = photometry.get(spec.reflectance_type)
        r = model.reflectance(ci, ce, al, (spec.c1, spec.c2)[: len(model.parameters)])
        r = np.where(ci >= 0.3, r, 0.0)
        signal = gain * albedo_fn(lon, lat) * exposures[k] * r
        dn = np.clip(np.round(signal + rng.normal(0, spec.noise_dn, signal.shape)), 0, 255).astype(np.uint8)
        alpha = np.full(dn.shape, 255, np.uint8)
        write_geotiff(out / "DRG" / f"{key}_drg.tif", np.stack([dn, alpha]), transform, MOON_CRS)
        sun_pos[key], sc_pos[key] = sun, sc
        keys.append(key)
    write_positions(out / "meta" / "sunpos.txt", sun_pos)
    write_positions(out / "meta" / "spacecraftpos.txt", sc_pos)
    box = (spec.lon0, spec.lon0 + width * res, spec.lat0, spec.lat0 + height * res)
    geometry_files = spec.reflectance_type != 0
    settings = legacy_text(
        {
            "DRG_DIR": "DRG",
            "DEM_DIR": "DEM" if geometry_files else None,
            "SUN_POSITION_FILE": "meta/sunpos.txt" if geometry_files else None,
            "SPACECRAFT_POSITION_FILE": "meta/spacecraftpos.txt" if geometry_files else None,
            "NUM_PROCESSES": 1,
            "TILE_SIZE": spec.tile_size,
            "SIMULATION_BOX": box,
            "REFLECTANCE_TYPE": spec.reflectance_type,
            "SHADOW_THRESH": spec.shadow_thresh,
            "SHADOW_TYPE": 1,
            "TR_CONST": 1.5,
            "PHASE_COEFF_C1": spec.c1,
            "PHASE_COEFF_C2": spec.c2,
            "MAX_NUM_ITER": spec.max_num_iter,
            "USE_WEIGHTS": 1,
            "USE_NORMALIZED_COST_FUN": spec.use_normalized_cost_fun,
            "COMPUTE_ERRORS": 1,
        },
        f"Synthetic scene rendered by lunaralbedo.simulate (seed {spec.seed})",
    )
    atomic_write_text(out / "settings.txt", settings)
    truth = {"keys": keys, "exposure": exposures.tolist(), "gain": gain, "spec": asdict(spec)}
    atomic_write_text(out / "truth" / "truth.json", json.dumps(truth, indent=2))
    return truth


def score(result_dir: str | Path, scene_dir: str | Path) -> dict:
    """Compare a solve's outputs with the truth of a rendered scene.

    Returns ``albedo_rel_rmse`` (relative RMSE of the albedo after the one global
    scale that A*T leaves free, least squares), ``exposure_max_rel_err`` (largest
    relative exposure error after normalising both to the same geometric mean),
    ``coverage`` (fraction of truth pixels with a solved albedo).
    """
    import glob

    import rasterio
    from rasterio.merge import merge

    from .io.outputs import read_exposure_csv

    result_dir, scene_dir = Path(result_dir), Path(scene_dir)
    truth = json.loads((scene_dir / "truth" / "truth.json").read_text())
    with rasterio.open(scene_dir / "truth" / "albedo.tif") as t:
        ta, tt, tb = t.read(1), t.transform, t.bounds
    files = sorted(glob.glob(str(result_dir / "albedo" / "*.tif")))
    mos, _ = merge(files, bounds=tb, res=(tt.a, -tt.e), nodata=np.nan, dtype="float32")
    a = mos[0]
    ok = np.isfinite(a) & np.isfinite(ta)
    s = np.sum(a[ok] * ta[ok]) / np.sum(a[ok] ** 2)
    rel = (s * a[ok] - ta[ok]) / ta[ok]
    est = read_exposure_csv(result_dir / "exposure.csv")
    if "images" in truth:  # the sample mission of tools/make_sample_data.py
        true_exp = {k: v["exposure"] for k, v in truth["images"].items()}
    else:
        true_exp = dict(zip(truth["keys"], truth["exposure"]))
    keys = sorted(set(true_exp) & set(est))
    te = np.array([true_exp[k] for k in keys])
    ratio = np.array([est[k] for k in keys]) / te
    ratio /= np.exp(np.mean(np.log(ratio)))
    return {
        "albedo_rel_rmse": float(np.sqrt(np.mean(rel**2))),
        "exposure_max_rel_err": float(np.max(np.abs(ratio - 1))),
        "coverage": float(ok.mean()),
        "images_compared": len(keys),
    }
