"""The ideal line-scan camera of the ASP LRO-NAC notes (ISIS ``noproj``) and the LE/RE mosaic (``handmos``), pure math.

Ideal camera (ISIS ``IdealCamera``, LE as the match): the LE's frame, timing and
focal length, no distortion, one row of ``samples`` detectors of the LE's pixel
pitch whose centre sits at focal-plane offset ``(x0, y0)`` mm from the LE's
boresight (ISIS's ``TransX0``/``TransY0``; the ASP LRO-NAC notes' NAC values are
``TransY = 16.8833`` mm, ``TransX = 0.6475`` mm, ``DetectorSamples = 10000``,
7 um pixels).  For a pair listed in :data:`NOPROJ_INSTRUMENTS` (the real LRO NAC) those
typed numbers are used, as ISIS ``noproj`` reads them from ``noprojInstruments*.pvl``
(:func:`noproj_spec`); for any other pair the offset is half-way between the LE and
RE boresights in the LE focal plane (the ASP LRO-NAC notes: "the angle between the two cameras
... divide by two"), computed from the two camera models (:func:`ideal_spec`).

``noproj``: every ideal pixel's ray meets the sphere of radius ``R + h`` (``h`` the
mean DEM height; ISIS intersects the ellipsoid) and the ground point is projected
into the input CCD; the mapping is computed every ``step`` pixels and
interpolated bilinearly (it is smooth), and the CCD image is sampled with cubic
splines, in blocks of lines (:mod:`.noproj`).  A measured LE/RE offset ``(so, lo)`` (convention of
:mod:`lunaralbedo.nac.jitreg`) is applied to RE by sampling it at ideal pixel
``(x - so, y - lo)``: sub-pixel, in the same single resampling.
"""
from __future__ import annotations

import numpy as np

from ..camera.model import CameraModel, DetectorMap
from ..camera.ideal import IdealSpec
from ..errors import InputError

#: ISIS ``noproj`` ideal-camera definitions (keys ``SpacecraftName/InstrumentId`` of the match cube, as the
#: groups of ``noprojInstruments*.pvl``): the ASP LRO-NAC notes' LRO NAC numbers, also written by ASP's ``lronac2mosaic.py``.
#: ``TransX``/``TransY`` in mm (focal-plane position of the ideal detector centre, LE frame), ``ItransS``/``ItransL``
#: the same in unsummed pixels (``-Trans / pitch``), ``DetectorSamples`` unsummed.
NOPROJ_INSTRUMENTS = {
    "LUNAR RECONNAISSANCE ORBITER/NACL": {"TransY": 16.8833, "ItransS": -2411.9, "TransX": 0.6475, "ItransL": -92.5,
                                         "DetectorSamples": 10000},
}


def ideal_camera(spec: IdealSpec, ephemeris, match: CameraModel) -> CameraModel:
    """A line-scan :class:`CameraModel` of ``spec`` on the match camera's ephemeris, one line per match cube line.

    Ideal line ``L`` is exposed when the match cube's line ``L`` is (also for a cropped or
    line-summed match cube: the ideal camera has no AlphaCube).
    """
    from ..camera.model import LineTiming

    mid = (match.samples + 1) / 2.0
    et0, et1 = (float(match.pixel_et(mid, l)) for l in (0.5, 1.5))
    return CameraModel(spec.focal_plane(), DetectorMap(), (match.lines, spec.samples), ephemeris,
                       timing=LineTiming(et0=et0, rate=et1 - et0))


def _focal_xy(v):
    return v[..., 0] / v[..., 2], v[..., 1] / v[..., 2]


def ideal_spec(le: CameraModel, re: CameraModel, margin: int = 2) -> IdealSpec:
    """The ideal camera half-way between LE and RE boresights, wide enough for both CCDs (see module docstring)."""
    f, fp = le.focal.focal_length, le.focal
    rel = le.rotations[len(le.rotations) // 2].T @ re.rotations[len(re.rotations) // 2]  # RE frame -> LE frame

    def in_le(cam, ds):
        look = cam.focal.look(ds, np.full(np.shape(ds), -cam.focal.origin_line))
        v = look if cam is le else look @ rel.T
        x, y = _focal_xy(v)
        return f * x, f * y

    xl, yl = in_le(le, np.array([0.0]))
    xr, yr = in_le(re, np.array([0.0]))
    x0, y0 = float((xl[0] + xr[0]) / 2), float((yl[0] + yr[0]) / 2)
    sx, sy = fp.transx[1], fp.transy[1]
    pitch = float(np.hypot(sx, sy))
    ends = []
    for cam in (le, re):
        alpha = cam.detector.alpha(np.array([0.5, cam.samples + 0.5]), 1.0)[0]
        x, y = in_le(cam, cam.detector.detector_sample(alpha) - cam.focal.origin_sample)
        ends += list(((x - x0) * sx + (y - y0) * sy) / pitch ** 2)
    half = int(np.ceil(max(abs(e) for e in ends))) + margin
    return IdealSpec(f, pitch, 2 * half, x0, y0, (sx, sy), (fp.transx[2], fp.transy[2]))


def noproj_spec(le: CameraModel, group: dict, summing: float = 1.0, name: str = "noproj definition") -> IdealSpec:
    """The ideal camera of an ISIS ``noproj`` definition ``group`` (keys of :data:`NOPROJ_INSTRUMENTS`) on ``le``.

    As ``noproj``: ``TransX0 = TransX``, ``TransY0 = TransY`` (mm), the pitch and axes are the
    match camera's (times ``summing``), ``DetectorSamples / summing`` samples.  ``ItransS``
    and ``ItransL`` must be ``-Trans / pitch`` of the axis that follows samples and lines
    (the ASP LRO-NAC notes: if they do not match, "funny errors will occur"); InputError otherwise.
    """
    fp = le.focal
    sa, la = np.array([fp.transx[1], fp.transy[1]]), np.array([fp.transx[2], fp.transy[2]])
    trans = np.array([float(group.get("TransX", 0.0)), float(group.get("TransY", 0.0))])
    for key, axis in (("ItransS", sa), ("ItransL", la)):
        expect = -float(trans @ axis) / float(axis @ axis)
        if key in group and abs(float(group[key]) - expect) > 0.05:
            raise InputError(f"{name}: {key} = {group[key]} does not match TransX/TransY ({expect:.2f} px expected)")
    samples = int(round(float(group["DetectorSamples"]) / summing))
    return IdealSpec(fp.focal_length, float(np.hypot(*sa)) * summing, samples, float(trans[0]), float(trans[1]),
                     tuple(float(v) * summing for v in sa), tuple(float(v) * summing for v in la))


def blend(le: np.ndarray, re: np.ndarray, columns: tuple[int, int]) -> np.ndarray:
    """One image: LE left of the overlap ``columns``, RE right of it, a linear ramp across it (no seam)."""
    x = np.arange(le.shape[1], dtype=np.float64)
    a, b = columns
    w = np.clip((x - a) / max(1.0, b - 1 - a), 0.0, 1.0)[None, :]
    both = np.isfinite(le) & np.isfinite(re)
    out = np.where(np.isfinite(le), le, re)
    return np.where(both, (1 - w) * le + w * re, out).astype(np.float32)
