"""The 8-bit stretch shared by every PNG of the KML pyramid (pure functions).

One stretch is computed for the whole result (never per tile), so neighbouring
tiles and levels have no brightness jumps::

    dn = round(255 * clip((albedo - lo) / (hi - lo), 0, 1))

with ``lo, hi`` either given (``--range``) or the ``p_lo``/``p_hi`` percentiles of
all valid albedo pixels (``--stretch``, default 2 and 98).  No-data pixels get
alpha 0; every other pixel alpha 255.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InputError

FORMULA = "dn = round(255 * clip((albedo - lo) / (hi - lo), 0, 1)); alpha = 0 where no data, else 255"


@dataclass(frozen=True)
class Stretch:
    lo: float
    hi: float
    method: str  # "percentile" or "range"
    percentiles: tuple[float, float] | None = None

    def to_json(self) -> str:
        d = asdict(self)
        d["percentiles"] = list(self.percentiles) if self.percentiles else None
        d["formula"] = FORMULA
        return json.dumps(d, indent=2) + "\n"


def parse_pair(text: str, what: str) -> tuple[float, float]:
    """``"2,98"`` or ``"p2,p98"`` -> (2.0, 98.0); :class:`InputError` otherwise."""
    parts = [p.strip().lstrip("pP") for p in str(text).split(",")]
    try:
        a, b = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"{what} must be two numbers 'a,b', got {text!r}") from None
    return a, b


def stretch_from_values(values: np.ndarray, percentiles: tuple[float, float] = (2.0, 98.0)) -> Stretch:
    """Percentile stretch of the finite ``values`` (a constant image gets a 1-unit-wide range)."""
    p0, p1 = percentiles
    if not 0.0 <= p0 < p1 <= 100.0:
        raise InputError(f"stretch percentiles must satisfy 0 <= low < high <= 100, got {p0},{p1}")
    vals = np.asarray(values, dtype=np.float64)
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        raise InputError("the albedo tiles hold no valid pixel: nothing to stretch")
    lo, hi = (float(v) for v in np.percentile(vals, [p0, p1]))
    if hi <= lo:
        hi = lo + 1.0
    return Stretch(lo, hi, "percentile", (p0, p1))


def stretch_from_range(lo: float, hi: float) -> Stretch:
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise InputError(f"--range needs finite lo < hi, got {lo},{hi}")
    return Stretch(float(lo), float(hi), "range")


def to_dn(values: np.ndarray, stretch: Stretch) -> np.ndarray:
    """Stretched 8-bit values (0 where no data)."""
    scaled = (np.asarray(values, dtype=np.float64) - stretch.lo) / (stretch.hi - stretch.lo)
    dn = np.rint(255.0 * np.clip(scaled, 0.0, 1.0))
    return np.where(np.isfinite(dn), dn, 0).astype(np.uint8)


def to_rgba(values: np.ndarray, stretch: Stretch) -> np.ndarray:
    """(4, h, w) uint8: gray in R, G and B, alpha 255 on data and 0 elsewhere."""
    dn = to_dn(values, stretch)
    alpha = np.where(np.isfinite(values), 255, 0).astype(np.uint8)
    return np.stack([dn, dn, dn, alpha])
