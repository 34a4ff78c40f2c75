"""A synthetic mission in the ingest contract: DEM, albedo, kernels and Level-1 ISIS cubes rendered as A*T*R.

``lunaralbedo simulate --format isis`` and ``tools/make_sample_data.py`` (sample_data/) write
it; the round-trip tests ingest it.  Pixels go through the one forward model of
:mod:`.forward` (Sun geometry, A*T*R with the photometric registry's Lunar-Lambert model,
multiplicative noise) and the truth is written in the one format of :mod:`.truth`.
Geometry is built directly in the body-fixed frame (km) and written to kernels
(SPK type 13, CK type 3, text LSK/PCK/FK/IK/SCLK); images are rendered with an
independent pinhole model (not the ingest camera code), so ingesting them is a
true round trip.  In this synthetic mission MOON_ME is defined (FK) to coincide
with IAU_MOON (PCK: IAU rotation without nutation terms).
"""
from __future__ import annotations

import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import spiceypy
from rasterio.transform import Affine

from ..camera.intersect import ray_dem
from ..model.grid import Grid, bilinear
from ..ingest.observation import packaged_lsk
from ..io.rasters import MOON_CRS
from ..io.geotiff import write_geotiff
from ..isis.write import Quantity, write_cube
from ..model import photometry
from ..model.geometry import body_fixed, dem_normals, illumination, lonlat_height
from ..spice.kernels import KernelPool
from ..spice.writers import write_ck, write_spk, write_text_kernel
from .forward import exposure_signal, local_frame, sun_position, to_radiance
from .truth import write_truth

SC, SC_FRAME, FRAME_CAM, LINE_CAM = -999, -999000, -999001, -999002
FOCAL_MM, PITCH_MM = 4.5, 0.01
ET_BASE = 675_000_000.0  # ~2021-05-22
KERNEL_FILES = ("sim.tls", "sim.tpc", "sim.tf", "sim.ti", "sim.tsc", "sim.bsp", "sim.bc")
C1, C2 = 1.4, 0.5
#: The mission's photometric model (registry) and its parameters.
MODEL = photometry.get("lunar-lambert")


@dataclass
class Shot:
    """One synthetic image; angles in degrees, altitude in km, et in s (TDB)."""

    key: str
    kind: str  # "frame" or "line"
    et: float
    exposure: float
    aim_lon: float
    aim_lat: float
    sun_azimuth: float
    sun_elevation: float
    view_azimuth: float
    view_zenith: float
    altitude_km: float = 80.0
    lines: int = 200
    samples: int = 200
    line_rate: float = 0.111  # s per line (line scanner)
    speed_kms: float = 1.6


@dataclass
class Scene:
    grid: Grid
    heights: np.ndarray  # metres above 1737.4 km
    albedo: np.ndarray

    def height(self, lon, lat):
        t = self.grid.transform
        return bilinear(self.heights, (np.asarray(lon) - t.c) / t.a - 0.5, (np.asarray(lat) - t.f) / t.e - 0.5)


def make_scene(rng, shape=(300, 300), west=4.5, north=-4.5, res=0.01) -> Scene:
    """Smooth craters on a gentle tilt (slopes < ~8 degrees) and a smooth albedo field (0.06-0.2)."""
    grid = Grid(Affine(res, 0, west, 0, -res, north), shape)
    lon, lat = grid.lonlat()
    km = 30.3239  # km per degree on the 1737.4 km sphere
    h = 200.0 * (lon - lon.mean()) / 3.0 - 150.0 * (lat - lat.mean()) / 3.0
    alb = 0.13 + 0.035 * np.tanh((lon - 5.6 - 0.3 * (lat + 6.0)) / 0.35)
    for _ in range(9):
        cx, cy = rng.uniform(west + 0.3, west + res * shape[1] - 0.3), rng.uniform(north - res * shape[0] + 0.3, north - 0.3)
        R, d = rng.uniform(3.0, 9.0), rng.uniform(150.0, 450.0) * 0.6
        r = np.hypot((lon - cx) * np.cos(np.radians(cy)), lat - cy) * km
        h += -d * np.exp(-2.0 * (r / R) ** 2) + 0.3 * d * np.exp(-(((r - R) / (0.35 * R)) ** 2))
        alb += rng.uniform(-0.025, 0.03) * np.exp(-(((r - 0.9 * R) / (0.5 * R)) ** 2))
    return Scene(grid, h, np.clip(alb, 0.05, 0.25))


