"""Image times as ISIS ``campt`` reports them (s, TDB past J2000).

* Frame camera: ``StartTime + ExposureDuration / 2`` (exposure in ms unless the
  label says seconds; 0 when absent, e.g. Apollo Metric).
* Line scanner: line ``L`` (parent/alpha line, 1-based) is exposed at
  ``et0 + (L - 0.5) * rate`` with ``rate = LineExposureDuration`` or
  ``LineSamplingInterval`` (ms -> s); ``et0`` is ``SpacecraftClockStartCount``
  through the SCLK kernel when one is loaded (a one-field clock written as a decimal
  number, e.g. Kaguya's ``922997380.174174``, as fractional ticks through ``sct2e``, as ale
  reads it), else ``StartTime``; Kaguya MI as ISIS ``KaguyaMiCamera``: ``StartTime`` and
  ``CorrectedSamplingInterval``; Chandrayaan-2 TMC-2 always from ``StartTime``; - except for LRO NAC, which ISIS times from the
  ``SpacecraftClockPrerollCount`` plus ``ADDITIONAL_PREROLL`` lines, with the IK's
  ``MULTIPLI_LINE_ERROR``/``ADDITIVE_LINE_ERROR``/``CONSTANT_TIME_OFFSET``; an ISIS ideal camera
  from its ``EphemerisTime``.
* The centre pixel is ``((samples+1)/2, (lines+1)/2)`` of the cube, mapped through
  ``AlphaCube`` when the cube is a crop.
"""
from __future__ import annotations

import struct

import spiceypy

from ..errors import IsisError, SpiceError
from ..isis.labels import IsisLabel, time_string, value_of
from ..spice.kernels import pool_value, spice_errors
from .instruments import CHANDRAYAAN2_TMC2, KAGUYA_MI, instrument_of
from .model import LineTiming


def naif_value(label: IsisLabel, name: str, default=None):
    """An IK/IAK/SCLK value: the loaded kernel pool first, then the label's ``NaifKeywords``."""
    v = pool_value(name)
    if v is not None:
        return v
    return label.naif_keywords.get(name, default)


def utc_to_et(label: IsisLabel, key: str) -> float:
    """ET (s) of an Instrument-group UTC keyword (needs a leapseconds kernel in the pool)."""
    text = time_string(label.keyword("Instrument", key))
    with spice_errors(f"{label.path}: cannot convert {key} {text!r} to ET (is a leapseconds kernel loaded?)"):
        return float(spiceypy.str2et(text))


def _seconds(q, default_units: str = "ms") -> float:
    units = str(getattr(q, "units", "") or default_units).lower()
    v = float(value_of(q))
    return v if units.startswith("s") else v / 1000.0


LINE_RATE_KEYS = ("LineExposureDuration", "LineSamplingInterval")


def camera_kind(label: IsisLabel) -> str:
    """``frame``, ``line`` (pushbroom), ``pushframe`` (e.g. LRO WAC framelets) or ``radar`` (e.g. Mini-RF SAR)."""
    inst = label.instrument
    if "RangeCoefficientSet" in inst or str(inst.get("InstrumentModeDesc", "")).upper() == "SAR":
        return "radar"
    if "InterframeDelay" in inst or "NumFramelets" in inst:
        return "pushframe"
    return "line" if any(k in inst for k in LINE_RATE_KEYS) else "frame"


def is_line_scanner(label: IsisLabel) -> bool:
    return camera_kind(label) == "line"


def frame_et(label: IsisLabel) -> float:
    """Mid-exposure time (s, TDB) of a frame camera."""
    start = utc_to_et(label, "StartTime")
    inst = label.instrument
    exposure = _seconds(inst["ExposureDuration"]) if "ExposureDuration" in inst else 0.0
    return start + exposure / 2.0


def _sclk_et(label: IsisLabel, count: str, code: int) -> float:
    sc = int(code / 1000)
    hexval = label.naif_keywords.get(f"CLOCK_ET_{sc}_{count}_COMPUTED")
    if hexval is not None:
        return struct.unpack("<d", bytes.fromhex(str(hexval)))[0]
    with spice_errors(f"{label.path}: cannot convert clock count {count} of spacecraft {sc} (is its SCLK kernel loaded?)"):
        if _decimal_ticks(sc, count):  # e.g. Kaguya: one-field clock counted in seconds, "922997380.174174"
            return float(spiceypy.sct2e(sc, float(count)))
        return float(spiceypy.scs2e(sc, count))


