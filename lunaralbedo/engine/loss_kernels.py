r"""The reweight pass's robust loss (:mod:`lunaralbedo.model.outliers`) in numba, over a block's runs.

Where three or more kept images meet at a pixel, each of their observations gets the IRLS factor
:math:`m = \rho'(u)/u` of its normalised residual :math:`u = r / s_k`, with
:math:`r = I - H_k - A\,T_k R` (the pixel's weighted least-squares albedo :math:`A` of eq. 3 from
its kept observations, weights :math:`w\,m_{\rm prev}`) and :math:`s_k` image k's robust scale
(1.4826 × the median absolute deviation of its residuals; the pooled one of the block for an image
with fewer than :data:`~lunaralbedo.model.outliers.MIN_SCALE_OBS` of them).  The factor itself is
:func:`lunaralbedo.model.outliers.loss_weight`, the one formula of the NumPy form.

:func:`loss_factors` walks the block's chunk-major runs (:mod:`.runs`) three times, with no array
per observation but its output: (1) each pixel's kept observations (per chunk: a chunk's pixels
are consecutive), hence each image's count :math:`n_k` of observations the loss applies to;
(2) each pixel's albedo (float64 sums in the runs' order, as ``np.bincount`` adds them), the
residuals (written into the output) and an evenly spaced sample of each image's residuals in the
runs' order -- every :math:`\lceil n_k / S \rceil`-th, :math:`S` =
:data:`.window_kernels.SCALE_SAMPLE`, so at most :math:`S` values, and the same of all of them for
the pooled scale; (3) each image's scale from its sample (:func:`.window_kernels.mad_sigma`, as
the spatial test takes its threshold) and the factors.  The sample is the one change against the
full medians: an image with at most :math:`S` residuals in a block gets its exact MAD; above, the
scale's relative standard error is ~1.3 % (Gaussian residuals), which moves a Cauchy factor
:math:`1/(1+u^2/k^2)` by at most ~2.6 %.  Everything per block in a fixed order: the same
bytes for any number of workers.  ``cache=True``, no fastmath.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..model import outliers
from . import robust_kernels, window_kernels


@njit(cache=True, nogil=True)
def _chunk_span(run_start, run_pixel, q0, q1):
    """The first pixel of the runs ``q0:q1`` (one chunk's) and one past their last."""
    lo, hi = run_pixel[q0], run_pixel[q0]
    for q in range(q0, q1):
        lo = min(lo, run_pixel[q])
        hi = max(hi, run_pixel[q] + run_start[q + 1] - run_start[q])
    return lo, hi


@njit(cache=True, nogil=True)
def _kept_counts(run_start, run_pixel, q0, q1, keep, lo, hi, cnt):
    """``cnt[p - lo]``: the kept observations at each pixel ``p`` of the runs ``q0:q1``."""
    for p in range(hi - lo):
        cnt[p] = 0
    for q in range(q0, q1):
        p0 = run_pixel[q] - lo - run_start[q]
        for o in range(run_start[q], run_start[q + 1]):
            cnt[p0 + o] += keep[o]


@njit(cache=True, nogil=True)
def _applies(chunks, run_start, run_pixel, run_image, n_img, keep, least, cnt):
    """Pass 1: per image the kept observations on pixels with at least ``least`` kept ones (``cnt``: scratch)."""
    n_k = np.zeros(n_img, np.int64)
    for ch in range(chunks.shape[0] - 1):
        q0, q1 = chunks[ch], chunks[ch + 1]
        lo, hi = _chunk_span(run_start, run_pixel, q0, q1)
        _kept_counts(run_start, run_pixel, q0, q1, keep, lo, hi, cnt)
        for q in range(q0, q1):
            p0, c = run_pixel[q] - lo - run_start[q], 0
            for o in range(run_start[q], run_start[q + 1]):
                c += keep[o] and cnt[p0 + o] >= least
            n_k[run_image[q]] += c
    return n_k


@njit(cache=True, nogil=True, error_model="numpy")
def _residuals(chunks, run_start, run_pixel, run_image, image, haze, texp, r, w_prev, keep, least, m, sample,
               off, step, cnt, albedo, den):
    """Pass 2: each pixel's albedo (eq. 3, weights :math:`w\\,m_{\\rm prev}` of its kept observations, summed in the
    runs' order), the residuals where the loss applies (into ``m``; 1 elsewhere) and the samples of the finite ones
    (image i's every ``step[i]``-th at ``off[i]``, of all every ``step[-1]``-th at ``off[-2]``); returns the samples'
    sizes."""
    n_img = off.shape[0] - 2
    got = np.zeros(n_img + 1, np.int64)
    skip = np.zeros(n_img + 1, np.int64)  # finite residuals to pass over before the next sampled one
    for ch in range(chunks.shape[0] - 1):
        q0, q1 = chunks[ch], chunks[ch + 1]
        lo, hi = _chunk_span(run_start, run_pixel, q0, q1)
        for p in range(hi - lo):
            albedo[p], den[p], cnt[p] = 0.0, 0.0, 0
        for q in range(q0, q1):
            i = run_image[q]
            h, t = np.float64(haze[i]), np.float64(texp[i])
            p0 = run_pixel[q] - lo - run_start[q]
            for o in range(run_start[q], run_start[q + 1]):
                if keep[o]:  # kept: eq. 1's weight above 0, its effective weight m_prev w
                    w = np.float64(w_prev[o])
                    tr = t * np.float64(r[o])
                    albedo[p0 + o] += (np.float64(image[o]) - h) * tr * w
                    den[p0 + o] += tr * tr * w
                    cnt[p0 + o] += 1
        for p in range(hi - lo):
            albedo[p] /= max(den[p], 1e-300)
        for q in range(q0, q1):
            i = run_image[q]
            h, t = np.float64(haze[i]), np.float64(texp[i])
            p0 = run_pixel[q] - lo - run_start[q]
            for o in range(run_start[q], run_start[q + 1]):
                p = p0 + o
                if not (keep[o] and cnt[p] >= least):
                    m[o] = 1.0
                    continue
                res = (np.float64(image[o]) - h) - albedo[p] * (t * np.float64(r[o]))
                m[o] = res
                if not abs(res) < np.inf:  # the scale of the finite residuals
                    continue
                for j in (i, n_img):  # no division per observation
                    if skip[j] == 0:
                        sample[off[j] + got[j]] = res
                        got[j] += 1
                        skip[j] = step[j]
                    skip[j] -= 1
    return got


@njit(cache=True, nogil=True, error_model="numpy")
def _factors(chunks, run_start, run_pixel, run_image, keep, least, scale, code, k, m, cnt):
    """Pass 3: the residuals in ``m`` where the loss applies become :func:`lunaralbedo.model.outliers.loss_weight`
    of the residual over its image's ``scale`` (1 where the scale is not above 0)."""
    for ch in range(chunks.shape[0] - 1):
        q0, q1 = chunks[ch], chunks[ch + 1]
        lo, hi = _chunk_span(run_start, run_pixel, q0, q1)
        _kept_counts(run_start, run_pixel, q0, q1, keep, lo, hi, cnt)
        for q in range(q0, q1):
            s = scale[run_image[q]]
            inv = 1.0 / s if s > 0 else 0.0
            p0 = run_pixel[q] - lo - run_start[q]
            for o in range(run_start[q], run_start[q + 1]):
                if keep[o] and cnt[p0 + o] >= least:
                    m[o] = outliers.loss_weight(m[o] * inv, code, k) if s > 0 else 1.0


@njit(cache=True, nogil=True, error_model="numpy")
def loss_factors(chunks, run_start, run_pixel, run_image, n_img, image, haze, texp, r, w_prev, keep, code, k,
                 least, min_obs, m, sample):
    r"""The robust loss's factors of one block (module docstring).

    Parameters
    ----------
    chunks, run_start, run_pixel, run_image : the block's chunk-major runs (:mod:`.runs`) of ``n_img`` local images.
    image, r, w_prev : per observation :math:`I` (DN), :math:`R` and the previous effective weight
        :math:`m_{\rm prev} w` (float32; eq. 1's weight :math:`w` in the first pass).
    haze, texp : per local image :math:`H_k` (DN) and :math:`T_k`.
    keep : the observations kept by the spatial test (bool).
    code, k : the loss (:data:`lunaralbedo.model.outliers.LOSS_CODES`) and its threshold.
    least, min_obs : fewest kept images on a pixel for the loss; fewest residuals of an image for its own scale.
    m : out, float64 per observation: the factor where the loss applies, 1 elsewhere (written only when the loss
        applies to at least ``min_obs`` observations).
    sample : float64 scratch of at least ``(n_img + 1) * SCALE_SAMPLE`` values.

    Returns the number of observations the loss applies to.
    """
    span = 0
    for ch in range(chunks.shape[0] - 1):
        lo, hi = _chunk_span(run_start, run_pixel, chunks[ch], chunks[ch + 1])
        span = max(span, hi - lo)
    cnt = np.zeros(span, np.int32)
    n_k = _applies(chunks, run_start, run_pixel, run_image, n_img, keep, least, cnt)
    total = n_k.sum()
    if total < min_obs:
        return total
    big = window_kernels.SCALE_SAMPLE
    step = np.empty(n_img + 1, np.int64)  # every step-th residual of each image, and of all (the pooled scale)
    off = np.zeros(n_img + 2, np.int64)  # their samples at off[i]:off[i + 1]
    for i in range(n_img + 1):
        n = n_k[i] if i < n_img else total
        step[i] = max(1, (n + big - 1) // big)
        off[i + 1] = off[i] + (n + step[i] - 1) // step[i]
    got = _residuals(chunks, run_start, run_pixel, run_image, image, haze, texp, r, w_prev, keep, least, m, sample,
                     off, step, cnt, np.empty(span), np.empty(span))
    pooled = window_kernels.mad_sigma(sample[off[n_img]:], got[n_img])
    scale = np.empty(n_img)
    for i in range(n_img):
        scale[i] = window_kernels.mad_sigma(sample[off[i]:], got[i]) if n_k[i] >= min_obs else pooled
    _factors(chunks, run_start, run_pixel, run_image, keep, least, scale, code, k, m, cnt)
    return total


def block_loss_factors(arrays: dict, haze, texp, r, keep, w_prev, loss: str, threshold: float, out: np.ndarray):
    """:func:`loss_factors` of a block (``arrays``: its runs, values and weights; ``out``: float64, one per observation,
    e.g. scratch no longer needed).  Returns ``(m, n)``: the factors (``out``; empty: 1 everywhere, the loss applies
    to fewer than :data:`~lunaralbedo.model.outliers.MIN_SCALE_OBS` observations) and the observations it applies to."""
    sample = robust_kernels.workspace("loss_sample", (len(arrays["index"]) + 1) * window_kernels.SCALE_SAMPLE)
    n = loss_factors(np.asarray(arrays["chunks"], np.int64), np.asarray(arrays["run_start"], np.int64),
                     np.asarray(arrays["run_pixel"], np.int64), np.asarray(arrays["run_image"], np.int64),
                     len(arrays["index"]), arrays["image"], np.asarray(haze, np.float32), np.asarray(texp, np.float32),
                     np.asarray(r, np.float32), np.asarray(w_prev, np.float32),
                     np.asarray(keep, np.bool_), outliers.LOSS_CODES[loss], float(threshold),
                     outliers.MIN_IMAGES_FOR_LOSS, outliers.MIN_SCALE_OBS, out, sample)
    if n < outliers.MIN_SCALE_OBS:
        return np.ones(0), 0
    return out, int(n)