def shot_geometry(scene: Scene, shot: Shot):
    """Body-fixed spacecraft position P0 (km) at the centre time, velocity (km/s), camera->body matrix, Sun (km)."""
    aim = body_fixed(shot.aim_lon, shot.aim_lat, float(scene.height(shot.aim_lon, shot.aim_lat)))
    east, north, up = local_frame(aim)
    az, zen = np.radians(shot.view_azimuth), np.radians(shot.view_zenith)
    horiz = np.cos(az) * north + np.sin(az) * east
    p0 = aim + shot.altitude_km / np.cos(zen) * (np.cos(zen) * up + np.sin(zen) * horiz)
    z = (aim - p0) / np.linalg.norm(aim - p0)
    x = east - east @ z * z
    x /= np.linalg.norm(x)
    m = np.stack([x, np.cross(z, x), z], axis=1)  # columns: camera axes in the body frame
    vel = shot.speed_kms * (m[:, 1] - m[:, 1] @ up * up) / np.linalg.norm(m[:, 1] - m[:, 1] @ up * up)
    sun = sun_position(aim, shot.sun_azimuth, shot.sun_elevation)
    return p0, vel, m, sun


class LinearEphemeris:
    """Spacecraft on a straight line ``p0 + vel (et - et_c)`` (km, km/s) with a fixed camera->body matrix ``m``."""

    def __init__(self, p0, vel, m, et_c: float):
        self.p0, self.vel, self.m, self.et_c = np.asarray(p0), np.asarray(vel), np.asarray(m), float(et_c)

    def spacecraft(self, et):
        et = np.asarray(et, dtype=np.float64)
        return self.p0 + self.vel * (et - self.et_c)[..., None]

    def camera_to_body(self, et):
        return np.broadcast_to(self.m, np.shape(et) + (3, 3))


def shot_camera(scene: Scene, shot: Shot, focal_mm: float = FOCAL_MM, pitch_mm: float = PITCH_MM, distortion=None):
    """The ingest camera model of ``shot`` without kernels (for benchmarks and orthoprojection tests)."""
    from ..camera.model import CameraModel, DetectorMap, LineTiming
    from ..camera.optics import FocalPlane, NoDistortion

    p0, vel, m, _sun = shot_geometry(scene, shot)
    line = shot.kind == "line"
    focal = FocalPlane(focal_mm, (0.0, pitch_mm, 0.0), (0.0, 0.0, pitch_mm), (0.0, 1 / pitch_mm, 0.0),
                       (0.0, 0.0, 1 / pitch_mm), (shot.samples + 1) / 2.0, 0.0 if line else (shot.lines + 1) / 2.0,
                       distortion or NoDistortion())
    eph = LinearEphemeris(p0, vel if line else np.zeros(3), m, shot.et)
    if line:
        timing = LineTiming(shot.et - shot.lines * shot.line_rate / 2.0, shot.line_rate)
        return CameraModel(focal, DetectorMap(), (shot.lines, shot.samples), eph, timing=timing)
    return CameraModel(focal, DetectorMap(), (shot.lines, shot.samples), eph, frame_et=shot.et)


