"""The DRG strip: a scene rendered by the forward model (:mod:`.forward`) in the input contract of ``solve``.

The scene is written in the exact input contract of ``lunaralbedo solve``:

* ``DRG/<KEY>_drg.tif`` — uint8 gray + alpha band (255 = data), geographic Moon CRS;
* ``DEM/dem.tif`` — float32 heights in metres above the 1737.4 km sphere;
* ``meta/sunpos.txt``, ``meta/spacecraftpos.txt`` — ``KEY x y z`` in km, body-fixed;
* ``settings.txt`` — a legacy settings file for the scene;
* ``truth/albedo.tif`` and ``truth/truth.json`` — the truth to compare against.

Images are :math:`I = \\mathrm{round}(A\\,T\\,R + n)` clipped to 0..255 (eq. 1's model),
with :math:`R` from the photometric model (:mod:`lunaralbedo.model.photometry`), Gaussian noise
``n`` and 8-bit quantisation.  Geometry: a strip of images along longitude near
the equator, each with its own Sun and spacecraft position.  The strip may straddle
±180° (``SceneSpec.centred(180.0)``): longitudes are continuous, and ``wrap_lon``
writes the DRGs east of 180° with -180..180 file longitudes, as a mission archive would.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from rasterio.transform import Affine

from ..constants import MOON_RADIUS_KM
from ..engine.photometry import bind
from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..io.positions import write_positions
from ..io.rasters import MOON_CRS
from ..io.geotiff import write_geotiff
from ..model import geometry
from ..model import photometry
from ..model.cast_shadows import cast_shadow_mask, shadow_reach_km
from ..settings import legacy_text, model_entry
from . import defects, forward
from .fields import truth_albedo, truth_dem
from .truth import render_into, write_truth


@dataclass
class SceneSpec:
    """Parameters of a synthetic strip (degrees, pixels, metres, km)."""

    n_images: int = 6
    image_px: int = 120  # image width (and height unless image_rows is set), pixels
    image_rows: int = 0  # image height, pixels (0: square images)
    res_deg: float = 0.01  # pixel size, degrees
    overlap: float = 0.5  # fraction of an image shared with the next
    lon0: float = 10.0  # west edge of the strip, degrees (continuous: may pass 180)
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
    gain: float = 120.0  # DN per unit of A T R
    fresh_craters: float = 0.0  # fresh bowl craters per square degree (simulate.fresh_craters)
    sun_azimuths: tuple[float, ...] = (90.0,)  # degrees clockwise from north, cycled over the images
    cast_shadows: bool = False  # render cast shadows (and attached ones) lit by scattered light only
    scatter: float = 0.25  # shadows receive this fraction of the flat ground's signal
    wrap_lon: bool = False  # DRGs east of 180 deg written at -180..180, SIMULATION_BOX as lon0:east-360
    film_contrast: float = 0.0  # > 0: DN through the S-shaped film curve of response.synthetic (Kim et al.)
    film_mid: float = 0.5  # exposure A*T*R at the curve's mid point
    misregister_px: float = 0.0  # each DRG's stated georeference off by up to this many pixels east and north
    haze_dn: tuple[float, float] = (0.0, 0.0)  # additive haze per image, uniform in this range, DN (simulate.defects)
    outlier_fraction: float = 0.0  # fraction of each image's pixels in hot spots and dropout rows (simulate.defects)
    calibrated: bool = False  # float32 I/F DRGs (A R + noise / gain, haze / gain), every exposure 1
    dem_blur_px: float = 0.0  # > 0: DEM/dem.tif is the truth blurred (Gaussian, sigma in pixels); truth/dem.tif the truth

    @classmethod
    def centred(cls, lon_center: float, lat_center: float = 0.0, **kwargs) -> "SceneSpec":
        """A spec whose strip is centred on ``(lon_center, lat_center)`` degrees."""
        spec = cls(**kwargs)
        spec.lon0 = lon_center - spec.width_px * spec.res_deg / 2
        spec.lat0 = lat_center - spec.image_px * spec.res_deg / 2
        return spec

    def validate(self) -> "SceneSpec":
        """:class:`InputError` naming the parameter (and its ``simulate`` option) when a value cannot make a scene."""
        for name, (option, lo, hi, lo_open) in _LIMITS.items():
            v = getattr(self, name)
            bad = not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v)
            bad = bad or (v <= lo if lo_open else v < lo) or (hi is not None and v >= hi)
            if bad:
                rng = f"{'>' if lo_open else '>='} {lo:g}" + (f" and < {hi:g}" if hi is not None else "")
                raise InputError(f"{option} ({name}) must be a number {rng}, got {v!r}")
        lo, hi = self.haze_dn
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
            raise InputError(f"--haze (haze_dn) must be LO:HI DN with 0 <= LO <= HI, got {lo!r}:{hi!r}")
        if not 0 <= self.outlier_fraction < 0.5:
            raise InputError(f"--outliers (outlier_fraction) must be a number >= 0 and < 0.5, got {self.outlier_fraction!r}")
        if self.width_px * self.res_deg > 360.0 or self.lat0 < -90.0 or self.lat0 + self.image_px * self.res_deg > 90.0:
            raise InputError(f"--res/--size/--images: the strip ({self.width_px} x {self.image_px} pixels of "
                             f"{self.res_deg:g} deg from lon {self.lon0:g}, lat {self.lat0:g}) does not fit on the Moon")
        return self

    @property
    def step_px(self) -> int:
        return max(1, int(round(self.image_px * (1 - self.overlap))))

    @property
    def rows_px(self) -> int:
        return self.image_rows or self.image_px

    @property
    def width_px(self) -> int:
        return self.image_px + self.step_px * (self.n_images - 1)


#: name -> (simulate option, lower limit, upper limit (exclusive) or None, lower limit exclusive)
_LIMITS = {
    "n_images": ("--images", 1, None, False),
    "image_px": ("--size", 8, None, False),
    "res_deg": ("--res", 0.0, None, True),
    "overlap": ("overlap", 0.0, 1.0, False),
    "exposure_spread": ("--spread", 0.0, 1.0, False),
    "noise_dn": ("--noise", 0.0, None, False),
    "tile_size": ("--tile-size", 0.0, None, True),
    "max_num_iter": ("max_num_iter", 1, None, False),
    "altitude_km": ("altitude_km", 0.0, None, True),
    "misregister_px": ("--misregister", 0.0, None, False),
    "dem_blur_px": ("--dem-blur", 0.0, None, False),
    "fresh_craters": ("--craters", 0.0, None, False),
}


def _write_field(path: Path, fn, transform: Affine, shape: tuple[int, int], nodata=None, chunk: int = 512) -> None:
    """Write ``fn(lon, lat)`` (float32) over a grid in column chunks, atomically."""
    import rasterio
    from rasterio.windows import Window

    from ..io.atomic import atomic_path

    h, w = shape
    with atomic_path(path) as tmp:
        profile = dict(driver="GTiff", width=w, height=h, count=1, dtype="float32", crs=MOON_CRS, transform=transform,
                       nodata=nodata, compress="deflate", tiled=True)
        with rasterio.open(tmp, "w", **profile) as dst:
            for c0 in range(0, w, chunk):
                cw = min(chunk, w - c0)
                lon, lat = geometry.lonlat_grid(transform @ Affine.translation(c0, 0), (h, cw))
                dst.write(fn(lon, lat).astype(np.float32), 1, window=Window(c0, 0, cw, h))


def misregistration(spec: SceneSpec) -> np.ndarray:
    """``(n_images, 2)`` pixels (east, north) by which each DRG's stated georeference is off: uniform in
    +-``misregister_px`` per component, from a generator of its own (a scene without misregistration is unchanged)."""
    if spec.misregister_px <= 0:
        return np.zeros((spec.n_images, 2))
    return np.random.default_rng([spec.seed, 4242]).uniform(-spec.misregister_px, spec.misregister_px, (spec.n_images, 2))


def offset_truth(stated_px, res_deg: float, lat_deg: float) -> dict:
    """The truth of one image's registration: the shift to ADD to its stated ground position to put it on the DEM,
    in pixels (``offset_px``: east, north) and in metres at the strip's mid latitude (``offset_east_m``,
    ``offset_north_m``); an image stated ``d`` pixels east of its true place gets ``-d``."""
    m_per_deg = np.radians(1.0) * MOON_RADIUS_KM * 1000.0
    e, n = -float(stated_px[0]), -float(stated_px[1])
    return {"offset_px": [e, n], "offset_east_m": e * res_deg * m_per_deg * float(np.cos(np.radians(lat_deg))),
            "offset_north_m": n * res_deg * m_per_deg}


def _write_blurred(path: Path, fn, transform: Affine, shape: tuple[int, int], sigma_px: float) -> None:
    """Write ``fn(lon, lat)`` blurred by a Gaussian of ``sigma_px`` pixels (evaluated 4 sigma beyond the grid, so
    the edges are blurred like the inside)."""
    from scipy.ndimage import gaussian_filter

    pad = int(np.ceil(4 * sigma_px))
    lon, lat = geometry.lonlat_grid(transform @ Affine.translation(-pad, -pad), (shape[0] + 2 * pad, shape[1] + 2 * pad))
    h = gaussian_filter(fn(lon, lat), sigma_px, mode="nearest")[pad:pad + shape[0], pad:pad + shape[1]]
    write_geotiff(path, h.astype(np.float32), transform, MOON_CRS, nodata=-32767.0)


def _sun_and_spacecraft(spec: SceneSpec, k: int, lon_c: float, lat_c: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Sun 1 AU away at the given incidence (+-3 degrees) and azimuth; spacecraft above the centre."""
    inc = spec.sun_incidence_deg + rng.uniform(-3, 3)
    sun = forward.sun_position(geometry.body_fixed(lon_c, lat_c, 0.0), spec.sun_azimuths[k % len(spec.sun_azimuths)], 90.0 - inc)
    off = rng.uniform(-0.08, 0.08, 2)  # a little off-nadir, degrees of arc
    sc = geometry.body_fixed(lon_c + off[0], lat_c + off[1], spec.altitude_km * 1000.0)
    return sun, sc


