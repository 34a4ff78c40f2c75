r"""The overlaps' log-ratio sums without the observations the first reweight pass rejected, for the exposures to be
initialised again without the outliers (:func:`lunaralbedo.model.exposure_init.overlap_exposure`).

The prepare step has summed, for every pair of images :math:`(j, k)` and over the pixels they share, the count
:math:`n_{jk}` and :math:`\sum (q_j - q_k)` of :math:`q = \log I - \log R` (:func:`.exposure_init.pair_sums`, the
exposures' first start).  The observations kept are those less the few the spatial test rejected, so the kept sums
are the prepare step's less the pairs with a rejected member: :func:`removed_pairs` walks only the rejected
observations (a few per cent), each against the other images' observations at its pixel (two runs of different
images in one chunk share the pixels where their ranges meet, as :func:`.haze_kernels.chunk_pairs` walks them),
instead of a second pass over every observation.  Both are taken at the same state (the first reweight pass comes
before the first iteration: the initial model parameters, no haze) and in the same float32 differences summed in
float64, chunk by chunk, in one order fixed by the data (the same for any number of workers).  ``cache=True``,
no fastmath.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def removed_pairs(chunks, run_start, run_pixel, run_image, image, r, flag, count, total):
    """Add to ``count[a, b]`` and ``total[a, b]`` (``a < b`` local images; float64, square) the pairs the rejected
    observations (``flag``) took part in among the prepare step's (value and R above 0), and the sum of
    :math:`q_a - q_b` over them, :math:`q = \\log I - \\log R` in float32 as :func:`.exposure_init.pair_sums` forms
    it (a pair of two rejected observations once)."""
    for c in range(chunks.shape[0] - 1):
        r0, r1 = chunks[c], chunks[c + 1]
        for qa in range(r0, r1):
            ka, pa, oa = run_image[qa], run_pixel[qa], run_start[qa]
            for ia in range(oa, run_start[qa + 1]):
                if not (flag[ia] and image[ia] > 0 and r[ia] > 0):
                    continue
                p = pa + ia - oa
                la = np.float32(np.log(image[ia])) - np.float32(np.log(r[ia]))
                for qb in range(r0, r1):
                    kb, pb, ob = run_image[qb], run_pixel[qb], run_start[qb]
                    if qb == qa or kb == ka or p < pb or p >= pb + run_start[qb + 1] - ob:
                        continue
                    ib = ob + p - pb
                    if flag[ib] and qb < qa:  # counted from the other one
                        continue
                    if not (image[ib] > 0 and r[ib] > 0):
                        continue
                    d = np.float64(la - (np.float32(np.log(image[ib])) - np.float32(np.log(r[ib]))))
                    lo, hi, sign = (ka, kb, 1.0) if ka < kb else (kb, ka, -1.0)
                    count[lo, hi] += 1.0
                    total[lo, hi] += sign * d
