"""A Kaguya-MI-like mission: multi-band line-scanner ISIS cubes with the MI label and IK conventions.

The scene, spacecraft trajectories, kernels and photometry are those of :mod:`.mission`
(its synthetic spacecraft -999 on straight lines, Lunar-Lambert A*T*R, the one truth format);
what is new is the camera, which ``ingest`` models with ISIS's ``KaguyaMiCamera`` conventions:

* labels as ``kaguya2isis`` writes them: ``SpacecraftName = KAGUYA``, ``InstrumentId = MI-NIR``,
  ``StartTime`` and ``CorrectedSamplingInterval`` (the line timing), a ``BandBin`` of four
  NIR bands registered to the base band, ``NaifFrameCode`` = the base band's IK code;
* an IK with the JAXA MI keywords (``FOCAL_LENGTH``, ``PIXEL_SIZE``, ``CENTER``,
  ``BORESIGHT``, ``DISTORTION_COEF_X/Y``, ``TRANSX/Y``, ``ITRANSS/L``, ``FOV_FRAME``) and a
  head frame whose +x is the flight direction (detector lines across track).

Pixels are rendered with the IK's own formula for the line of sight of pixel ``n``
(``SEL_MI_V01.TI``: ``r = -(n - CENTER) * PIXEL_SIZE``, ``v = (BORESIGHT_X + sum a_k r^k,
BORESIGHT_Y + r + sum b_k r^k, BORESIGHT_Z)``), independent of the ingest camera code. Each
band is the same A*T*R times the band's gain (so one albedo map explains every band), with its
own noise; the truth exposure of band ``b`` of image ``k`` is ``exposure_k * gain_b``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import spiceypy

from ..io.geotiff import write_geotiff
from ..io.rasters import MOON_CRS
from ..isis.write import Quantity, write_cube
from ..spice.kernels import KernelPool
from ..spice.writers import write_text_kernel
from .forward import to_radiance
from .mission import C1, C2, ET_BASE, KERNEL_FILES, MODEL, SC, Shot, make_scene, surface_signal, write_kernels
from .truth import write_truth

MI_CODE, MI_FRAME = SC * 1000 - 341, SC * 1000 - 340  # like LISM_MI-NIR1 (-131341) and LISM_MI_N_HEAD (-131340)
FOCAL_MM, PIXEL_MM, SAMPLES = 16.0, 0.04, 120
CENTER = (60.5, 1.0)
BORESIGHT = (-0.30, -0.01, FOCAL_MM)
#: the NIR head's coefficients of SEL_MI_V01.TI (mm)
COEF_X = (-0.00090474, -0.002439, -2.5248e-05, 2.8753e-05)
COEF_Y = (-0.00017747, 0.0024504, 0.00010338, -4.728e-05)
BANDS_NM = (1000.0, 1049.0, 1248.0, 1548.0)
GAINS = (0.92, 1.0, 1.07, 1.15)
#: head frame -> spacecraft frame: the head's +x (along track) is the spacecraft's +y (its direction of flight)
HEAD_TO_SC = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def ik_look(samples) -> np.ndarray:
    """Unit lines of sight ``(..., 3)`` in the head frame of detector pixels ``samples`` (1-based), the IK's formula."""
    r = -(np.asarray(samples, dtype=np.float64) - CENTER[0]) * PIXEL_MM
    vx = BORESIGHT[0] + sum(c * r**k for k, c in enumerate(COEF_X))
    vy = BORESIGHT[1] + r + sum(c * r**k for k, c in enumerate(COEF_Y))
    v = np.stack([vx, vy, np.full(np.shape(r), BORESIGHT[2])], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _mi_kernels(kdir: Path) -> None:
    fk = {f"FRAME_SIM_MI_N_HEAD": MI_FRAME, f"FRAME_{MI_FRAME}_NAME": "SIM_MI_N_HEAD", f"FRAME_{MI_FRAME}_CLASS": 4,
          f"FRAME_{MI_FRAME}_CLASS_ID": MI_FRAME, f"FRAME_{MI_FRAME}_CENTER": SC,
          f"TKFRAME_{MI_FRAME}_RELATIVE": "SIM_SPACECRAFT", f"TKFRAME_{MI_FRAME}_SPEC": "MATRIX",
          f"TKFRAME_{MI_FRAME}_MATRIX": HEAD_TO_SC.T.ravel().tolist()}
    key = f"INS{MI_CODE}_"
    ik = {key + "FOCAL_LENGTH": FOCAL_MM, key + "PIXEL_SIZE": PIXEL_MM, key + "PIXEL_SAMPLES": float(SAMPLES),
          key + "PIXEL_LINES": 1.0, key + "CENTER": list(CENTER), key + "BORESIGHT": list(BORESIGHT),
          key + "DISTORTION_COEF_X": list(COEF_X), key + "DISTORTION_COEF_Y": list(COEF_Y),
          key + "TRANSX": [0.0, 0.0, 0.0], key + "TRANSY": [0.0, -PIXEL_MM, 0.0],
          key + "ITRANSS": [0.0, 0.0, -1.0 / PIXEL_MM], key + "ITRANSL": [0.0, -1.0 / PIXEL_MM, 0.0],
          key + "FOV_FRAME": "SIM_MI_N_HEAD"}
    write_text_kernel(kdir / "sim_mi.tf", "FK", fk, "Synthetic MI head frame: +x along track.")
    write_text_kernel(kdir / "sim_mi.ti", "IK", ik, "Synthetic Kaguya-MI-like NIR camera (JAXA IK keywords).")


def default_shots(rng, n_images: int = 3) -> list[Shot]:
    """Line-scanner shots over the scene centre: different Sun, view and exposure (MI-like ~180 m pixels)."""
    return [Shot(key=f"MNSIM{k + 1:02d}", kind="line", et=ET_BASE + k * 7200.0 + 77.7, exposure=float(rng.uniform(0.85, 1.2)),
                 aim_lon=6.0 + rng.uniform(-0.2, 0.2), aim_lat=-6.0 + rng.uniform(-0.2, 0.2),
                 sun_azimuth=float(rng.uniform(0, 360)), sun_elevation=float(rng.uniform(50, 65)),
                 view_azimuth=float(rng.uniform(0, 360)), view_zenith=float(rng.uniform(0, 6)), altitude_km=72.0,
                 lines=160, samples=SAMPLES, line_rate=0.11) for k in range(n_images)]


def render_mi(scene, shot: Shot, p0, vel, m, sun_km, rng, noise: float) -> np.ndarray:
    """Four-band image ``(bands, lines, samples)`` of the shot (line ``L`` exposed at StartTime + (L - 0.5) rate)."""
    ll, ss = np.meshgrid(np.arange(1, shot.lines + 1, dtype=float), np.arange(1, shot.samples + 1, dtype=float),
                         indexing="ij")
    dirs = ik_look(ss) @ (m @ HEAD_TO_SC).T
    t = (ll - 0.5) * shot.line_rate - shot.lines * shot.line_rate / 2.0
    origins = p0 + vel * t[..., None]
    signal = surface_signal(scene, origins, dirs, p0, sun_km, shot.exposure)
    return np.stack([to_radiance(g * signal, noise, rng) for g in GAINS])


def build(out: str | Path, seed: int = 4601, n_images: int = 3, noise: float = 0.005) -> dict:
    """Write DEM, truth albedo, kernels, four-band MI cubes and truth.json under ``out``; return the truth."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    scene = make_scene(rng)
    shots = default_shots(rng, n_images)
    kdir = out / "kernels"
    geo = write_kernels(kdir, scene, shots)
    _mi_kernels(kdir)
    write_geotiff(out / "dem" / "dem.tif", scene.heights.astype(np.float32), scene.grid.transform, MOON_CRS,
                  nodata=-32767.0, dtype="float32", compress="deflate")
    write_geotiff(out / "truth" / "albedo.tif", scene.albedo.astype(np.float32), scene.grid.transform, MOON_CRS,
                  dtype="float32", compress="deflate")
    truth = {"c1": C1, "c2": C2, "reflectance_type": MODEL.code, "noise_relative": noise, "seed": seed,
             "albedo": "truth/albedo.tif", "dem": "dem/dem.tif", "frame": "MOON_ME (= IAU_MOON here), km",
             "band_gains": dict(zip([f"{b:g}" for b in BANDS_NM], GAINS)), "images": {}}
    with KernelPool([kdir / n for n in KERNEL_FILES]):
        for s in shots:
            p0, vel, m, _ = geo[s.key]
            sun, _ = spiceypy.spkpos("SUN", s.et, "J2000", "LT+S", "MOON")
            sun = np.asarray(spiceypy.pxform("J2000", "MOON_ME", s.et)) @ np.asarray(sun)
            img = render_mi(scene, s, p0, vel, m, sun, rng, noise)
            start = s.et - s.lines * s.line_rate / 2.0
            inst = {"MissionName": "SELENE", "SpacecraftName": "KAGUYA", "InstrumentName": "Multiband Imager Near Infrared",
                    "InstrumentId": "MI-NIR", "TargetName": "MOON", "StartTime": spiceypy.et2utc(start, "ISOC", 6),
                    "LineSamplingInterval": Quantity(s.line_rate * 1000.0, "msec"),
                    "CorrectedSamplingInterval": Quantity(s.line_rate * 1000.0, "msec")}
            band = {"FilterName": [f"MN{b + 1}" for b in range(len(BANDS_NM))], "Center": Quantity(list(BANDS_NM), "nm"),
                    "BaseBand": "MN1"}
            kern = {"NaifFrameCode": MI_CODE, "LeapSecond": "../kernels/sim.tls",
                    "TargetAttitudeShape": "../kernels/sim.tpc", "TargetPosition": "../kernels/sim.bsp",
                    "InstrumentPointing": ["../kernels/sim.bc", "../kernels/sim.tf", "../kernels/sim_mi.tf"],
                    "Instrument": "../kernels/sim_mi.ti", "SpacecraftClock": "../kernels/sim.tsc",
                    "InstrumentPosition": "../kernels/sim.bsp", "ShapeModel": "Null"}
            write_cube(out / "cubes" / f"{s.key}.cub", img, {"Instrument": inst, "BandBin": band, "Kernels": kern})
            for b, gain in enumerate(GAINS, 1):
                key = f"{s.key:_<8}"[:8] + f"B{b:02d}"  # ingest's key of band b (ingest.keys.band_items)
                truth["images"][key] = {"exposure": s.exposure * gain, "sun_km": sun.tolist(), "spacecraft_km": p0.tolist(),
                                        "cube": f"cubes/{s.key}.cub", "band": b, "band_center_nm": BANDS_NM[b - 1]}
    write_truth(out, truth)
    return truth
