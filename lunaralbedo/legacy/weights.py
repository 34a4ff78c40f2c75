"""Legacy per-image blending weights (reconstruct --save-weights), pure math.

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
    """Legacy ComputeImageCenterLines from the validity mask ``(rows, cols)`` of a DRG."""
    valid = np.asarray(valid, dtype=bool)
    nrows, ncols = valid.shape

    def lines(mask: np.ndarray, n_other: int) -> tuple[np.ndarray, np.ndarray]:
        idx = np.arange(mask.shape[1])
        any_ = mask.any(axis=1)
        lo = np.where(any_, np.where(mask, idx, n_other).min(axis=1), n_other)
        hi = np.where(any_, np.where(mask, idx, 0).max(axis=1), 0)
        center = (lo + hi) // 2  # both >= 0: C integer division
        return center.astype(np.int64), np.maximum(hi - lo, 0).astype(np.int64)

    hc, hm = lines(valid, ncols)
    vc, vm = lines(valid.T, nrows)
    return CenterLines(hc, hm, vc, vm)


def _c_round(v: np.ndarray) -> np.ndarray:
    return np.where(v >= 0, np.floor(v + 0.5), -np.floor(-v + 0.5))


def _tent(along: np.ndarray, across: np.ndarray, center: np.ndarray, maxdist: np.ndarray) -> np.ndarray:
    pos = _c_round(across)
    n = len(center)
    inside = (pos >= 0) & (pos < n)
    p = np.clip(pos, 0, max(n - 1, 0)).astype(np.int64)
    md = (maxdist[p] / 2.0).astype(np.float32)
    ctr = center[p].astype(np.float32)
    dist = np.abs(along - ctr.astype(np.float64)).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):  # zero extents are masked below
        a = (-1.0 / md.astype(np.float64)).astype(np.float32)
        w = np.maximum(np.float32(0.0), a * dist + np.float32(1.0)).astype(np.float32)
    return np.where(inside & (md != 0), w, np.float32(0.0)).astype(np.float32)


def line_weights(cl: CenterLines, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Legacy ComputeLineWeightsHV at fractional full-image pixels ``(x, y)`` (float32)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    wh = _tent(x, y, cl.h_center, cl.h_maxdist)
    wv = _tent(y, x, cl.v_center, cl.v_maxdist)
    return (wh * wv).astype(np.float32)
