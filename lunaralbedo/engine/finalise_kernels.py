r"""Finalise's fused numba kernel: eq. 3's albedo and eq. 7's error of a block's compact observations.

:func:`finalise_runs` goes through a block's chunk-major runs (:mod:`.runs`) as the iterate
kernel does (:mod:`.kernels`, whose run helpers it calls: the same albedo bits), then adds
eq. 7's terms.  Products in float32 as the NumPy formulas of :mod:`lunaralbedo.model.updates`
form them, sums in float64 in one fixed order; ``cache=True``, no fastmath.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import _albedo_span, _chunk_extent, _eq3_run, _spans, _zero_sums


@njit(cache=True, error_model="numpy")  # IEEE division as the NumPy formula; the zero check kept the loop scalar
def _error_run(img, r, w, t, a, E, n):
    r"""Eq. 7's terms :math:`(I/(TR) - A)^2 w` (where :math:`w > 0`) of one run added to its consecutive pixels' float64
    sums (vectorised: 1.2 -> 0.6 ns per observation with the division's zero check gone)."""
    for i in range(n):
        if w[i] > 0:
            dev = img[i] / (t * r[i]) - a[i]
            E[i] += dev * dev * w[i]


@njit(cache=True, inline="always", error_model="numpy")
def _error_default(blend, err, n):
    """Eq. 7's error where a pixel has a blending weight (``0.0 / blend``: 0 until an observation adds to it), one row."""
    for j in range(n):
        if blend[j] > 0:
            err[j] = np.float32(0.0 / blend[j])


@njit(cache=True, inline="always", error_model="numpy")
def _error_quotient(num, blend, err, n):
    """Eq. 7's quotient over a row's consecutive pixels: the float64 numerator over the float32 blending sum."""
    for j in range(n):
        if blend[j] > 0:
            err[j] = num[j] / blend[j]


@njit(cache=True, nogil=True, error_model="numpy")  # IEEE division, as the NumPy formulas (tests/oracles.py; model/updates.error_terms)
def finalise_runs(chunks, run_start, run_pixel, run_image, image, texp, r, w, blend, c0, alb, err):
    r"""Eq. 3's albedo and eq. 7's error of a block's observations in chunk-major runs, into ``alb`` and ``err``.

    ``texp`` (float32) are the exposures of the local images ``run_image``, ``r`` the model's R
    and ``w`` the weights of the observations (float32); ``blend`` (float32, rows x columns
    ``c0:`` of the block: those its images' windows span; 0 in the others) eq. 7's denominator,
    the sum of blending weights.  ``alb`` (float32 per pixel of the block) gets
    :math:`A = \sum I\,TR\,w / \sum (TR)^2 w` (NaN where no weight), each pixel's float64
    sums over its images in tile order, as :func:`iterate_runs` sums them (the same bits);
    ``err`` (float32 per pixel, or size 0: not wanted) gets
    :math:`\sum_{w>0} (I/(TR) - A)^2 w / \sum S` (float64 numerator and quotient, its terms in
    the same order; 0 where the pixel has a blending weight and no observation, NaN where it has
    none), the bits of the NumPy formulas (``np.where(den > 0, num / den, nan)`` cast to float32).
    """
    nan = np.float32(np.nan)
    want_err = err.shape[0] > 0
    for p in range(alb.shape[0]):
        alb[p] = nan
    n_rows, n_cols = blend.shape
    width = alb.shape[0] // n_rows
    if want_err:
        for p in range(err.shape[0]):
            err[p] = nan
        for i in range(n_rows):
            _error_default(blend[i], err[i * width + c0:i * width + c0 + n_cols], n_cols)
    most_obs, most_px, most_runs = _chunk_extent(chunks, run_start, run_pixel)
    SN, SD = np.empty(most_px), np.empty(most_px)
    order, spans = np.empty(most_runs, np.int32), np.empty((most_runs, 2), np.int32)
    for c in range(chunks.shape[0] - 1):  # eq. 3 as iterate_runs does it: a shared njit helper cost it 3 % (0.15 ns)
        r0, r1 = chunks[c], chunks[c + 1]
        lo = run_pixel[r0]
        for rr in range(r0, r1):
            lo = min(lo, run_pixel[rr])
        nsp = _spans(run_start, run_pixel, r0, r1, lo, order, spans)
        for q in range(nsp):
            _zero_sums(SN[spans[q, 0]:spans[q, 1]], SD[spans[q, 0]:spans[q, 1]], spans[q, 1] - spans[q, 0])
        for rr in range(r0, r1):
            a, b, p = run_start[rr], run_start[rr + 1], run_pixel[rr] - lo
            _eq3_run(image[a:b], r[a:b], w[a:b], texp[run_image[rr]], SN[p:p + b - a], SD[p:p + b - a], b - a)
        for q in range(nsp):
            a, b = spans[q, 0], spans[q, 1]
            _albedo_span(SN[a:b], SD[a:b], alb[lo + a:lo + b], b - a)
        if not want_err:
            continue
        for q in range(nsp):  # SN holds eq. 7's numerators now
            _zero_sums(SN[spans[q, 0]:spans[q, 1]], SD[spans[q, 0]:spans[q, 1]], spans[q, 1] - spans[q, 0])
        for rr in range(r0, r1):
            a, b, p = run_start[rr], run_start[rr + 1], run_pixel[rr] - lo
            _error_run(image[a:b], r[a:b], w[a:b], texp[run_image[rr]], alb[lo + p:lo + p + b - a], SN[p:p + b - a], b - a)
        for q in range(nsp):  # the span's pixels row by row: pixel p is column p - i * width - c0 of blend's row i
            p, end = lo + spans[q, 0], lo + spans[q, 1]
            while p < end:
                i = p // width
                a, b = max(p, i * width + c0), min(end, i * width + c0 + n_cols)  # observed pixels lie in blend's columns
                if b > a:
                    _error_quotient(SN[a - lo:b - lo], blend[i, a - i * width - c0:b - i * width - c0], err[a:b], b - a)
                p = (i + 1) * width


@njit(cache=True, error_model="numpy")
def lost_fraction_runs(run_start, run_pixel, base, effective, lost, count, out):
    r"""The ``outliers/`` layer of a block from its runs: per pixel :math:`\sum (1 - m) / \#\{w > 0\}`, ``m`` the
    effective weight over the cached one ``base`` (float32 ``out``; NaN where no observation has weight), the float64
    sums ``lost`` and ``count`` (scratch, one per pixel) added in the runs' order, the order in which
    :func:`lunaralbedo.model.outliers.lost_fraction` (its NumPy form) adds them: the same bits, without a pixel
    number per observation."""
    for j in range(out.shape[0]):
        lost[j] = 0.0
        count[j] = 0.0
    for q in range(run_start.shape[0] - 1):
        a, b, p = run_start[q], run_start[q + 1], run_pixel[q] - run_start[q]
        for i in range(a, b):
            w = np.float64(base[i])
            if w > 0:
                lost[p + i] += 1.0 - np.float64(effective[i]) / w
                count[p + i] += 1.0
    for j in range(out.shape[0]):
        out[j] = lost[j] / count[j]
