"""Build a :class:`~lunaralbedo.camera.model.CameraModel` from an ISIS label, IK values and an ephemeris.

IK values (``INS<code>_FOCAL_LENGTH``, ``PIXEL_PITCH``, ``TRANSX/Y``, ``ITRANSS/L``,
``BORESIGHT_SAMPLE/LINE``, distortion ``OD_K``/``PP``/``DECENTER``) come from the
loaded kernel pool or, failing that, from the label's ``NaifKeywords`` object.
"""
from __future__ import annotations

from ..errors import SpiceError
from ..isis.labels import IsisLabel, value_of
from .ideal import is_ideal, spec_from_label
from .lunar import build_lunar_camera
from .model import CameraModel, DetectorMap
from .optics import ApolloMetricDistortion, FocalPlane, LroNacDistortion, NoDistortion, RadialOdk
from .timing import camera_kind, frame_et, is_line_scanner, line_timing, naif_value, refuse_radar


def _tuple(v, n=None):
    vals = [float(x) for x in (v if isinstance(v, (list, tuple)) else [v])]
    return tuple(vals if n is None else (vals + [0.0] * n)[:n])


def focal_plane(label: IsisLabel, code: int) -> FocalPlane:
    """IK focal-plane geometry of instrument ``code`` (mm, pixels)."""
    key = f"INS{code}_"

    def get(name, default=...):
        v = naif_value(label, key + name)
        if v is None:
            if default is ...:
                raise SpiceError(f"{label.path}: {key}{name} is not defined (load the instrument kernel, IK/IAK)")
            return default
        return v

    focal = float(_tuple(get("FOCAL_LENGTH"))[0])
    pitch = get("PIXEL_PITCH", None)
    p = float(_tuple(pitch)[0]) if pitch is not None else None
    if get("TRANSX", None) is not None:
        transx, transy = _tuple(get("TRANSX"), 3), _tuple(get("TRANSY"), 3)
        itranss, itransl = _tuple(get("ITRANSS"), 3), _tuple(get("ITRANSL"), 3)
    elif p is not None:
        transx, transy, itranss, itransl = (0, p, 0), (0, 0, p), (0, 1 / p, 0), (0, 0, 1 / p)
    else:
        raise SpiceError(f"{label.path}: neither {key}TRANSX nor {key}PIXEL_PITCH is defined (load the IK)")
    _b, lines, samples = label.shape
    os_, ol = get("BORESIGHT_SAMPLE", None), get("BORESIGHT_LINE", None)
    if os_ is None:
        os_, ol = samples / 2.0, lines / 2.0  # ISIS frame cameras without a boresight: detector centre
    odk, pp, dec = get("OD_K", None), get("PP", None), get("DECENTER", None)
    if odk is not None and pp is not None and dec is not None:
        dist = ApolloMetricDistortion(_tuple(pp, 2), _tuple(odk, 3), _tuple(dec, 3))
    elif odk is not None and len(_tuple(odk)) == 1:
        dist = LroNacDistortion(_tuple(odk)[0])
    elif odk is not None:
        dist = RadialOdk(_tuple(odk, 3))
    else:
        dist = NoDistortion()
    zdir = -1.0 if isinstance(dist, ApolloMetricDistortion) else 1.0
    return FocalPlane(focal, transx, transy, itranss, itransl, float(_tuple(os_)[0]), float(_tuple(ol)[0]), dist, zdir)


def detector_map(label: IsisLabel) -> DetectorMap:
    """AlphaCube crop, summing and first detector pixel from the label."""
    inst = label.instrument
    summing = float(value_of(inst.get("SpatialSumming", inst.get("Summing", inst.get("SampleSumming", 1))) or 1))
    line_summing = float(value_of(inst.get("LineSumming", 1)) or 1) if "LineExposureDuration" not in inst else 1.0
    start = float(value_of(inst.get("SampleFirstPixel", 0)) or 0) + 1.0
    return DetectorMap.from_alpha_cube(label.alpha_cube(), summing, line_summing, start)


def build_camera(label: IsisLabel, ephemeris, code: int, band: int = 1) -> CameraModel:
    """A frame camera, line scanner or (LRO WAC) push-frame camera for band ``band`` of the cube."""
    kind = camera_kind(label)
    if kind == "pushframe":
        from .pushframe import build_pushframe

        return build_pushframe(label, ephemeris, band)
    refuse_radar(label, "no camera model for radar (SAR) geometry (`lunaralbedo positions` gives its positions)")
    lunar = build_lunar_camera(label, ephemeris, code)  # Kaguya MI/TC, Clementine UVVIS, Chandrayaan-2 TMC-2
    if lunar is not None:
        return lunar
    _b, lines, samples = label.shape
    if is_ideal(label.instrument):  # noproj/nacmosaic output: focal plane from the label, LE frame and timing
        focal, det = spec_from_label(label.instrument).focal_plane(), DetectorMap()
    else:
        focal, det = focal_plane(label, code), detector_map(label)
    if is_line_scanner(label):
        return CameraModel(focal, det, (lines, samples), ephemeris, timing=line_timing(label, code))
    return CameraModel(focal, det, (lines, samples), ephemeris, frame_et=frame_et(label))
