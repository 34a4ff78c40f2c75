"""Legacy per-image blending weights (reconstruct --save-weights): the tent of
:mod:`lunaralbedo.model.weights` with the legacy centre lines and float32 numerics.

For every row of a DRG the legacy program kept the centre (integer midpoint)
and extent of its valid pixels, and likewise for every column.  The weight at
fractional pixel ``(x, y)`` is the product of two tents in float32:

    w_h = max(0, 1 - |x - hCenter[round(y)]| / (hMaxDist[round(y)] / 2))
    w_v = max(0, 1 - |y - vCenter[round(x)]| / (vMaxDist[round(x)] / 2))

(zero outside the image or where an extent is zero).  The four integer arrays
are what ``weight/<key>_weight.txt`` holds, one line each.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.weights import profile_from_mask, tent_about


@dataclass(frozen=True)
class CenterLines:
    """Per-row and per-column centres and extents of the valid pixels of one DRG."""

    h_center: np.ndarray
    h_maxdist: np.ndarray
    v_center: np.ndarray
    v_maxdist: np.ndarray

    def to_lines(self) -> list[str]:
        """The four lines of a legacy weight file (``%d `` per value)."""
        return ["".join(f"{int(v)} " for v in arr) for arr in (self.h_center, self.h_maxdist, self.v_center, self.v_maxdist)]

    @classmethod
    def from_lines(cls, lines: list[str]) -> "CenterLines":
        arrs = [np.array([int(t) for t in line.split()], dtype=np.int64) for line in lines[:4]]
        return cls(*arrs)


def center_lines(valid: np.ndarray) -> CenterLines:
    """Legacy ComputeImageCenterLines from the validity mask ``(rows, cols)`` of a DRG.

    The first/last valid pixels are :func:`lunaralbedo.model.weights.profile_from_mask`;
    the legacy kept their integer midpoint (C division) and distance.
    """
    p = profile_from_mask(valid)

    def lines(first: np.ndarray, last: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        first, last = first.astype(np.int64), last.astype(np.int64)
        hi = np.maximum(last, 0)  # an empty row/column: first = its length, last = 0
        return (first + hi) // 2, np.maximum(last - first, 0)

    hc, hm = lines(p.row_first, p.row_last)
    vc, vm = lines(p.col_first, p.col_last)
    return CenterLines(hc, hm, vc, vm)


def _c_round(v: np.ndarray) -> np.ndarray:
    return np.where(v >= 0, np.floor(v + 0.5), -np.floor(-v + 0.5))


def _tent(along: np.ndarray, across: np.ndarray, center: np.ndarray, maxdist: np.ndarray) -> np.ndarray:
    """The float32 tent (:func:`lunaralbedo.model.weights.tent_about`) of the line nearest to ``across``."""
    pos = _c_round(across)
    n = len(center)
    inside = (pos >= 0) & (pos < n)
    p = np.clip(pos, 0, max(n - 1, 0)).astype(np.int64)
    w = tent_about(along, center[p], maxdist[p] / 2.0, dtype=np.float32)
    return np.where(inside, w, np.float32(0.0)).astype(np.float32)


def line_weights(cl: CenterLines, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Legacy ComputeLineWeightsHV at fractional full-image pixels ``(x, y)`` (float32)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    wh = _tent(x, y, cl.h_center, cl.h_maxdist)
    wv = _tent(y, x, cl.v_center, cl.v_maxdist)
    return (wh * wv).astype(np.float32)
