"""Forward model of an LE/RE line-scanner pair with a known RE boresight error (tests and docs of ``nacmosaic``).

Reuses the synthetic mission of :mod:`.mission` (scene, SPK/CK of
the spacecraft, renderer) and adds two CCD frames fixed to the spacecraft
(``sim_nac.tf``/``sim_nac.ti``): LE looks ``(samples - overlap) / 2`` pixels to one
side, RE as far to the other and ``ahead`` pixels along the track.  The kernels
hold these nominal frames; RE is *rendered* with an extra rotation of
``boresight_error`` = (across, along) pixels that the kernels do not know - the
LE/RE offset ``jitreg`` must find.  ``render_ideal`` renders, column by column,
what an ideal camera (:class:`~lunaralbedo.nac.ideal.IdealSpec`) sees, noise-free.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import spiceypy

from .mission import ET_BASE, FOCAL_MM, KERNEL_FILES, PITCH_MM, Shot, make_scene, render, write_kernels
from ..io.atomic import atomic_write_text
from ..io.rasters import MOON_CRS
from ..io.geotiff import write_geotiff
from ..isis.write import Quantity, write_cube
from ..spice.kernels import KernelPool
from ..spice.writers import write_text_kernel
from ..nac.synthetic import WaveTexture

LE_CODE, RE_CODE = -999011, -999012


def _ry(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


@dataclass
class Pair:
    """Paths and truth of a simulated pair; ``m`` etc. are body-fixed (km) geometry of the spacecraft."""

    le: Path
    re: Path
    shot: Shot
    scene: object
    geometry: tuple
    sun: np.ndarray
    frames: dict  # CCD -> spacecraft matrices actually used for rendering


def _frames_kernels(kdir: Path, samples: int, overlap: int, ahead: float, focal_mm: float = FOCAL_MM) -> dict:
    ifov = PITCH_MM / focal_mm
    a = (samples - overlap) / 2.0 * ifov
    nominal = {"LE": _ry(-a), "RE": _ry(a) @ _rx(-ahead * ifov)}
    fk, ik = {}, {}
    for name, code in (("LE", LE_CODE), ("RE", RE_CODE)):
        frame = f"SIM_NAC_{name}"
        fk.update({f"FRAME_{frame}": code, f"FRAME_{code}_NAME": frame, f"FRAME_{code}_CLASS": 4,
                   f"FRAME_{code}_CLASS_ID": code, f"FRAME_{code}_CENTER": -999,
                   f"TKFRAME_{code}_RELATIVE": "SIM_SPACECRAFT", f"TKFRAME_{code}_SPEC": "MATRIX",
                   f"TKFRAME_{code}_MATRIX": list(nominal[name].T.ravel())})
        ik.update({f"INS{code}_FOCAL_LENGTH": focal_mm, f"INS{code}_PIXEL_PITCH": PITCH_MM,
                   f"INS{code}_TRANSX": [0.0, PITCH_MM, 0.0], f"INS{code}_TRANSY": [0.0, 0.0, PITCH_MM],
                   f"INS{code}_ITRANSS": [0.0, 1 / PITCH_MM, 0.0], f"INS{code}_ITRANSL": [0.0, 0.0, 1 / PITCH_MM],
                   f"INS{code}_BORESIGHT_SAMPLE": (samples + 1) / 2.0, f"INS{code}_BORESIGHT_LINE": 0.0})
    write_text_kernel(kdir / "sim_nac.tf", "FK", fk, "Synthetic LE/RE CCD frames (nominal, no boresight error).")
    write_text_kernel(kdir / "sim_nac.ti", "IK", ik, "Synthetic LE/RE line scanners.")
    return nominal


def build_pair(out: str | Path, seed: int = 4, samples: int = 100, overlap: int = 40, lines: int = 320,
               ahead: float = 3.0, boresight_error=(0.6, 0.4), noise: float = 0.003, focal_mm: float = FOCAL_MM,
               line_rate: float | None = None, rendered: bool = True) -> Pair:
    """Write kernels, ``dem/dem.tif`` and ``cubes/SIMNAC_LE.cub``/``SIMNAC_RE.cub`` under ``out``; see the module docstring.

    ``rendered=False`` (benchmarks of large pairs): the cubes hold uniform noise instead of a
    rendering, and ``focal_mm``/``line_rate`` may differ from the renderer's camera (e.g. NAC-like
    10 um/700 mm pixels on a 5064-sample CCD).
    """
    if rendered and focal_mm != FOCAL_MM:
        raise ValueError("a rendered pair uses the renderer's focal length")
    out = Path(out)
    rng = np.random.default_rng(seed)
    scene = make_scene(rng)
    # small-scale albedo texture (a few image pixels) so that LE and RE can be correlated
    tex = WaveTexture.random(rng, 120, fmin=0.05, fmax=0.3)
    rows, cols = np.mgrid[0:scene.albedo.shape[0], 0:scene.albedo.shape[1]]
    t = tex(cols, rows)
    scene.albedo = np.clip(scene.albedo * (1.0 + 0.2 * t / t.std()), 0.03, 0.3)
    shot = Shot(key="SIMNAC", kind="line", et=ET_BASE + 86400.0 + 77.7, exposure=1.0, aim_lon=6.0, aim_lat=-6.0,
                sun_azimuth=100.0, sun_elevation=55.0, view_azimuth=0.0, view_zenith=2.0, lines=lines,
                samples=samples, **({"line_rate": line_rate} if line_rate else {}))
    kdir = out / "kernels"
    write_geotiff(out / "dem" / "dem.tif", scene.heights.astype(np.float32), scene.grid.transform, MOON_CRS,
                  nodata=-32767.0, dtype="float32")
    geo = write_kernels(kdir, scene, [shot])[shot.key]
    nominal = _frames_kernels(kdir, samples, overlap, ahead, focal_mm)
    ifov = PITCH_MM / focal_mm
    err = _ry(boresight_error[0] * ifov) @ _rx(-boresight_error[1] * ifov)
    frames = {"LE": nominal["LE"], "RE": nominal["RE"] @ err}
    p0, vel, m, _sun = geo
    kernels = [kdir / n for n in KERNEL_FILES] + [kdir / "sim_nac.tf", kdir / "sim_nac.ti"]
    paths = {}
    with KernelPool(kernels):
        sun, _ = spiceypy.spkpos("SUN", shot.et, "J2000", "LT+S", "MOON")
        sun = np.asarray(spiceypy.pxform("J2000", "MOON_ME", shot.et)) @ np.asarray(sun)
        start = shot.et - lines * shot.line_rate / 2.0
        for name, code in (("LE", LE_CODE), ("RE", RE_CODE)):
            img = render(scene, shot, p0, vel, m @ frames[name], sun, rng, noise) if rendered else \
                rng.uniform(0.05, 0.15, (lines, samples)).astype(np.float32)
            inst = {"SpacecraftName": "LUNARALBEDO SIM", "InstrumentId": f"NAC{name[0]}", "TargetName": "MOON",
                    "StartTime": spiceypy.et2utc(start, "ISOC", 6),
                    "SpacecraftClockStartCount": spiceypy.sce2s(-999, start),
                    "LineExposureDuration": Quantity(shot.line_rate * 1000.0, "ms")}
            kern = {"NaifFrameCode": code, "LeapSecond": "../kernels/sim.tls", "TargetAttitudeShape": "../kernels/sim.tpc",
                    "TargetPosition": "../kernels/sim.bsp",
                    "InstrumentPointing": ["../kernels/sim.bc", "../kernels/sim.tf", "../kernels/sim_nac.tf"],
                    "Instrument": "../kernels/sim_nac.ti", "SpacecraftClock": "../kernels/sim.tsc",
                    "InstrumentPosition": "../kernels/sim.bsp", "ShapeModel": "Null"}
            paths[name] = out / "cubes" / f"SIMNAC_{name}.cub"
            write_cube(paths[name], img, {"Instrument": inst, "Kernels": kern})
    truth = {"boresight_error_px": list(boresight_error), "samples": samples, "overlap": overlap, "ahead": ahead,
             "noise_relative": noise, "seed": seed}
    atomic_write_text(out / "truth.json", json.dumps(truth, indent=1) + "\n")
    return Pair(paths["LE"], paths["RE"], shot, scene, geo, sun, frames)


def _ideal_looks(spec, sample) -> np.ndarray:
    """Unit look vectors ``(..., 3)`` in the LE frame of ideal-camera 1-based ``sample`` (the detector row)."""
    ds = np.asarray(sample, dtype=np.float64) - (spec.samples / 2.0 + 0.5)
    u = np.stack([spec.x0 + spec.sample_axis[0] * ds, spec.y0 + spec.sample_axis[1] * ds,
                  np.full(np.shape(ds), spec.focal_length)], axis=-1)
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def ideal_rays(pair: Pair, spec, sample, line) -> tuple[np.ndarray, np.ndarray]:
    """True rays of ideal-camera pixels at 1-based ``(sample, line)``: origins (km, body-fixed) and unit directions.

    The geometry the pair was rendered with (spacecraft ``p0 + vel t``, line ``l`` at
    ``t = (l - 0.5) rate - lines rate / 2``, the LE frame), not the kernels'.
    """
    p0, vel, m, _ = pair.geometry
    shot = pair.shot
    t = (np.asarray(line, dtype=np.float64) - 0.5) * shot.line_rate - shot.lines * shot.line_rate / 2.0
    return p0 + vel * t[..., None], _ideal_looks(spec, sample) @ (m @ pair.frames["LE"]).T


def render_ideal(pair: Pair, spec, columns) -> np.ndarray:
    """Noise-free image ``(lines, len(columns))`` of the ideal camera's 0-based ``columns`` (LE frame, true)."""
    p0, vel, m, _ = pair.geometry
    out = []
    for c in columns:
        z = _ideal_looks(spec, c + 1.0)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        q = np.stack([x, np.cross(z, x), z], axis=1)  # a frame whose z axis is the column's look direction
        one = Shot(**{**pair.shot.__dict__, "samples": 1})
        out.append(render(pair.scene, one, p0, vel, m @ pair.frames["LE"] @ q, pair.sun, np.random.default_rng(0), 0.0)[:, 0])
    return np.stack(out, axis=1)