def _text_kernels(kdir: Path, shots) -> None:
    shutil.copyfile(packaged_lsk(), kdir / "sim.tls")
    write_text_kernel(kdir / "sim.tpc", "PCK", {
        "BODY301_RADII": [1737.4, 1737.4, 1737.4], "BODY301_POLE_RA": [269.9949, 0.0031, 0.0],
        "BODY301_POLE_DEC": [66.5392, 0.0130, 0.0], "BODY301_PM": [38.3213, 13.17635815, -1.4e-12],
    }, "Synthetic Moon orientation: IAU 2009 constants without nutation/precession terms.")
    fk = {"NAIF_BODY_NAME": ["LUNARALBEDO_SIM"], "NAIF_BODY_CODE": [SC],
          "FRAME_MOON_ME": 31001, "FRAME_31001_NAME": "MOON_ME", "FRAME_31001_CLASS": 4, "FRAME_31001_CLASS_ID": 31001,
          "FRAME_31001_CENTER": 301, "TKFRAME_31001_RELATIVE": "IAU_MOON", "TKFRAME_31001_SPEC": "MATRIX",
          "TKFRAME_31001_MATRIX": [1, 0, 0, 0, 1, 0, 0, 0, 1],
          "FRAME_SIM_SPACECRAFT": SC_FRAME, f"FRAME_{SC_FRAME}_NAME": "SIM_SPACECRAFT", f"FRAME_{SC_FRAME}_CLASS": 3,
          f"FRAME_{SC_FRAME}_CLASS_ID": SC_FRAME, f"FRAME_{SC_FRAME}_CENTER": SC, f"CK_{SC_FRAME}_SCLK": SC,
          f"CK_{SC_FRAME}_SPK": SC}
    ik = {}
    for code, name, ns in ((FRAME_CAM, "SIM_FRAME_CAMERA", 200), (LINE_CAM, "SIM_LINE_SCANNER", 120)):
        fk.update({f"FRAME_{name}": code, f"FRAME_{code}_NAME": name, f"FRAME_{code}_CLASS": 4,
                   f"FRAME_{code}_CLASS_ID": code, f"FRAME_{code}_CENTER": SC,
                   f"TKFRAME_{code}_RELATIVE": "SIM_SPACECRAFT", f"TKFRAME_{code}_SPEC": "MATRIX",
                   f"TKFRAME_{code}_MATRIX": [1, 0, 0, 0, 1, 0, 0, 0, 1]})
        ik.update({f"INS{code}_FOCAL_LENGTH": FOCAL_MM, f"INS{code}_PIXEL_PITCH": PITCH_MM,
                   f"INS{code}_TRANSX": [0.0, PITCH_MM, 0.0], f"INS{code}_TRANSY": [0.0, 0.0, PITCH_MM],
                   f"INS{code}_ITRANSS": [0.0, 1 / PITCH_MM, 0.0], f"INS{code}_ITRANSL": [0.0, 0.0, 1 / PITCH_MM],
                   f"INS{code}_BORESIGHT_SAMPLE": (ns + 1) / 2.0,
                   f"INS{code}_BORESIGHT_LINE": 100.5 if code == FRAME_CAM else 0.0})
    write_text_kernel(kdir / "sim.tf", "FK", fk, "Synthetic spacecraft and instrument frames; MOON_ME = IAU_MOON here.")
    write_text_kernel(kdir / "sim.ti", "IK", ik, "Synthetic frame camera (-999001, 200x200) and line scanner (-999002, 120 px).")
    write_text_kernel(kdir / "sim.tsc", "SCLK", {
        "SCLK_KERNEL_ID": "@2021-01-01/00:00:00", "SCLK_DATA_TYPE_999": 1, "SCLK01_TIME_SYSTEM_999": 1,
        "SCLK01_N_FIELDS_999": 2, "SCLK01_MODULI_999": [4294967296, 65536], "SCLK01_OFFSETS_999": [0, 0],
        "SCLK01_OUTPUT_DELIM_999": 1, "SCLK_PARTITION_START_999": 0.0, "SCLK_PARTITION_END_999": 2.8147497671065e14,
        "SCLK01_COEFFICIENTS_999": [0.0, ET_BASE - 1.0e6, 1.0],
    }, "Synthetic clock: 1 count per TDB second, 65536 ticks per count.")