def _decimal_ticks(sc: int, count: str) -> bool:
    """A one-field clock (``SCLK01_N_FIELDS`` = 1) given as a decimal number: ticks with a fraction (ale's reading)."""
    from ..spice.kernels import pool_value

    if pool_value(f"SCLK01_N_FIELDS_{abs(sc)}") != 1.0:
        return False
    try:
        float(count)
    except ValueError:
        return False
    return "." in count


def _has_sclk(sc: int) -> bool:
    from ..spice.kernels import pool_value

    return pool_value(f"SCLK01_COEFFICIENTS_{abs(sc)}") is not None


def _count_text(v) -> str:
    v = value_of(v)
    return repr(v) if isinstance(v, float) else str(v)


def line_timing(label: IsisLabel, code: int | None) -> LineTiming:
    """Timing of a line scanner (see module docstring)."""
    inst = label.instrument
    # radar (Mini-RF) gives LineExposureDuration in seconds without units; optical cameras in ms
    rate = _seconds(inst[next(k for k in LINE_RATE_KEYS if k in inst)], "s" if camera_kind(label) == "radar" else "ms")
    ik = (lambda name, d=0.0: float(naif_value(label, f"INS{code}_{name}", d))) if code is not None else None
    preroll = inst.get("SpacecraftClockPrerollCount")
    name = instrument_of(label)
    if name in (KAGUYA_MI, CHANDRAYAAN2_TMC2):  # ISIS KaguyaMiCamera, Chandrayaan2TmcCamera: StartTime
        if name == KAGUYA_MI:
            rate = _seconds(inst.get("CorrectedSamplingInterval", inst[next(k for k in LINE_RATE_KEYS if k in inst)]))
        et0 = utc_to_et(label, "StartTime")
    elif camera_kind(label) == "radar":  # ISIS MiniRF camera: StartTime; its clock counts are "UNK", never parsed
        et0 = utc_to_et(label, "StartTime")
    elif ik is not None and preroll is not None and naif_value(label, f"INS{code}_ADDITIONAL_PREROLL") is not None:
        rate = rate * (1.0 + ik("MULTIPLI_LINE_ERROR")) + ik("ADDITIVE_LINE_ERROR")
        et0 = _sclk_et(label, str(value_of(preroll)), code) + ik("CONSTANT_TIME_OFFSET") + ik("ADDITIONAL_PREROLL") * rate
    elif "EphemerisTime" in inst:  # ISIS ideal camera (noproj, nacmosaic): ET of the first line's start
        et0 = float(value_of(inst["EphemerisTime"]))
    elif code is not None and "SpacecraftClockStartCount" in inst and _has_sclk(int(code / 1000)):
        et0 = _sclk_et(label, _count_text(inst["SpacecraftClockStartCount"]), code)
    else:
        et0 = utc_to_et(label, "StartTime")
    if rate <= 0:
        raise SpiceError(f"{label.path}: LineExposureDuration must be positive")
    return LineTiming(et0=et0, rate=rate)


#: What a radar cube cannot be used for, in the words of :func:`refuse_radar`.
RADAR_REFUSAL = "radar (Mini-RF) is not supported"


def refuse_radar(label: IsisLabel, what: str) -> None:
    """Raise :class:`IsisError` (exit 2) when ``label`` is a radar cube (Mini-RF), which cannot be orthoprojected:
    ``<cube>: radar (Mini-RF) is not supported: <what>``.  Called before its kernels or clock counts are read
    (a Mini-RF label's counts are ``UNK``)."""
    if label.has("Instrument") and not label.is_map_projected and camera_kind(label) == "radar":
        raise IsisError(f"{label.path}: {RADAR_REFUSAL}: {what}")


def center_et(label: IsisLabel, code: int | None) -> float:
    """The ``campt`` time of the cube's centre pixel (s, TDB).

    Push-frame cubes are not modelled: raises :class:`IsisError` (the caller may then use
    the midpoint of the cube's SPICE cache, see :func:`cache_midpoint_et`).
    """
    kind = camera_kind(label)
    if kind == "pushframe":
        raise IsisError(f"{label.path}: push-frame camera (framelets): centre time not modelled")
    if kind == "frame":
        return frame_et(label)
    _bands, lines, samples = label.shape
    _s, alpha_line = label.to_alpha((samples + 1) / 2.0, (lines + 1) / 2.0)
    return float(line_timing(label, code).et(alpha_line))