def render_scene(out_dir: str | Path, spec: SceneSpec | None = None) -> dict:
    """Render a synthetic strip of DRGs from a known Moon, in the input contract of ``solve``.

    The forward model of the PhotometryTK manual's image formation, eq. 1:
    :math:`I = \\mathrm{round}(A\\,T\\,R + n)` clipped to 0..255, with the true albedo
    :math:`A`, each image's exposure :math:`T`, the photometric model's reflectance
    :math:`R` on the true DEM and Gaussian noise :math:`n` (optionally through an
    S-shaped film response, and with cast shadows).  Writes ``DRG/<KEY>_drg.tif`` (uint8
    gray + alpha, geographic degrees), ``DEM/dem.tif`` (float32 heights, metres above
    the 1737.4 km sphere), ``meta/sunpos.txt`` and ``meta/spacecraftpos.txt`` (``KEY x
    y z``, km, Moon body-fixed), ``settings.txt`` and the truth (``truth/albedo.tif``,
    ``truth/truth.json``).  A failed render leaves no scene folder behind.

    Parameters
    ----------
    out_dir : str or Path
        Scene folder to write: new, or existing and empty.
    spec : SceneSpec, optional
        The scene: number and size of the images (pixels), pixel size and position of
        the strip (degrees, continuous longitudes), exposure spread, photometric model and
        its parameters, noise (DN), DEM relief (metres), Sun incidence (degrees),
        spacecraft altitude (km), random ``seed`` and more; default ``SceneSpec()``.

    Returns
    -------
    dict
        The truth (also ``truth/truth.json``, see :mod:`.truth`): ``reflectance_type``,
        the model's parameters by name (e.g. ``c1``, ``c2``), ``seed``, ``albedo`` and
        ``dem`` (paths relative to ``out_dir``), ``frame``, ``gain`` (DN per unit of
        :math:`A\\,T\\,R`), ``spec`` (the scene's parameters) and ``images``: per key
        ``exposure``, ``sun_km`` and ``spacecraft_km`` (km, body-fixed), ``drg``.

    Raises
    ------
    InputError
        Exit 2, before anything is written: a spec that cannot make a scene.
    OutputError
        Exit 2, before anything is written: ``out_dir`` cannot be created or is not empty.
    """
    spec = (spec or SceneSpec()).validate()
    return render_into(out_dir, lambda out: _render(out, spec))


