"""LE/RE registration and jitter (``lronacjitreg``/``hijitreg`` of the ASP LRO-NAC notes), pure NumPy/OpenCV math.

Inputs are the two CCD images resampled onto one ideal-camera grid (same shape,
NaN outside each CCD).  Convention (used everywhere in :mod:`lunaralbedo.nac`):
the ground feature at RE pixel ``(x, y)`` lies at LE pixel
``(x + sample_offset, y + line_offset)``.  ASP's ``lronacjitreg`` reports the
opposite sign (its disparity maps LE/left pixels onto RE/right pixels).

Method, per window of ``window`` lines centred on line ``c`` (every ``step``
lines) over the overlap columns:

1. a global integer offset from OpenCV phase correlation (Hann-windowed) of
   256-line blocks (median over blocks), within ``search`` pixels;
2. per window, OpenCV's enhanced-correlation-coefficient maximisation
   (``cv2.findTransformECC``, translation motion; Evangelidis & Psarakis 2008)
   started at the window's phase-correlation estimate.  The template (LE) rows are
   padded by ``search`` lines that are masked out, so the shifted RE window never
   runs off its data (no border bias).  ECC returns the correlation coefficient of
   the final match, which is reported per window.

Windows whose correlation is below ``min_correlation`` or whose offset differs
from the median by more than ``max_deviation`` pixels are rejected.  Standard
errors use the effective number of independent windows ``n * step / window``
(windows overlap when ``step < window``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

#: Correlation coefficient below which a window's match is not used.
MIN_CORRELATION = 0.5


@dataclass
class JitterResult:
    """Per-window offsets (pixels, convention of the module docstring) and their summary."""

    lines: np.ndarray  # window centre lines, 0-based rows of the input
    sample_offset: np.ndarray
    line_offset: np.ndarray
    correlation: np.ndarray
    good: np.ndarray  # bool per window
    columns: tuple[int, int]  # overlap columns used, [start, stop)
    shape: tuple[int, int]
    window: int
    step: int
    extra: dict = field(default_factory=dict)

    @property
    def n_good(self) -> int:
        return int(self.good.sum())

    def _stats(self, v: np.ndarray) -> tuple[float, float, float]:
        g = v[self.good]
        if g.size == 0:
            return float("nan"), float("nan"), float("nan")
        n_eff = max(1.0, g.size * min(1.0, self.step / self.window))
        sd = float(np.std(g, ddof=1)) if g.size > 1 else 0.0
        return float(np.mean(g)), sd, sd / np.sqrt(n_eff)

    def summary(self) -> dict:
        """Mean offsets, their standard deviation and standard error, counts (JSON-ready)."""
        ms, ss, es = self._stats(self.sample_offset)
        ml, sl, el = self._stats(self.line_offset)
        return {
            "sample_offset": ms, "line_offset": ml,
            "sample_offset_stderr": es, "line_offset_stderr": el,
            "sample_offset_std": ss, "line_offset_std": sl,
            "good_matches": self.n_good, "windows": int(self.good.size),
            "overlap_columns": list(self.columns), "window_lines": self.window, "step_lines": self.step,
            "convention": "feature at RE pixel (x, y) lies at LE pixel (x + sample_offset, y + line_offset); "
                          "0-based pixels of the input grid",
            **self.extra,
        }


def overlap_columns(le: np.ndarray, re: np.ndarray, crop_width: int = 200, min_fraction: float = 0.9) -> tuple[int, int]:
    """Columns ``[start, stop)`` valid in both images in ``min_fraction`` of the rows, at most ``crop_width`` wide.

    Like ``lronacjitreg``, a wide overlap is cropped to ``crop_width`` columns around its centre.
    """
    both = np.isfinite(le) & np.isfinite(re)
    cols = np.flatnonzero(both.mean(axis=0) >= min_fraction)
    if cols.size < 8:
        raise InputError(f"LE and RE overlap in {cols.size} columns (need at least 8 valid in both)")
    # the longest run of consecutive overlap columns
    breaks = np.flatnonzero(np.diff(cols) > 1)
    starts = np.concatenate([[0], breaks + 1])
    stops = np.concatenate([breaks + 1, [cols.size]])
    k = int(np.argmax(stops - starts))
    a, b = int(cols[starts[k]]), int(cols[stops[k] - 1]) + 1
    if b - a > crop_width:
        mid = (a + b) // 2
        a, b = mid - crop_width // 2, mid - crop_width // 2 + crop_width
    return a, b


def _filled(a: np.ndarray) -> np.ndarray:
    out = np.asarray(a, dtype=np.float32).copy()
    bad = ~np.isfinite(out)
    if bad.any():
        out[bad] = float(np.mean(out[~bad])) if (~bad).any() else 0.0
    return out


def global_offset(le: np.ndarray, re: np.ndarray, search: int, block: int = 256) -> tuple[int, int]:
    """Integer ``(sample, line)`` offset (module convention) from phase correlation of ``block``-line pieces."""
    import cv2

    n = le.shape[0]
    starts = range(0, max(1, n - block + 1), block) if n >= block else [0]
    shifts = []
    for s in starts:
        a, b = _filled(le[s:s + block]), _filled(re[s:s + block])
        hann = cv2.createHanningWindow((a.shape[1], a.shape[0]), cv2.CV_32F)
        (dx, dy), response = cv2.phaseCorrelate(a, b, hann)
        if response > 0.02:
            shifts.append((-dx, -dy))
    if not shifts:
        return 0, 0
    ds, dl = np.median(np.array(shifts), axis=0)
    if abs(ds) > search or abs(dl) > search:
        raise InputError(f"LE/RE offset ({ds:.1f}, {dl:.1f}) px is beyond the search range {search} px; "
                         "raise --search")
    return int(round(ds)), int(round(dl))


def _ecc(template: np.ndarray, image: np.ndarray, mask: np.ndarray, start: tuple[float, float]):
    """ECC translation of ``image`` onto ``template``: ``image(x + dx, y + dy) ~ template(x, y)``."""
    import cv2

    warp = np.array([[1, 0, start[0]], [0, 1, start[1]]], dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    try:
        cc, warp = cv2.findTransformECC(template, image, warp, cv2.MOTION_TRANSLATION, criteria, mask, 1)
    except cv2.error:
        return np.nan, np.nan, 0.0
    return float(warp[0, 2]), float(warp[1, 2]), float(cc)


def register(le: np.ndarray, re: np.ndarray, window: int = 32, step: int = 8, search: int = 10,
             crop_width: int = 200, min_correlation: float = MIN_CORRELATION, max_deviation: float = 2.0) -> JitterResult:
    """Offsets between ``le`` and ``re`` (2-D arrays on one grid, NaN outside each CCD) per window of lines.

    ``window``: window height in lines; ``step``: lines between window centres;
    ``search``: the largest offset searched (pixels); ``crop_width``: widest overlap used.
    """
    le = np.asarray(le, dtype=np.float64)
    re = np.asarray(re, dtype=np.float64)
    if le.ndim != 2 or le.shape != re.shape:
        raise InputError(f"LE and RE must be 2-D images of one size, got {le.shape} and {re.shape}")
    if window < 4 or step < 1 or search < 1:
        raise InputError(f"window ({window}) must be >= 4, step ({step}) and search ({search}) >= 1")
    lines, samples = le.shape
    if lines < window + 2 * search:
        raise InputError(f"images have {lines} lines; window {window} + 2 x search {search} do not fit")
    c0, c1 = overlap_columns(le, re, crop_width)
    gs, gl = global_offset(le[:, c0:c1], re[:, c0:c1], search)
    # the RE columns/lines that hold the features of the LE crop (integer part of the offset removed)
    m = search
    pad = max(abs(gs), 0)
    a0, a1 = c0 + pad, c1 - pad
    if a1 - a0 < 8:
        raise InputError(f"overlap of {c1 - c0} columns is too narrow for an offset of {gs} samples")
    h = window // 2
    centres = np.arange(h + m + max(0, gl), lines - window + h - m - max(0, -gl) + 1, step)
    n = centres.size
    so, lo, cc = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n)
    mask = np.zeros((window + 2 * m, a1 - a0), dtype=np.uint8)
    mask[m:m + window] = 1
    for k, c in enumerate(centres):
        r0 = c - h - m
        t = le[r0:r0 + window + 2 * m, a0:a1]
        i = re[r0 - gl:r0 - gl + window + 2 * m, a0 - gs:a1 - gs]
        if not (np.isfinite(t[m:m + window]).all() and np.isfinite(i).all()):
            continue
        dx, dy, cc[k] = _ecc(t.astype(np.float32), i.astype(np.float32), mask, (0.0, 0.0))
        so[k], lo[k] = gs - dx, gl - dy
    good = np.isfinite(so) & (cc >= min_correlation)
    if good.any():
        ms, ml = np.median(so[good]), np.median(lo[good])
        good &= (np.abs(so - ms) <= max_deviation) & (np.abs(lo - ml) <= max_deviation)
    return JitterResult(centres, so, lo, cc, good, (c0, c1), (lines, samples), window, step,
                        {"integer_offset": [gs, gl]})
