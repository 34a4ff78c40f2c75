r"""The per-block sums of the joint exposure-haze step (FLOAT_HAZE 1; :mod:`lunaralbedo.model.haze`), in numba.

With haze, :func:`.kernels.iterate_runs` runs on the haze-subtracted values :math:`I - H_k`
(its albedo, Q, exposure and phase sums are then those of :math:`I = T A R + H`), and
:func:`haze_runs` adds, over the same chunk-major runs, the gradient and the reduced normal
matrix of the unknowns :math:`\theta = (T_1, H_1, \dots, T_K, H_K)` of the block's images with
the albedo eliminated (a Schur complement per pixel):

.. math::

   g = \sum_{o} w_o\,r_o \begin{pmatrix} A R_o \\ 1 \end{pmatrix}_{k(o)}, \qquad
   S = \sum_o w_o \begin{pmatrix} (A R_o)^2 & A R_o \\ A R_o & 1 \end{pmatrix}_{k(o)k(o)}
     - \sum_p \frac{b_p b_p^T}{c_p},

with :math:`r_o = I_o - H_k - A T_k R_o`, :math:`c_p = \sum_{o \in p} w_o (T R_o)^2` (eq. 3's
denominator) and :math:`b_p = \sum_{o \in p} w_o T R_o (A R_o, 1)_{k(o)}`: the images seen at a
pixel are coupled through its albedo.  The weights :math:`w` here are noise weights (1, times
the robust factor of :mod:`lunaralbedo.model.outliers`), not eq. 1's blending weights: the
images' noise does not grow towards their edges, and with weights that do not match it the
fit of :math:`(T, H)` is a misweighted errors-in-variables regression whose haze is biased
in proportion to :math:`T` (measured: +0.6 to +2.7 DN on a clean strip with the blending
weights, see docs/solver.md).  Sums in float64 in the order of the runs (fixed by the
data: the same for any number of workers); ``cache=True``, no fastmath.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def haze_runs(chunks, run_start, run_pixel, run_image, value, r, w, texp, g, s, rss):
    r"""Add the block's :math:`g` (``2 n``) and :math:`S` (``2n x 2n``, local images ``run_image``) to ``g`` and ``s``.

    ``value``: haze-subtracted observations (float32); ``r``: reflectance per observation;
    ``w``: the noise weight of each observation (float32: 0 unused, else the robust factor m);
    ``texp``: exposures of the local images.  The albedo eliminated is the one of these
    weights, :math:`A_p = \sum w (I - H) T R / \sum w (T R)^2`.  ``rss`` (3) gets the sum of
    :math:`w r_o^2`, the number of observations and the number of pixels it runs over.
    """
    most = 1
    for c in range(chunks.shape[0] - 1):
        lo, hi = run_pixel[chunks[c]], run_pixel[chunks[c]]
        for q in range(chunks[c], chunks[c + 1]):
            lo = min(lo, run_pixel[q])
            hi = max(hi, run_pixel[q] + run_start[q + 1] - run_start[q])
        most = max(most, hi - lo)
    cp, cn = np.zeros(most), np.zeros(most)
    for c in range(chunks.shape[0] - 1):
        q0, q1 = chunks[c], chunks[c + 1]
        lo, hi = run_pixel[q0], run_pixel[q0]
        for q in range(q0, q1):
            lo = min(lo, run_pixel[q])
            hi = max(hi, run_pixel[q] + run_start[q + 1] - run_start[q])
        for i in range(hi - lo):
            cp[i] = 0.0
            cn[i] = 0.0
        for q in range(q0, q1):  # c_p and the albedo's numerator
            t, p0 = np.float64(texp[run_image[q]]), run_pixel[q] - run_start[q] - lo
            for o in range(run_start[q], run_start[q + 1]):
                wo = np.float64(w[o])
                if wo > 0:
                    tr = t * np.float64(r[o])
                    cp[p0 + o] += wo * tr * tr
                    cn[p0 + o] += wo * tr * np.float64(value[o])
        for i in range(hi - lo):
            if cp[i] > 0:
                rss[2] += 1.0
        for q in range(q0, q1):  # the per-image terms
            k, t, p0 = run_image[q], np.float64(texp[run_image[q]]), run_pixel[q] - run_start[q] - lo
            for o in range(run_start[q], run_start[q + 1]):
                wo = np.float64(w[o])
                if not (wo > 0 and cp[p0 + o] > 0):
                    continue
                a = cn[p0 + o] / cp[p0 + o]
                ro = np.float64(r[o])
                ar = a * ro
                res = np.float64(value[o]) - ar * t
                rss[0] += wo * res * res
                rss[1] += 1.0
                g[2 * k] += wo * ar * res
                g[2 * k + 1] += wo * res
                s[2 * k, 2 * k] += wo * ar * ar
                s[2 * k, 2 * k + 1] += wo * ar
                s[2 * k + 1, 2 * k] += wo * ar
                s[2 * k + 1, 2 * k + 1] += wo
        for qa in range(q0, q1):  # the albedo's elimination: b_p b_p^T / c_p over the pairs of runs meeting at pixels
            ka, ta, pa, na = run_image[qa], np.float64(texp[run_image[qa]]), run_pixel[qa], run_start[qa + 1] - run_start[qa]
            for qb in range(q0, q1):
                kb, tb, pb, nb = run_image[qb], np.float64(texp[run_image[qb]]), run_pixel[qb], run_start[qb + 1] - run_start[qb]
                for p in range(max(pa, pb), min(pa + na, pb + nb)):
                    c_p = cp[p - lo]
                    oa, ob = run_start[qa] + p - pa, run_start[qb] + p - pb
                    wa, wb = np.float64(w[oa]), np.float64(w[ob])
                    if not (c_p > 0 and wa > 0 and wb > 0):
                        continue
                    a = cn[p - lo] / c_p
                    ra, rb = np.float64(r[oa]), np.float64(r[ob])
                    f = (wa * ta * ra) * (wb * tb * rb) / c_p  # b's haze entries; its exposure entries are A R times them
                    s[2 * ka, 2 * kb] -= f * a * ra * a * rb
                    s[2 * ka, 2 * kb + 1] -= f * a * ra
                    s[2 * ka + 1, 2 * kb] -= f * a * rb
                    s[2 * ka + 1, 2 * kb + 1] -= f
