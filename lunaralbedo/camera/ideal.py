"""ISIS ideal camera (``IdealCamera``, the output of ``noproj``): label keywords <-> focal plane (pure math).

Keywords of the Instrument group (ISIS ``IdealCamera``): ``InstrumentId = IdealCamera``,
``FocalLength`` and ``PixelPitch`` (mm), ``SampleDetectors``, ``TransX0``/``TransY0``
(mm, focal-plane position of the detector centre), ``FocalPlaneXDependency`` (1: x
follows samples, 2: x follows lines) with ``TransX``/``TransY`` direction signs.
lunaralbedo also writes ``SampleAxis``/``LineAxis`` (mm per detector sample/line in
x and y), which it prefers when present.  The detector origin is sample
``SampleDetectors / 2 + 0.5``, line 0 (line scanner); there is no distortion.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..isis.labels import value_of
from .optics import FocalPlane


@dataclass
class IdealSpec:
    """Ideal-camera numbers (mm, pixels); ``sample_axis`` = focal-plane mm per detector sample (x, y)."""

    focal_length: float
    pitch: float
    samples: int
    x0: float
    y0: float
    sample_axis: tuple[float, float]
    line_axis: tuple[float, float]

    def focal_plane(self) -> FocalPlane:
        m = np.array([[self.sample_axis[0], self.line_axis[0]], [self.sample_axis[1], self.line_axis[1]]])
        inv = np.linalg.inv(m)
        off = -inv @ np.array([self.x0, self.y0])
        return FocalPlane(self.focal_length, (self.x0, self.sample_axis[0], self.line_axis[0]),
                          (self.y0, self.sample_axis[1], self.line_axis[1]), (off[0], inv[0, 0], inv[0, 1]),
                          (off[1], inv[1, 0], inv[1, 1]), self.samples / 2.0 + 0.5, 0.0)



def is_ideal(instrument) -> bool:
    """True for an ISIS ideal-camera label (``InstrumentId = IdealCamera``)."""
    return str(instrument.get("InstrumentId", "")).strip().lower() == "idealcamera"


def spec_from_label(instrument) -> IdealSpec:
    """The :class:`IdealSpec` of an ideal-camera Instrument group (see module docstring)."""
    f = float(value_of(instrument["FocalLength"]))
    p = float(value_of(instrument["PixelPitch"]))
    if "SampleAxis" in instrument:
        sa = tuple(float(v) for v in instrument["SampleAxis"])
        la = tuple(float(v) for v in instrument["LineAxis"])
    else:
        xdir = float(value_of(instrument.get("TransX", 1.0)))
        ydir = float(value_of(instrument.get("TransY", 1.0)))
        if int(value_of(instrument.get("FocalPlaneXDependency", 1))) == 2:
            sa, la = (0.0, p * ydir), (p * xdir, 0.0)
        else:
            sa, la = (p * xdir, 0.0), (0.0, p * ydir)
    return IdealSpec(f, p, int(value_of(instrument["SampleDetectors"])), float(value_of(instrument.get("TransX0", 0.0))),
                     float(value_of(instrument.get("TransY0", 0.0))), sa, la)
