"""Instrument-like missions: ISIS cubes with the labels and IKs of Kaguya MI and TC, Chandrayaan-2 TMC-2 (line
scanners) or Clementine UVVIS (frame).

The scene, spacecraft trajectories, kernels and photometry are those of :mod:`.mission`
(its synthetic spacecraft -999 on straight lines, Lunar-Lambert A*T*R, the one truth format);
what is new is the camera, which ``ingest`` models with ISIS's plugin conventions
(:mod:`lunaralbedo.camera.lunar`):

* ``kaguya_mi`` - labels as ``kaguya2isis`` writes them (``SpacecraftName = KAGUYA``,
  ``InstrumentId = MI-NIR``, ``StartTime`` and ``CorrectedSamplingInterval``, a ``BandBin`` of
  four NIR bands registered to the base band) and an IK with the JAXA MI keywords (``CENTER``,
  ``PIXEL_SIZE``, ``BORESIGHT``, the NIR head's ``DISTORTION_COEF_X/Y``, ``TRANSX/Y``,
  ``FOV_FRAME``; head frame +x along track). Pixels are rendered with the IK's own line of
  sight of pixel ``n`` (``SEL_MI_V01.TI``: ``r = -(n - CENTER) * PIXEL_SIZE``,
  ``v = (BORESIGHT_X + sum a_k r^k, BORESIGHT_Y + r + sum b_k r^k, BORESIGHT_Z)``), not by the
  ingest camera chain. Band ``b`` is A*T*R times the band's gain with its own noise: the truth
  exposure of band ``b`` of image ``k`` is ``exposure_k * gain_b``.
* ``clementine_uvvis`` - one filter per cube (filters A and B alternate, each with its own IK code,
  focal length and boresight), ``StartTime`` + ``ExposureDuration`` / 2, ``BandBin`` centre in
  micrometres, and the ``PP``/``OD_K``/``DECENTER`` distortion of ISIS's UVVIS map. Rays are
  pixel -> focal plane (``(s - BORESIGHT_SAMPLE) * pitch``, ...) -> undistorted -> look.
* ``kaguya_tc`` - TC1 labels (``InstrumentId = TC1``, ``SwathModeId = NOMINAL``: first detector
  sample 297, ``LineSamplingInterval``, ``SpacecraftClockStartCount`` and a ``StartTime`` 30 ms
  earlier, as in JAXA's labels) of a crop (``AlphaCube``) of the 3504-sample swath around the
  detector centre; IK with the TC keywords (``CENTER``, ``PIXEL_SIZE``, ``TRANSX/Y``, 4-term
  ``DISTORTION_COEF_X/Y``, a ``BORESIGHT`` offset that ISIS's map leaves out). Rays as ISIS's
  ``KaguyaTcCamera`` reads the IK: detector sample ``n`` (parent sample + 296), origin
  ``(2048.5, 1)``, ``(x, y) = (-p (0 - 1), -p (n - 2048.5))`` mm, ``u = (x, y) + poly(r)`` with
  ``r = |(x, y)|``; line ``k`` of the cube (parent line ``k + 20``) exposed at the clock count's time.
* ``chandrayaan2_tmc2`` - TMC-2 labels (``CH2_TMC_NADIR``, ``StartTime``, ``LineExposureDuration``,
  ``SpatialSumming = 2``) of a sample crop of the summed 2000-sample line, head flown backwards
  (yaw 180 degrees, as the real nadir camera); IK ``CENTER`` (1999.5, 0.5), ``TRANSX/Y``, a
  radial ``OD_K``. Rays: detector sample ``n = 2 a - 0.5`` of parent sample ``a``,
  ``(x, y) = p (0 - 0.5, n - 1999.5)`` mm, ``u = (x, y) (1 - (k0 + k1 r^2 + k2 r^4))``.

Line ``k`` of every line scanner is exposed at ``start + (parent line - 0.5) * rate`` from the
moving spacecraft; the crop's middle is the shot's time.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import spiceypy

from ..camera.instruments import CHANDRAYAAN2_TMC2, CLEMENTINE_UVVIS, KAGUYA_MI, KAGUYA_TC
from ..camera.lunar_optics import ClementineUvvisDistortion
from ..isis.write import Quantity, write_cube
from ..spice.kernels import KernelPool
from ..spice.writers import write_text_kernel
from .forward import to_radiance
from .mission import ET_BASE, KERNEL_FILES, SC, Shot, make_scene, surface_signal, write_kernels, write_scene_truth
from .truth import write_truth

# -- Kaguya MI-like NIR camera ---------------------------------------------------------------------------
MI_CODE, MI_FRAME = SC * 1000 - 341, SC * 1000 - 340  # like LISM_MI-NIR1 (-131341) and LISM_MI_N_HEAD (-131340)
MI_FOCAL_MM, MI_PIXEL_MM, MI_SAMPLES = 16.0, 0.04, 120
CENTER = (60.5, 1.0)
BORESIGHT = (-0.30, -0.01, MI_FOCAL_MM)
#: the NIR head's coefficients of SEL_MI_V01.TI (mm)
COEF_X = (-0.00090474, -0.002439, -2.5248e-05, 2.8753e-05)
COEF_Y = (-0.00017747, 0.0024504, 0.00010338, -4.728e-05)
BANDS_NM = (1000.0, 1049.0, 1248.0, 1548.0)
GAINS = (0.92, 1.0, 1.07, 1.15)
#: head frame -> spacecraft frame: the head's +x (along track) is the spacecraft's +y (its direction of flight)
HEAD_TO_SC = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

# -- Clementine UVVIS-like frame camera: filter -> (IK code, focal mm, boresight sample/line, centre um) -----
UVVIS_PITCH_MM, UVVIS_SHAPE = 0.023, (120, 160)  # lines, samples
UVVIS_FILTERS = {"A": (SC * 1000 - 21, 12.0, 80.5, 60.5, 0.415), "B": (SC * 1000 - 22, 12.04, 80.2, 60.9, 0.75)}
UVVIS_DISTORTION = ClementineUvvisDistortion(pp=(0.01, -0.005), odk=(0.0, -2.0e-3, 0.0), decenter=(2.0e-4, 1.5e-4))

# -- Kaguya TC-like line scanner (NOMINAL swath crop) ------------------------------------------------------
TC_CODE, TC_FRAME = SC * 1000 - 351, SC * 1000 - 350  # like TC1 (-131351) and LISM_TC1_HEAD (-131350)
TC_FOCAL_MM, TC_PIXEL_MM, TC_SWATH_SAMPLES, TC_SWATH_START = 2.8, 0.007, 3504, 297.0
TC_CROP = (1692.5, 20.5)  # AlphaCube: parent sample/line edges where the cube starts (its centre: detector 2048.5)
#: polynomials in r (mm) of the TC IK's form, larger than TC1's so that they matter at this crop's radii
TC_COEF_X = (-9.6499e-4, 9.8441e-3, 8.0e-3, -4.0e-3)
TC_COEF_Y = (-1.3796e-3, 1.3502e-3, 3.0e-3, -6.0e-3)

# -- Chandrayaan-2 TMC-2-like line scanner (2x summed, sample crop, flown backwards) ------------------------
TMC_CODE, TMC_FOCAL_MM, TMC_PIXEL_MM, TMC_SAMPLES, TMC_SUMMING = SC * 1000 - 210, 5.6, 0.007, 4000, 2
TMC_CENTER, TMC_CROP_SAMPLE, TMC_ODK = (1999.5, 0.5), 940.5, (0.0, 1.5e-2, 0.0)
TMC_HEAD_TO_SC = HEAD_TO_SC @ np.diag([-1.0, -1.0, 1.0])  # yaw 180 degrees: head +x against the flight


def tc_look(det_samples) -> np.ndarray:
    """Unit lines of sight ``(..., 3)`` in the TC head frame of detector samples (1-based), as ISIS's
    KaguyaTcCamera reads the IK: origin (2048.5, 1), line 0, no boresight offset, ``u = d + poly(|d|)``."""
    y = -(np.asarray(det_samples, dtype=np.float64) - 2048.5) * TC_PIXEL_MM  # TRANSY = (0, -p, 0)
    x = np.full(np.shape(y), -TC_PIXEL_MM * (0.0 - 1.0))  # TRANSX = (0, 0, -p), detector line 0 - 1
    r = np.hypot(x, y)
    ux, uy = x + sum(c * r**k for k, c in enumerate(TC_COEF_X)), y + sum(c * r**k for k, c in enumerate(TC_COEF_Y))
    v = np.stack([ux, uy, np.full(np.shape(r), TC_FOCAL_MM)], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def tmc_look(det_samples) -> np.ndarray:
    """Unit lines of sight ``(..., 3)`` in the TMC-2 frame of detector samples (1-based), as ISIS's
    Chandrayaan2TmcCamera reads the IK: origin CENTER, line 0, radial ``OD_K`` (ISIS's default map)."""
    y = (np.asarray(det_samples, dtype=np.float64) - TMC_CENTER[0]) * TMC_PIXEL_MM  # TRANSY = (0, p, 0)
    x = np.full(np.shape(y), TMC_PIXEL_MM * (0.0 - TMC_CENTER[1]))  # TRANSX = (0, 0, p)
    rr = x * x + y * y
    d = TMC_ODK[0] + rr * (TMC_ODK[1] + rr * TMC_ODK[2])
    v = np.stack([x - d * x, y - d * y, np.full(np.shape(y), TMC_FOCAL_MM)], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def ik_look(samples) -> np.ndarray:
    """Unit lines of sight ``(..., 3)`` in the MI head frame of detector pixels ``samples`` (1-based), the IK's formula."""
    r = -(np.asarray(samples, dtype=np.float64) - CENTER[0]) * MI_PIXEL_MM
    vx = BORESIGHT[0] + sum(c * r**k for k, c in enumerate(COEF_X))
    vy = BORESIGHT[1] + r + sum(c * r**k for k, c in enumerate(COEF_Y))
    v = np.stack([vx, vy, np.full(np.shape(r), BORESIGHT[2])], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def uvvis_look(filt: str, samples, lines) -> np.ndarray:
    """Unit lines of sight ``(..., 3)`` in the UVVIS filter frame of pixels ``(samples, lines)`` (1-based)."""
    _code, focal, bs, bl, _um = UVVIS_FILTERS[filt]
    ux, uy = UVVIS_DISTORTION.undistort((np.asarray(samples) - bs) * UVVIS_PITCH_MM, (np.asarray(lines) - bl) * UVVIS_PITCH_MM)
    v = np.stack([ux, uy, np.full(np.shape(ux), focal)], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _tk_frame(code: int, name: str, to_sc) -> dict:
    return {f"FRAME_{name}": code, f"FRAME_{code}_NAME": name, f"FRAME_{code}_CLASS": 4, f"FRAME_{code}_CLASS_ID": code,
            f"FRAME_{code}_CENTER": SC, f"TKFRAME_{code}_RELATIVE": "SIM_SPACECRAFT", f"TKFRAME_{code}_SPEC": "MATRIX",
            f"TKFRAME_{code}_MATRIX": np.asarray(to_sc).T.ravel().tolist()}  # column-major


def _mi_kernels(kdir: Path) -> None:
    key = f"INS{MI_CODE}_"
    ik = {key + "FOCAL_LENGTH": MI_FOCAL_MM, key + "PIXEL_SIZE": MI_PIXEL_MM, key + "PIXEL_SAMPLES": float(MI_SAMPLES),
          key + "PIXEL_LINES": 1.0, key + "CENTER": list(CENTER), key + "BORESIGHT": list(BORESIGHT),
          key + "DISTORTION_COEF_X": list(COEF_X), key + "DISTORTION_COEF_Y": list(COEF_Y),
          key + "TRANSX": [0.0, 0.0, 0.0], key + "TRANSY": [0.0, -MI_PIXEL_MM, 0.0],
          key + "ITRANSS": [0.0, 0.0, -1.0 / MI_PIXEL_MM], key + "ITRANSL": [0.0, -1.0 / MI_PIXEL_MM, 0.0],
          key + "FOV_FRAME": "SIM_MI_N_HEAD"}
    write_text_kernel(kdir / "sim_inst.tf", "FK", _tk_frame(MI_FRAME, "SIM_MI_N_HEAD", HEAD_TO_SC),
                      "Synthetic MI head frame: +x along track.")
    write_text_kernel(kdir / "sim_inst.ti", "IK", ik, "Synthetic Kaguya-MI-like NIR camera (JAXA IK keywords).")


def _uvvis_kernels(kdir: Path) -> None:
    fk, ik = {}, {}
    p = UVVIS_PITCH_MM
    for filt, (code, focal, bs, bl, _um) in UVVIS_FILTERS.items():
        fk.update(_tk_frame(code, f"SIM_UVVIS_{filt}", np.eye(3)))
        k = f"INS{code}_"
        ik.update({k + "FOCAL_LENGTH": focal, k + "PIXEL_PITCH": p, k + "BORESIGHT_SAMPLE": bs, k + "BORESIGHT_LINE": bl,
                   k + "TRANSX": [0.0, p, 0.0], k + "TRANSY": [0.0, 0.0, p], k + "ITRANSS": [0.0, 1 / p, 0.0],
                   k + "ITRANSL": [0.0, 0.0, 1 / p], k + "PP": list(UVVIS_DISTORTION.pp), k + "OD_K": list(UVVIS_DISTORTION.odk),
                   k + "DECENTER": list(UVVIS_DISTORTION.decenter), k + "FILTER_NAME": filt})
    write_text_kernel(kdir / "sim_inst.tf", "FK", fk, "Synthetic UVVIS filter frames (= spacecraft axes).")
    write_text_kernel(kdir / "sim_inst.ti", "IK", ik, "Synthetic Clementine-UVVIS-like filters A and B.")


def _tc_kernels(kdir: Path) -> None:
    k, p = f"INS{TC_CODE}_", TC_PIXEL_MM
    ik = {k + "FOCAL_LENGTH": TC_FOCAL_MM, k + "PIXEL_SIZE": p, k + "PIXEL_SAMPLES": 4096.0, k + "CENTER": [2048.5, 1.0],
          k + "TRANSX": [0.0, 0.0, -p], k + "TRANSY": [0.0, -p, 0.0], k + "ITRANSS": [0.0, 0.0, -1 / p],
          k + "ITRANSL": [0.0, -1 / p, 0.0], k + "DISTORTION_COEF_X": list(TC_COEF_X),
          k + "DISTORTION_COEF_Y": list(TC_COEF_Y),
          k + "BORESIGHT": [-0.0725, 0.0214, TC_FOCAL_MM], k + "FOV_FRAME": "SIM_TC1_HEAD"}
    write_text_kernel(kdir / "sim_inst.tf", "FK", _tk_frame(TC_FRAME, "SIM_TC1_HEAD", HEAD_TO_SC),
                      "Synthetic TC1 head frame: +x along track.")
    write_text_kernel(kdir / "sim_inst.ti", "IK", ik, "Synthetic Kaguya-TC-like camera (JAXA IK keywords).")


def _tmc_kernels(kdir: Path) -> None:
    k, p = f"INS{TMC_CODE}_", TMC_PIXEL_MM
    ik = {k + "FOCAL_LENGTH": TMC_FOCAL_MM, k + "PIXEL_SIZE": p / 1000.0, k + "PIXEL_SAMPLES": float(TMC_SAMPLES),
          k + "CENTER": list(TMC_CENTER), k + "TRANSX": [0.0, 0.0, p], k + "TRANSY": [0.0, p, 0.0],
          k + "ITRANSS": [0.0, 0.0, 1 / p], k + "ITRANSL": [0.0, 1 / p, 0.0], k + "OD_K": list(TMC_ODK)}
    write_text_kernel(kdir / "sim_inst.tf", "FK", _tk_frame(TMC_CODE, "SIM_TMC_NADIR", TMC_HEAD_TO_SC),
                      "Synthetic TMC-2 nadir frame: +x against the flight.")
    write_text_kernel(kdir / "sim_inst.ti", "IK", ik, "Synthetic Chandrayaan-2-TMC-2-like camera.")


@dataclass
class _Instrument:
    kernels: Callable[[Path], None]
    shots: Callable
    image: Callable  # (scene, shot, p0, vel, m, sun, rng, noise) -> (bands, lines, samples), label groups, truth keys
    extra: dict = field(default_factory=dict)


def _line_shots(prefix: str, samples: int, lines: int = 160):
    """Shots of a line-scanner mission: ``prefix`` + number as key, ``lines`` x ``samples`` pixels, ~180 m."""
    def shots(rng, n_images: int) -> list[Shot]:
        return [Shot(key=f"{prefix}{k + 1:02d}", kind="line", et=ET_BASE + k * 7200.0 + 77.7,
                     exposure=float(rng.uniform(0.85, 1.2)), aim_lon=6.0 + rng.uniform(-0.2, 0.2),
                     aim_lat=-6.0 + rng.uniform(-0.2, 0.2), sun_azimuth=float(rng.uniform(0, 360)),
                     sun_elevation=float(rng.uniform(50, 65)), view_azimuth=float(rng.uniform(0, 360)),
                     view_zenith=float(rng.uniform(0, 6)), altitude_km=72.0, lines=lines, samples=samples, line_rate=0.11)
                for k in range(n_images)]
    return shots


def _line_signal(scene, s: Shot, p0, vel, m, sun, look, head_to_sc, dt: float = 0.0):
    """Noiseless A*T*R of a line scanner: ``look(samples)`` the head-frame lines of sight of the cube's samples;
    cube line ``k`` exposed ``(k - 0.5 - lines / 2) * rate + dt`` s after the shot's time (km, s)."""
    ll, ss = np.meshgrid(np.arange(1, s.lines + 1, dtype=float), np.arange(1, s.samples + 1, dtype=float), indexing="ij")
    t = (ll - 0.5) * s.line_rate - s.lines * s.line_rate / 2.0 + dt
    return surface_signal(scene, p0 + vel * t[..., None], look(ss) @ (m @ head_to_sc).T, p0, sun, s.exposure)


def _alpha_cube(parent, start, shape) -> dict:
    """ISIS ``AlphaCube`` group: a ``shape`` (samples, lines) crop starting at ``start`` (pixel edges) of ``parent``."""
    return {"AlphaSamples": parent[0], "AlphaLines": parent[1], "AlphaStartingSample": start[0],
            "AlphaStartingLine": start[1], "AlphaEndingSample": start[0] + shape[0], "AlphaEndingLine": start[1] + shape[1],
            "BetaSamples": shape[0], "BetaLines": shape[1]}


def _uvvis_shots(rng, n_images: int) -> list[Shot]:
    lines, samples = UVVIS_SHAPE
    return [Shot(key=f"LUASIM{k + 1:02d}", kind="frame", et=ET_BASE + k * 7200.0 + 33.3, exposure=float(rng.uniform(0.85, 1.2)),
                 aim_lon=6.0 + rng.uniform(-0.15, 0.15), aim_lat=-6.0 + rng.uniform(-0.15, 0.15),
                 sun_azimuth=float(rng.uniform(0, 360)), sun_elevation=float(rng.uniform(50, 65)),
                 view_azimuth=float(rng.uniform(0, 360)), view_zenith=float(rng.uniform(0, 8)), altitude_km=80.0,
                 lines=lines, samples=samples) for k in range(n_images)]


def _label_kernels(code: int) -> dict:
    return {"NaifFrameCode": code, "LeapSecond": "../kernels/sim.tls", "TargetAttitudeShape": "../kernels/sim.tpc",
            "TargetPosition": "../kernels/sim.bsp",
            "InstrumentPointing": ["../kernels/sim.bc", "../kernels/sim.tf", "../kernels/sim_inst.tf"],
            "Instrument": "../kernels/sim_inst.ti", "SpacecraftClock": "../kernels/sim.tsc",
            "InstrumentPosition": "../kernels/sim.bsp", "ShapeModel": "Null"}


def _mi_image(scene, s: Shot, p0, vel, m, sun, rng, noise):
    signal = _line_signal(scene, s, p0, vel, m, sun, ik_look, HEAD_TO_SC)  # line L at StartTime + (L - 0.5) rate
    img = np.stack([to_radiance(g * signal, noise, rng) for g in GAINS])
    start = s.et - s.lines * s.line_rate / 2.0
    groups = {"Instrument": {"MissionName": "SELENE", "SpacecraftName": "KAGUYA", "InstrumentName": "Multiband Imager Near Infrared",
                             "InstrumentId": "MI-NIR", "TargetName": "MOON", "StartTime": spiceypy.et2utc(start, "ISOC", 6),
                             "LineSamplingInterval": Quantity(s.line_rate * 1000.0, "msec"),
                             "CorrectedSamplingInterval": Quantity(s.line_rate * 1000.0, "msec")},
              "BandBin": {"FilterName": [f"MN{b + 1}" for b in range(len(BANDS_NM))], "Center": Quantity(list(BANDS_NM), "nm"),
                          "BaseBand": "MN1"},
              "Kernels": _label_kernels(MI_CODE)}
    keys = {f"{s.key:_<8}"[:8] + f"B{b:02d}": dict(exposure=s.exposure * g, band=b, band_center_nm=BANDS_NM[b - 1])
            for b, g in enumerate(GAINS, 1)}  # ingest's key of band b (ingest.keys.band_items)
    return img, groups, keys


def _uvvis_image(scene, s: Shot, p0, vel, m, sun, rng, noise):
    filt = "AB"[int(s.key[-2:]) % 2 == 0]
    code, _f, _bs, _bl, um = UVVIS_FILTERS[filt]
    ll, ss = np.meshgrid(np.arange(1, s.lines + 1, dtype=float), np.arange(1, s.samples + 1, dtype=float), indexing="ij")
    signal = surface_signal(scene, np.broadcast_to(p0, ll.shape + (3,)), uvvis_look(filt, ss, ll) @ m.T, p0, sun, s.exposure)
    exposure_ms = 9.0624
    groups = {"Instrument": {"SpacecraftName": "CLEMENTINE 1", "InstrumentId": "UVVIS", "TargetName": "MOON",
                             "StartTime": spiceypy.et2utc(s.et - exposure_ms / 2000.0, "ISOC", 6),
                             "ExposureDuration": Quantity(exposure_ms, "ms")},
              "BandBin": {"FilterName": filt, "Center": Quantity(um, "micrometers")},
              "Kernels": _label_kernels(code)}
    return to_radiance(signal, noise, rng)[None], groups, {f"{s.key:_<11}": dict(exposure=s.exposure, band_center_nm=um * 1000)}


def _tc_image(scene, s: Shot, p0, vel, m, sun, rng, noise):
    sample0, line0 = TC_CROP
    nominal = s.et - (line0 - 0.5 + s.lines / 2.0) * s.line_rate  # parent line 1: the crop's middle at the shot's time
    count = spiceypy.sce2s(SC, nominal)
    et0 = spiceypy.scs2e(SC, count)  # whole clock ticks
    look = lambda ss: tc_look(ss + sample0 - 0.5 + TC_SWATH_START - 1.0)  # noqa: E731 - cube -> parent -> detector sample
    signal = _line_signal(scene, s, p0, vel, m, sun, look, HEAD_TO_SC, et0 - nominal)
    groups = {"Instrument": {"MissionName": "SELENE", "SpacecraftName": "KAGUYA", "InstrumentName": "TERRAIN CAMERA 1",
                             "InstrumentId": "TC1", "TargetName": "MOON", "SwathModeId": "NOMINAL",
                             "StartTime": spiceypy.et2utc(et0 - 0.030, "ISOC", 6), "SpacecraftClockStartCount": count,
                             "LineSamplingInterval": Quantity(s.line_rate * 1000.0, "ms")},
              "BandBin": {"FilterName": "BroadBand", "Center": "640nm", "Width": "420nm"},
              "Kernels": _label_kernels(TC_CODE),
              "AlphaCube": _alpha_cube((TC_SWATH_SAMPLES, s.lines + 2 * int(line0 - 0.5)), TC_CROP, (s.samples, s.lines))}
    return to_radiance(signal, noise, rng)[None], groups, {f"{s.key:_<11}": dict(exposure=s.exposure, band_center_nm=640.0)}


def _tmc_image(scene, s: Shot, p0, vel, m, sun, rng, noise):
    start = s.et - s.lines * s.line_rate / 2.0
    look = lambda ss: tmc_look(TMC_SUMMING * (ss + TMC_CROP_SAMPLE - 0.5) - 0.5)  # noqa: E731 - cube -> parent -> detector
    signal = _line_signal(scene, s, p0, vel, m, sun, look, TMC_HEAD_TO_SC)
    groups = {"Instrument": {"SpacecraftName": "Chandrayaan-2", "InstrumentId": "CH2_TMC_NADIR", "TargetName": "Moon",
                             "StartTime": spiceypy.et2utc(start, "ISOC", 6),
                             "StopTime": spiceypy.et2utc(start + s.lines * s.line_rate, "ISOC", 6),
                             "LineExposureDuration": Quantity(s.line_rate * 1000.0, "ms"), "SpatialSumming": TMC_SUMMING},
              "BandBin": {"Center": Quantity(675.0, "nm"), "Width": Quantity(50.0, "nm")},
              "Kernels": _label_kernels(TMC_CODE),
              "AlphaCube": _alpha_cube((TMC_SAMPLES // TMC_SUMMING, s.lines), (TMC_CROP_SAMPLE, 0.5), (s.samples, s.lines))}
    return to_radiance(signal, noise, rng)[None], groups, {f"{s.key:_<11}": dict(exposure=s.exposure, band_center_nm=675.0)}


#: the missions by instrument name (the names of ``camera.instruments``, which ingest recognises in their labels)
INSTRUMENTS = {KAGUYA_MI: _Instrument(_mi_kernels, _line_shots("MNSIM", MI_SAMPLES), _mi_image,
                                      {"band_gains": dict(zip(map(str, BANDS_NM), GAINS))}),
               CLEMENTINE_UVVIS: _Instrument(_uvvis_kernels, _uvvis_shots, _uvvis_image),
               KAGUYA_TC: _Instrument(_tc_kernels, _line_shots("TC1SIM", 120), _tc_image),
               CHANDRAYAAN2_TMC2: _Instrument(_tmc_kernels, _line_shots("TMCSIM", 120), _tmc_image)}


def plan(instrument: str, seed: int, n_images: int):
    """``(rng, scene, shots)`` of a mission: the random scene and shots that :func:`build` renders (the rng then
    draws the noise); ``mission.shot_geometry(scene, shot)`` gives a shot's spacecraft, velocity and pointing."""
    rng = np.random.default_rng(seed)
    scene = make_scene(rng)
    return rng, scene, INSTRUMENTS[instrument].shots(rng, n_images)


def build(out: str | Path, instrument: str = "kaguya_mi", seed: int = 4601, n_images: int = 3, noise: float = 0.005) -> dict:
    """Write DEM, truth albedo, kernels, the instrument's cubes and truth.json under ``out``; return the truth."""
    inst = INSTRUMENTS[instrument]
    out = Path(out)
    rng, scene, shots = plan(instrument, seed, n_images)
    kdir = out / "kernels"
    geo = write_kernels(kdir, scene, shots)
    inst.kernels(kdir)
    truth = write_scene_truth(out, scene, noise, seed, instrument=instrument, **inst.extra)
    with KernelPool([kdir / n for n in KERNEL_FILES]):
        for s in shots:
            p0, vel, m, _ = geo[s.key]
            sun, _ = spiceypy.spkpos("SUN", s.et, "J2000", "LT+S", "MOON")
            sun = np.asarray(spiceypy.pxform("J2000", "MOON_ME", s.et)) @ np.asarray(sun)
            img, groups, keys = inst.image(scene, s, p0, vel if s.kind == "line" else np.zeros(3), m, sun, rng, noise)
            write_cube(out / "cubes" / f"{s.key}.cub", img if len(img) > 1 else img[0], groups)
            for key, extra in keys.items():
                truth["images"][key] = {"sun_km": sun.tolist(), "spacecraft_km": p0.tolist(), "et": s.et,
                                        "cube": f"cubes/{s.key}.cub", **extra}
    write_truth(out, truth)
    return truth
