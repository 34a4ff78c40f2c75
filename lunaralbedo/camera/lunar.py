"""Camera models of Kaguya MI and TC, Clementine UVVIS and Chandrayaan-2 TMC-2, following ISIS's plugins.

IK values come from the kernel pool or the label's ``NaifKeywords`` (``naif_value``);
``code`` is the label's ``NaifFrameCode`` (the instrument/filter IK code). Conventions
(ISIS pixel coordinates: first pixel centre = 1; detector offsets = detector coordinate
minus the detector origin; line scanners look through detector line 0):

* Kaguya MI (``KaguyaMiCamera``): line scanner timed from ``StartTime`` with
  ``CorrectedSamplingInterval``; pixel pitch ``PIXEL_SIZE``; origin
  ``(CENTER[0], CENTER[1] - 1)``; first detector sample 1, no summing; every band of an
  L2B cube is registered to the base band, so all bands share the base band's IK code;
  distortion :class:`~.lunar_optics.KaguyaMiDistortion` (3 coefficients for VIS, 4 for NIR).
* Kaguya TC (``KaguyaTcCamera``): line scanner (``LineSamplingInterval``; start time as the
  generic line scanner: the SCLK count when the clock is loaded, which is ale's time);
  origin ``(2048.5, 1.0)``; first detector sample 1, 297 or 1172 for the FULL, NOMINAL and
  HALF swath modes; distortion :class:`~.lunar_optics.KaguyaTcDistortion`.
* Clementine UVVIS (``UvvisCamera``): frame camera at ``StartTime + ExposureDuration / 2``,
  one filter per cube (its own IK code, focal length and ``PP``/``OD_K``/``DECENTER``),
  origin ``(BORESIGHT_SAMPLE, BORESIGHT_LINE)``, distortion
  :class:`~.lunar_optics.ClementineUvvisDistortion`.
* Chandrayaan-2 TMC-2 (``Chandrayaan2TmcCamera``): line scanner from ``StartTime`` with
  ``LineExposureDuration``, pixel pitch ``PIXEL_SIZE`` (metres) * 1000, sample summing
  ``SpatialSumming``, origin ``CENTER``, ISIS's default radial ``OD_K`` map.
"""
from __future__ import annotations

from ..errors import IsisError, SpiceError
from ..isis.labels import IsisLabel, value_of
from .instruments import CHANDRAYAAN2_TMC2, CLEMENTINE_UVVIS, KAGUYA_MI, KAGUYA_TC, instrument_of
from .lunar_optics import ClementineUvvisDistortion, KaguyaMiDistortion, KaguyaTcDistortion
from .model import CameraModel, DetectorMap
from .optics import FocalPlane, RadialOdk
from .timing import frame_et, line_timing, naif_value

TC_SWATH_START = {"FULL": 1.0, "NOMINAL": 297.0, "HALF": 1172.0}


def _floats(v, n=None):
    vals = [float(x) for x in (v if isinstance(v, (list, tuple)) else [v])]
    return vals if n is None else (vals + [0.0] * n)[:n]


class _Ik:
    """``INS<code>_<NAME>`` values of one instrument, with errors naming the missing key."""

    def __init__(self, label: IsisLabel, code: int):
        self.label, self.code = label, code

    def __call__(self, name, n=None, default=...):
        key = f"INS{self.code}_{name}"
        v = naif_value(self.label, key)
        if v is None:
            if default is not ...:
                return default
            raise SpiceError(f"{self.label.path}: {key} is not defined (load the instrument kernel and its addendum)")
        return _floats(v, n)

    def focal_plane(self, origin, distortion) -> FocalPlane:
        return FocalPlane(self("FOCAL_LENGTH")[0], tuple(self("TRANSX", 3)), tuple(self("TRANSY", 3)),
                          tuple(self("ITRANSS", 3)), tuple(self("ITRANSL", 3)), float(origin[0]), float(origin[1]),
                          distortion)


def _detector(label: IsisLabel, start_sample: float = 1.0, summing: float = 1.0) -> DetectorMap:
    return DetectorMap.from_alpha_cube(label.alpha_cube(), summing, 1.0, start_sample)


def _line_camera(label, ephemeris, code, focal, det):
    _b, lines, samples = label.shape
    return CameraModel(focal, det, (lines, samples), ephemeris, timing=line_timing(label, code))


def kaguya_mi(label: IsisLabel, ephemeris, code: int) -> CameraModel:
    ik = _Ik(label, code)
    pitch = ik("PIXEL_SIZE")[0]
    n = 3 if abs(pitch - 0.013) < 1e-9 else 4  # ISIS: the 13 um VIS head has 3 coefficients, NIR 4
    dist = KaguyaMiDistortion(tuple(ik("DISTORTION_COEF_X", n)), tuple(ik("DISTORTION_COEF_Y", n)),
                              tuple(ik("BORESIGHT", 2)))
    center = ik("CENTER", 2)
    return _line_camera(label, ephemeris, code, ik.focal_plane((center[0], center[1] - 1.0), dist), _detector(label))


def kaguya_tc(label: IsisLabel, ephemeris, code: int) -> CameraModel:
    ik = _Ik(label, code)
    swath = str(value_of(label.instrument.get("SwathModeId", "FULL"))).strip().upper()
    if swath not in TC_SWATH_START:
        raise IsisError(f"{label.path}: SwathModeId {swath!r} is not FULL, NOMINAL or HALF")
    dist = KaguyaTcDistortion(tuple(ik("DISTORTION_COEF_X", 4)), tuple(ik("DISTORTION_COEF_Y", 4)))
    focal = ik.focal_plane((2048.5, 1.0), dist)
    return _line_camera(label, ephemeris, code, focal, _detector(label, TC_SWATH_START[swath]))


def clementine_uvvis(label: IsisLabel, ephemeris, code: int) -> CameraModel:
    ik = _Ik(label, code)
    dist = ClementineUvvisDistortion(tuple(ik("PP", 2)), tuple(ik("OD_K", 3)), tuple(ik("DECENTER", 2)))
    focal = ik.focal_plane((ik("BORESIGHT_SAMPLE")[0], ik("BORESIGHT_LINE")[0]), dist)
    _b, lines, samples = label.shape
    return CameraModel(focal, _detector(label), (lines, samples), ephemeris, frame_et=frame_et(label))


def chandrayaan2_tmc2(label: IsisLabel, ephemeris, code: int) -> CameraModel:
    ik = _Ik(label, code)
    summing = float(value_of(label.instrument.get("SpatialSumming", 1)) or 1)
    focal = ik.focal_plane(ik("CENTER", 2), RadialOdk(tuple(ik("OD_K", 3, default=[0.0, 0.0, 0.0]))))
    return _line_camera(label, ephemeris, code, focal, _detector(label, 1.0, summing))


BUILDERS = {KAGUYA_MI: kaguya_mi, KAGUYA_TC: kaguya_tc, CLEMENTINE_UVVIS: clementine_uvvis,
            CHANDRAYAAN2_TMC2: chandrayaan2_tmc2}


def build_lunar_camera(label: IsisLabel, ephemeris, code: int | None) -> CameraModel | None:
    """The ISIS-convention camera of a Kaguya MI/TC, Clementine UVVIS or Chandrayaan-2 TMC-2 label, else None."""
    name = instrument_of(label)
    if name is None:
        return None
    if code is None:
        raise IsisError(f"{label.path}: Kernels group has no NaifFrameCode (the {name} IK code)")
    return BUILDERS[name](label, ephemeris, int(code))
