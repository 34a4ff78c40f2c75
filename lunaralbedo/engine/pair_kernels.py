r"""The overlaps' log-ratio sums of a block's kept observations, from its runs (:mod:`.runs`), for the exposures to be
initialised again without the outliers (:func:`lunaralbedo.model.exposure_init.overlap_exposure`).

For every pair of images :math:`(a, b)` sharing pixels where both observations are kept and both signals
:math:`I - H` are positive: the count :math:`n_{ab}` and :math:`\sum (\log a_a - \log a_b)` of the single-image log
albedos :math:`\log a = \log((I - H)/(T R))` (float32, :func:`log_albedo`, the spatial test's own
:func:`.robust_kernels._log_run`; a vectorised pass over the block, in the first reweight pass only).  Two runs of different images in one chunk share the pixels where their
ranges meet (:func:`.haze_kernels.chunk_pairs` walks them alike); the sums run chunk by chunk, pixel by pixel, in
float64: one order fixed by the data, the same for any number of workers.  ``cache=True``, no fastmath.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .robust_kernels import _log_run


@njit(cache=True, nogil=True)
def log_albedo(run_start, run_image, image, haze, texp, r, w, loga, used):
    """Every observation's single-image log albedo (float32, :func:`.robust_kernels._log_run`; NaN where not used)."""
    for q in range(run_start.shape[0] - 1):
        a, b, k = run_start[q], run_start[q + 1], run_image[q]
        _log_run(image[a:b], r[a:b], w[a:b], np.float32(haze[k]), np.float32(texp[k]), loga[a:b], used[a:b], b - a)


@njit(cache=True, nogil=True)
def kept_pair_sums(chunks, run_start, run_pixel, run_image, image, haze, loga, keep, count, total):
    """Add to ``count[a, b]`` and ``total[a, b]`` (``a < b`` local images; float64, square) the shared kept pixels of
    every pair of images and the sum of :math:`\\log a_a - \\log a_b` over them (``image``: the values, ``haze`` per
    local image, ``keep`` per observation)."""
    for c in range(chunks.shape[0] - 1):
        r0, r1 = chunks[c], chunks[c + 1]
        for qa in range(r0, r1):
            ka, pa, oa = run_image[qa], run_pixel[qa], run_start[qa]
            na = run_start[qa + 1] - oa
            ha = haze[ka]
            for qb in range(qa + 1, r1):
                kb, pb, ob = run_image[qb], run_pixel[qb], run_start[qb]
                if kb == ka:
                    continue
                p0, p1 = max(pa, pb), min(pa + na, pb + run_start[qb + 1] - ob)
                if p1 <= p0:
                    continue
                hb = haze[kb]
                lo, hi, sign = (ka, kb, 1.0) if ka < kb else (kb, ka, -1.0)
                n, s = 0.0, 0.0
                for p in range(p0, p1):
                    ia, ib = oa + p - pa, ob + p - pb
                    if keep[ia] and keep[ib] and image[ia] - ha > 0 and image[ib] - hb > 0:
                        n += 1.0
                        s += np.float64(loga[ia]) - np.float64(loga[ib])
                count[lo, hi] += n
                total[lo, hi] += sign * s