def _render(out: Path, spec: SceneSpec) -> dict:
    rng = np.random.default_rng(spec.seed)
    res = spec.res_deg
    width, height = spec.width_px, spec.rows_px
    # Global truth grid, with a margin for the DEM (8 px, or the longest cast shadow); evaluated window by window.
    m = 8
    if spec.cast_shadows:
        reach = shadow_reach_km(2.0 * spec.dem_relief_m, np.radians(87.0 - spec.sun_incidence_deg))
        m = max(m, int(np.ceil(reach / (np.radians(res) * MOON_RADIUS_KM))) + 2)
    gt = Affine(res, 0, spec.lon0 - m * res, 0, -res, spec.lat0 + height * res + m * res)
    extent = (spec.lon0, spec.lon0 + width * res, spec.lat0, spec.lat0 + height * res)
    def dem_fn(lo, la):
        return truth_dem(lo, la, extent, spec.dem_relief_m, fresh_per_square_degree=spec.fresh_craters)

    def albedo_fn(lo, la):
        return truth_albedo(lo, la, extent)

    if spec.dem_blur_px > 0:  # the given DEM lost the relief finer than the blur; the truth is kept
        _write_field(out / "truth" / "dem.tif", dem_fn, gt, (height + 2 * m, width + 2 * m), nodata=-32767.0)
        _write_blurred(out / "DEM" / "dem.tif", dem_fn, gt, (height + 2 * m, width + 2 * m), spec.dem_blur_px)
    else:
        _write_field(out / "DEM" / "dem.tif", dem_fn, gt, (height + 2 * m, width + 2 * m), nodata=-32767.0)
    _write_field(out / "truth" / "albedo.tif", albedo_fn, gt @ Affine.translation(m, m), (height, width))
    u = np.linspace(-1, 1, spec.n_images)
    exposures = 1.0 + spec.exposure_spread * rng.permutation(u)
    if spec.calibrated:  # I/F: the calibration took the exposure out
        exposures = np.ones(spec.n_images)
    defect_rng = np.random.default_rng(spec.seed + 1000)  # its own stream: a clean scene draws as before
    haze = defect_rng.uniform(*spec.haze_dn, spec.n_images) if spec.haze_dn[1] > 0 else np.zeros(spec.n_images)
    # Scale so the brightest pixels stay below 255: DN = gain * A * T * R.
    gain = spec.gain
    model, model_files = photometry.get(spec.reflectance_type), {}
    for key, (name, text) in model.examples.items():  # the model's own files (e.g. Hapke's parameter PVL)
        atomic_write_text(out / "meta" / name, text)
        model_files[key] = f"meta/{name}"
    model = bind(model, {key: out / rel for key, rel in model_files.items()}, str(out))
    params = (spec.c1, spec.c2)[: len(model.parameters)]
    dem_all = None
    if spec.cast_shadows:
        dem_all = dem_fn(*geometry.lonlat_grid(gt, (height + 2 * m, width + 2 * m)))
    sun_pos, sc_pos, keys = {}, {}, []
    stated = misregistration(spec)
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
        r = model.reflectance(ci, ce, al, params)
        if dem_all is not None:  # shadows keep the scattered light, a fraction of the flat ground's signal
            shade = cast_shadow_mask(dem_all, gt, sun, (m, m + height, c0, c0 + spec.image_px)) | (ci <= 0)
            up = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
            flat = model.reflectance(*geometry.illumination(pts, up, sun, sc), params)
            r = np.where(shade, spec.scatter * flat, r)
        film = None
        if spec.film_contrast > 0:  # an unknown nonlinear response: DN = f(A T R)
            from ..response.synthetic import FilmCurve

            film = FilmCurve(k=spec.film_contrast, x0=spec.film_mid)
        signal = forward.exposure_signal(albedo_fn(lon, lat), exposures[k], r)
        if spec.outlier_fraction > 0 or haze[k] > 0:  # in DN: outliers, then the image's haze
            factors = defects.outlier_factors(signal.shape, spec.outlier_fraction, defect_rng)
            signal = (defects.apply_outliers(gain * signal, factors) + haze[k]) / gain
        if spec.calibrated:
            dn = defects.calibrated(signal, spec.noise_dn / gain, rng)
            alpha = np.ones(dn.shape, np.float32)
        else:
            dn = forward.to_dn(signal, gain, spec.noise_dn, rng, film)
            alpha = np.full(dn.shape, 255, np.uint8)
        transform = Affine.translation(stated[k, 0] * res, stated[k, 1] * res) @ transform  # where the file says it is
        if spec.wrap_lon and transform.c >= 180.0:  # the file says -180..-170 for 180..190
            transform = Affine.translation(-360.0, 0.0) @ transform
        write_geotiff(out / "DRG" / f"{key}_drg.tif", np.stack([dn, alpha]), transform, MOON_CRS)
        sun_pos[key], sc_pos[key] = sun, sc
        keys.append(key)
    write_positions(out / "meta" / "sunpos.txt", sun_pos)
    write_positions(out / "meta" / "spacecraftpos.txt", sc_pos)
    box = (spec.lon0, spec.lon0 + width * res, spec.lat0, spec.lat0 + height * res)
    if spec.wrap_lon and box[1] > 180.0:
        box = (box[0], box[1] - 360.0, box[2], box[3])  # written e.g. 179.5:-179.5
    geometry_files = model.needs_geometry
    settings = legacy_text(
        {
            "DRG_DIR": "DRG",
            "DEM_DIR": "DEM" if geometry_files else None,
            "SUN_POSITION_FILE": "meta/sunpos.txt" if geometry_files else None,
            "SPACECRAFT_POSITION_FILE": "meta/spacecraftpos.txt" if geometry_files else None,
            "NUM_PROCESSES": 1,
            "TILE_SIZE": spec.tile_size,
            "SIMULATION_BOX": box,
            **model_entry(model),  # REFLECTANCE_TYPE, or REFLECTANCE for a model without a legacy code
            "SHADOW_THRESH": spec.shadow_thresh / gain if spec.calibrated else spec.shadow_thresh,
            "SHADOW_TYPE": 1,
            "TR_CONST": 1.5,
            "PHASE_COEFF_C1": spec.c1,
            "PHASE_COEFF_C2": spec.c2,
            "MAX_NUM_ITER": spec.max_num_iter,
            "USE_WEIGHTS": 1,
            "USE_NORMALIZED_COST_FUN": spec.use_normalized_cost_fun,
            "COMPUTE_ERRORS": 1,
            **({"EXPOSURE_MODE": "fixed"} if spec.calibrated else {}),
            **model_files,
        },
        f"Synthetic scene rendered by lunaralbedo.simulate (seed {spec.seed})",
    )
    atomic_write_text(out / "settings.txt", settings)
    truth = {"reflectance_type": model.code, **dict(zip(model.parameters, params)), "seed": spec.seed,
             "albedo": "truth/albedo.tif", "dem": "truth/dem.tif" if spec.dem_blur_px > 0 else "DEM/dem.tif",
             "frame": "Moon body-fixed (1737.4 km sphere), km",
             "gain": gain, "spec": asdict(spec),
             "images": {key: {"exposure": float(exposures[k]), "sun_km": sun_pos[key].tolist(),
                              "spacecraft_km": sc_pos[key].tolist(), "drg": f"DRG/{key}_drg.tif",
                              "haze": float(haze[k]) / (gain if spec.calibrated else 1.0),
                              **offset_truth(stated[k], res, spec.lat0 + height * res / 2)}
                        for k, key in enumerate(keys)}}
    write_truth(out, truth)
    return truth
