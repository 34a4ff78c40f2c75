"""LRO WAC push-frame camera (ISIS ``LroWideAngleCamera`` conventions; pure NumPy once built).

Each band of a WAC cube is a stack of framelets (VIS: 14 lines, UV: 16 detector lines
summed 4x).  Parent line ``L`` (1-based) lies in framelet ``n = int((L - 0.5) / h) + 1``
(``h`` = framelet height / line summing) at framelet line ``f = L - h (n - 1)``; the
framelet is exposed at ``t0 + (n - 1 - offset) * InterframeDelay`` (reversed when the
data are flipped) with ``t0`` = SCLK start + ExposureDuration / 2.  On the detector,
``sample = (s - 1) * summing + summing/2 + 0.5 + (COLOR_SAMPLE_OFFSET + 1) - 1`` and
``line = FILTER_OFFSET(band) + (f - 1) * summing + summing/2 + 0.5``.  Each filter has
its own IK (code ``IK - (7 + band id)`` for VIS, ``IK - (14 + band id)`` for UV):
focal length, boresight (detector origin = boresight + 1), TRANSX/Y, ITRANSS/L and the
radial distortion ``u = d (1 + k1 r^2 + k2 r^4 + k3 r^6)``.  The cube's size is what
its label says (a reduced cube without AlphaCube is treated as a small image, as ISIS does).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import IsisError, SpiceError
from ..isis.labels import IsisLabel, value_of
from .model import DetectorMap
from .optics import FocalPlane, _Iterative
from .timing import _sclk_et, naif_value


@dataclass
class WacDistortion(_Iterative):
    """LRO WAC radial distortion: undistorted = distorted * (1 + k1 r^2 + k2 r^4 + k3 r^6), mm."""

    odk: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def undistort(self, x, y):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        k1, k2, k3 = self.odk
        rr = x * x + y * y
        dr = 1.0 + rr * (k1 + rr * (k2 + rr * k3))
        return x * dr, y * dr


def _ints(v):
    return [int(round(float(x))) for x in (v if isinstance(v, (list, tuple)) else [v])]


class PushFrameCamera:
    """A push-frame camera for one band: ``rays``, ``pixel_et`` and ``ground_to_image`` like :class:`CameraModel`."""

    #: Ground -> image is piecewise (one piece per framelet, cube lines jump between framelets),
    #: so orthoprojection projects every pixel exactly instead of interpolating a coarse grid.
    smooth_ground_map = False

    def __init__(self, focal: FocalPlane, detector: DetectorMap, shape, ephemeris, et_start: float, rate: float,
                 framelet_height: int, line_summing: int, band_start_line: float, framelet_offset: int = 0,
                 reversed_order: bool = False, even: bool = False):
        self.focal, self.detector = focal, detector
        self.lines, self.samples = int(shape[0]), int(shape[1])
        self.h = int(framelet_height / line_summing)
        self.line_summing = line_summing
        self.band_start = band_start_line
        self.n_framelets = max(1, self.lines // self.h)
        self.et_start, self.rate, self.offset, self.reversed = et_start, rate, framelet_offset, reversed_order
        self.even = even
        n = np.arange(1, self.n_framelets + 2)  # one spare for a partial last framelet
        self.knots = self.framelet_et(n)
        self.positions = np.asarray(ephemeris.spacecraft(self.knots), dtype=np.float64).reshape(-1, 3)
        self.rotations = np.asarray(ephemeris.camera_to_body(self.knots), dtype=np.float64).reshape(-1, 3, 3)
        self.timing = None

    is_line_scanner = False

    def framelet_et(self, n):
        """Exposure time (s, TDB) of framelet ``n`` (1-based)."""
        k = np.asarray(n) - self.offset
        return self.et_start + ((self.n_framelets - k) if self.reversed else (k - 1)) * self.rate

    @property
    def center_et(self) -> float:
        return float(self.pixel_et((self.samples + 1) / 2, (self.lines + 1) / 2))

    def _framelet(self, line):
        return np.clip((np.asarray(line, dtype=np.float64) - 0.5) // self.h + 1, 1, self.n_framelets + 1).astype(int)

    def pixel_et(self, sample, line):
        return np.broadcast_to(self.framelet_et(self._framelet(line)), np.broadcast(sample, line).shape)

    def _detector_line(self, framelet_line):
        s = self.line_summing
        return self.band_start + (framelet_line - 1.0) * s + s / 2.0 + 0.5

    def rays(self, sample, line):
        """Origins (km) and unit directions (body-fixed) of the rays through cube pixels ``(sample, line)``."""
        sample = np.asarray(sample, dtype=np.float64)
        line = np.asarray(line, dtype=np.float64)
        n = self._framelet(line)
        fl = line - self.h * (n - 1)
        ds = self.detector.detector_sample(self.detector.alpha(sample, line)[0]) - self.focal.origin_sample
        dl = self._detector_line(fl) - self.focal.origin_line
        look = np.einsum("...ij,...j->...i", self.rotations[n - 1], self.focal.look(ds, dl))
        return np.array(self.positions[n - 1]), look / np.linalg.norm(look, axis=-1, keepdims=True)

    def ground_to_image(self, points, iterations: int = 0, clip: bool = True):
        """Cube ``(sample, line)`` of body-fixed points (km); NaN when no framelet of this cube's parity sees them.

        ``clip`` is accepted for the interface of :class:`CameraModel`: a point outside every
        framelet has no coordinates, so the result is the same either way.
        """
        p = np.asarray(points, dtype=np.float64)
        best_s = np.full(p.shape[:-1], np.nan)
        best_l = np.full(p.shape[:-1], np.nan)
        best_rank = np.full(p.shape[:-1], 9)
        for k in range(1, self.n_framelets + 1):
            v = np.einsum("ji,...j->...i", self.rotations[k - 1], p - self.positions[k - 1])
            ds, dl = self.focal.project(v)
            fl = (dl + self.focal.origin_line - self.band_start - 0.5 - self.line_summing / 2.0) / self.line_summing + 1
            s = self.detector.beta(self.detector.alpha_sample(ds + self.focal.origin_sample), 0.0)[0]
            line = fl + self.h * (k - 1)
            ok = (fl >= 0.5) & (fl <= self.h + 0.5) & (s >= 0.5) & (s <= self.samples + 0.5) & (line <= self.lines + 0.5)
            rank = np.where((k % 2 == 0) == self.even, 0, 1)  # prefer framelets of the cube's parity (ISIS ground map)
            take = ok & (rank < best_rank)
            best_s, best_l, best_rank = np.where(take, s, best_s), np.where(take, line, best_l), np.where(take, rank, best_rank)
        return best_s, best_l


def build_pushframe(label: IsisLabel, ephemeris, band: int = 1) -> PushFrameCamera:
    """The LRO WAC camera of band ``band`` (1-based) from the label, its NaifKeywords or the loaded IK/IAK."""
    inst = label.instrument
    k = label.group("Kernels")
    ik = int(value_of(k.get("NaifIkCode", k.get("NaifFrameCode", 0))))
    inst_id = str(value_of(inst.get("InstrumentId", ""))).upper()
    if inst_id == "WAC-UV":
        summing, height, ik_base = 4, 16, 14
    elif inst_id == "WAC-VIS":
        summing, height, ik_base = 1, 14, 7
    else:
        raise IsisError(f"{label.path}: push-frame camera {inst_id!r} is not modelled (LRO WAC-VIS / WAC-UV)")

    def need(name):
        v = naif_value(label, name)
        if v is None:
            raise SpiceError(f"{label.path}: {name} is not defined (load the LROC IK/IAK or spiceinit the cube)")
        return v

    centers = label.group("BandBin")["Center"]
    centers = [int(round(float(value_of(c)))) for c in (centers if isinstance(centers, (list, tuple)) else [centers])]
    if not 1 <= band <= len(centers):
        raise IsisError(f"{label.path}: band {band} out of range 1..{len(centers)}")
    fbc = _ints(need(f"INS{ik}_FILTER_BANDCENTER"))
    foff = _ints(need(f"INS{ik}_FILTER_OFFSET"))
    fid = _ints(need(f"INS{ik}_FILTER_BANDID"))
    if centers[band - 1] not in fbc:
        raise IsisError(f"{label.path}: band centre {centers[band - 1]} nm is not a filter of INS{ik} ({fbc})")
    j = fbc.index(centers[band - 1])
    code = ik - (ik_base + fid[j])
    flipped = str(value_of(inst.get("DataFlipped", "No"))).upper() == "YES"
    color_offset = int(value_of(inst.get("ColorOffset", 0))) * (-1 if flipped else 1)
    wavelengths_by_offset = [c for _o, c in sorted(zip(foff, fbc))]
    framelet_offset = wavelengths_by_offset.index(centers[band - 1]) * color_offset
    mode = str(value_of(inst.get("InstrumentModeId", "COLOR"))).upper()
    if mode == "BW":
        mode += str(value_of(inst.get("Mode", "")))
        framelet_offset = 0 if band == 1 else framelet_offset
    samp_offset = int(float(need(f"INS{ik}_{mode}_SAMPLE_OFFSET")))
    f = [float(x) for x in need(f"INS{code}_TRANSX")], [float(x) for x in need(f"INS{code}_TRANSY")]
    it = [float(x) for x in need(f"INS{code}_ITRANSS")], [float(x) for x in need(f"INS{code}_ITRANSL")]
    odk = tuple(float(x) for x in need(f"INS{code}_OD_K"))[:3]
    focal = FocalPlane(float(need(f"INS{code}_FOCAL_LENGTH")), tuple(f[0]), tuple(f[1]), tuple(it[0]), tuple(it[1]),
                       float(need(f"INS{code}_BORESIGHT_SAMPLE")) + 1.0, float(need(f"INS{code}_BORESIGHT_LINE")) + 1.0,
                       WacDistortion(odk))
    det = DetectorMap(sample_summing=summing, start_sample=samp_offset + 1.0)
    exposure = float(value_of(inst["ExposureDuration"])) / 1000.0
    et0 = _sclk_et(label, str(value_of(inst["SpacecraftClockStartCount"])), ik) + exposure / 2.0
    rate = float(value_of(inst["InterframeDelay"])) / 1000.0
    _b, lines, samples = label.shape
    even = str(value_of(inst.get("Framelets", "Odd"))).upper() == "EVEN"
    return PushFrameCamera(focal, det, (lines, samples), ephemeris, et0, rate, height, summing, float(foff[j]),
                           framelet_offset, flipped, even)