def write_kernels(kdir: Path, scene: Scene, shots) -> dict:
    """Write all kernels for ``shots``; returns ``{key: (p0, vel, m, sun_bf)}`` (body-fixed km, km/s)."""
    kdir.mkdir(parents=True, exist_ok=True)
    _text_kernels(kdir, shots)
    geo = {s.key: shot_geometry(scene, s) for s in shots}
    with KernelPool([kdir / n for n in KERNEL_FILES[:5]]):
        spk, ck = [], []
        lo, hi = min(s.et for s in shots) - 2000.0, max(s.et for s in shots) + 2000.0
        spk.append(dict(body=301, center=0, epochs=[lo, hi], states=np.zeros((2, 6)), degree=1, segid="MOON AT SSB"))
        for s in shots:
            p0, vel, m, sun = geo[s.key]
            half = (s.lines * s.line_rate if s.kind == "line" else 1.0) / 2.0 + 30.0
            ep = s.et + np.linspace(-half, half, 41)
            states, quats = [], []
            for t in ep:
                xf = np.asarray(spiceypy.sxform("MOON_ME", "J2000", t))
                states.append(xf @ np.concatenate([p0 + vel * (t - s.et), vel]))
                quats.append(spiceypy.m2q(m.T @ np.asarray(spiceypy.pxform("J2000", "MOON_ME", t))))
            spk.append(dict(body=SC, center=301, epochs=ep, states=states, segid=s.key))
            sun_ep = s.et + np.linspace(-900.0, half, 41)
            sun_states = [np.asarray(spiceypy.sxform("MOON_ME", "J2000", t)) @ np.concatenate([sun, np.zeros(3)])
                          for t in sun_ep]
            spk.append(dict(body=10, center=301, epochs=sun_ep, states=sun_states, segid=f"SUN {s.key}"))
            ck.append(dict(inst=SC_FRAME, sclkdp=[spiceypy.sce2c(SC, t) for t in ep], quats=quats, segid=s.key))
        write_spk(kdir / "sim.bsp", spk)
        write_ck(kdir / "sim.bc", ck)
    return geo


def _pinhole_dirs(m, samples, lines, ns, boresight_line):
    x = (np.asarray(samples) - (ns + 1) / 2.0) * PITCH_MM
    y = (np.asarray(lines) - boresight_line) * PITCH_MM
    v = np.stack([x, y, np.full(np.shape(x), FOCAL_MM)], axis=-1)
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return v @ m.T


def render(scene: Scene, shot: Shot, p0, vel, m, sun_km, rng, noise: float) -> np.ndarray:
    """Image (lines, samples) of A * T * R(Lunar-Lambert) with multiplicative Gaussian noise."""
    ll, ss = np.meshgrid(np.arange(1, shot.lines + 1, dtype=float), np.arange(1, shot.samples + 1, dtype=float),
                         indexing="ij")
    if shot.kind == "frame":
        dirs = _pinhole_dirs(m, ss, ll, shot.samples, 100.5)
        origins = np.broadcast_to(p0, dirs.shape)
    else:
        dirs = _pinhole_dirs(m, ss, np.zeros_like(ll), shot.samples, 0.0)
        t = (ll - 0.5) * shot.line_rate - shot.lines * shot.line_rate / 2.0  # centre line at t = 0
        origins = p0 + vel * t[..., None]
    return to_radiance(surface_signal(scene, origins, dirs, p0, sun_km, shot.exposure), noise, rng)


