r"""The overlaps' log-ratio sums of a block's kept observations, from its runs (:mod:`.runs`), for the exposures to be
initialised again without the outliers (:func:`lunaralbedo.model.exposure_init.overlap_exposure`).

For every pair of images :math:`(a, b)` sharing pixels where both observations are kept and both signals
:math:`I - H` are positive: the count :math:`n_{ab}` and :math:`\sum (\log a_a - \log a_b)` of the single-image log
albedos :math:`\log a = \log((I - H)/(T R))` the reweight pass has already computed
(:func:`.robust_kernels.log_albedo`).  Two runs of different images in one chunk share the pixels where their
ranges meet (:func:`.haze_kernels.chunk_pairs` walks them alike); the sums run chunk by chunk, pixel by pixel, in
float64: one order fixed by the data, the same for any number of workers.  ``cache=True``, no fastmath.
"""
from __future__ import annotations

from numba import njit


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
                        s += loga[ia] - loga[ib]
                count[lo, hi] += n
                total[lo, hi] += sign * s