def surface_signal(scene: Scene, origins, dirs, p0, sun_km, exposure: float) -> np.ndarray:
    """Noiseless A * T * R(Lunar-Lambert) where rays ``origins + t dirs`` (body-fixed km) meet the scene's DEM."""
    pts = ray_dem(origins, dirs, lambda lo, la: np.nan_to_num(scene.height(lo, la)), tol_m=1e-4)
    lon, lat, _ = lonlat_height(pts)
    g = scene.grid.transform
    col, row = (lon - g.c) / g.a - 0.5, (lat - g.f) / g.e - 0.5
    normals_grid = dem_normals(body_fixed(*scene.grid.lonlat(), scene.heights))
    n = np.stack([bilinear(normals_grid[..., k], col, row) for k in range(3)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    # Photometry with the single per-image spacecraft position (p0) that the solver assumes;
    # only the ray geometry of a line scanner follows the moving spacecraft.
    cos_i, cos_e, alpha = illumination(pts, n, sun_km, p0)
    return exposure_signal(bilinear(scene.albedo, col, row), exposure, MODEL.reflectance(cos_i, cos_e, alpha, (C1, C2)))


def write_scene_truth(out: Path, scene: Scene, noise: float, seed: int, **extra) -> dict:
    """Write a mission's DEM (``dem/dem.tif``, heights in metres) and true albedo (``truth/albedo.tif``); return the
    truth's header (``images`` still empty), with ``extra`` entries."""
    # compression pinned so the committed files stay byte-identical if the writer's default changes
    write_geotiff(out / "dem" / "dem.tif", scene.heights.astype(np.float32), scene.grid.transform, MOON_CRS,
                  nodata=-32767.0, dtype="float32", compress="deflate")
    write_geotiff(out / "truth" / "albedo.tif", scene.albedo.astype(np.float32), scene.grid.transform, MOON_CRS,
                  dtype="float32", compress="deflate")
    return {"c1": C1, "c2": C2, "reflectance_type": MODEL.code, "noise_relative": noise, "seed": seed,
            "albedo": "truth/albedo.tif", "dem": "dem/dem.tif", "frame": "MOON_ME (= IAU_MOON here), km",
            **extra, "images": {}}


def default_shots(rng, n_frames: int = 5, with_line: bool = False) -> list[Shot]:
    shots = []
    for k in range(n_frames):
        shots.append(Shot(
            key=f"SIM-F-{k + 1:05d}", kind="frame", et=ET_BASE + k * 7200.0 + 123.456,
            exposure=float(rng.uniform(0.8, 1.25)), aim_lon=6.0 + rng.uniform(-0.35, 0.35),
            aim_lat=-6.0 + rng.uniform(-0.35, 0.35), sun_azimuth=float(rng.uniform(0, 360)),
            sun_elevation=float(rng.uniform(52, 66)), view_azimuth=float(rng.uniform(0, 360)),
            view_zenith=float(rng.uniform(0, 12)), altitude_km=float(rng.uniform(75, 90))))
    if with_line:
        shots.append(Shot(key="SIM-L-00001", kind="line", et=ET_BASE + n_frames * 7200.0 + 55.5, exposure=1.0,
                          aim_lon=6.0, aim_lat=-6.0, sun_azimuth=120.0, sun_elevation=58.0, view_azimuth=30.0,
                          view_zenith=5.0, lines=150, samples=120))
    return shots


def build(out: str | Path, seed: int = 20240601, n_frames: int = 5, with_line: bool = False,
          noise: float = 0.005) -> dict:
    """Write DEM, truth albedo, kernels, cubes and truth.json under ``out``; return the truth dict."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    scene = make_scene(rng)
    shots = default_shots(rng, n_frames, with_line)
    kdir = out / "kernels"
    geo = write_kernels(kdir, scene, shots)
    truth = write_scene_truth(out, scene, noise, seed)
    with KernelPool([kdir / n for n in KERNEL_FILES]):
        for s in shots:
            p0, vel, m, sun_bf = geo[s.key]
            sun, _ = spiceypy.spkpos("SUN", s.et, "J2000", "LT+S", "MOON")
            sun = np.asarray(spiceypy.pxform("J2000", "MOON_ME", s.et)) @ np.asarray(sun)
            img = render(scene, s, p0, vel, m, sun, rng, noise)
            code = FRAME_CAM if s.kind == "frame" else LINE_CAM
            if s.kind == "frame":
                start, timing = s.et - 0.005, {"ExposureDuration": Quantity(10.0, "ms")}
            else:
                start = s.et - s.lines * s.line_rate / 2.0
                timing = {"LineExposureDuration": Quantity(s.line_rate * 1000.0, "ms")}
            inst = {"SpacecraftName": "LUNARALBEDO SIM", "InstrumentId": "SIMFRAME" if s.kind == "frame" else "SIMLINE",
                    "TargetName": "MOON", "StartTime": spiceypy.et2utc(start, "ISOC", 6),
                    "SpacecraftClockStartCount": spiceypy.sce2s(SC, start), **timing}
            kern = {"NaifFrameCode": code, "LeapSecond": "../kernels/sim.tls", "TargetAttitudeShape": "../kernels/sim.tpc",
                    "TargetPosition": "../kernels/sim.bsp", "InstrumentPointing": ["../kernels/sim.bc", "../kernels/sim.tf"],
                    "Instrument": "../kernels/sim.ti", "SpacecraftClock": "../kernels/sim.tsc",
                    "InstrumentPosition": "../kernels/sim.bsp", "ShapeModel": "Null"}
            write_cube(out / "cubes" / f"{s.key}.cub", img, {"Instrument": inst, "Kernels": kern})
            truth["images"][s.key] = {**asdict(s), "sun_km": sun.tolist(), "spacecraft_km": p0.tolist(),
                                      "cube": f"cubes/{s.key}.cub"}
    write_truth(out, truth)
    return truth
