r"""Fused numba kernels of one iteration over a tile's compact observations (eqs. 1, 3, 4, 5, 7).

Observations are 1-D float32 arrays ordered by image, then by pixel (``pix``: flat
index into the tile); ``start[k]:start[k+1]`` are image ``k``'s.  Every product is
formed in float32 exactly as the former NumPy stack code did, and summed into
float64 accumulators in one fixed sequential order (images in tile order, pixels in
row-major order), so results do not depend on workers or threads and equal the
NumPy implementation within float32 rounding of the sums.  ``cache=True``, no
fastmath (IEEE semantics, no reassociation).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def albedo(pix, image, tr, w, npix):
    r"""Eq. 3: :math:`A = \sum I\,TR\,w / \sum (TR)^2 w` per pixel (float32, NaN where no weight)."""
    num = np.zeros(npix)
    den = np.zeros(npix)
    for o in range(pix.shape[0]):
        trw = tr[o] * w[o]
        num[pix[o]] += image[o] * trw
        den[pix[o]] += tr[o] * trw
    out = np.empty(npix, np.float32)
    for p in range(npix):
        out[p] = num[p] / den[p] if den[p] > 0 else np.nan
    return out


@njit(cache=True)
def iteration_sums(pix, start, image, r, w, t_obs, alb, dr, jtj, jtr, exp_num, exp_den):
    r"""Cost (eq. 1), exposure sums (eq. 4) and the parameters' normal equations (eq. 5) in one pass.

    ``dr`` is ``(P, n)`` float32 (:math:`\partial R/\partial p_m`; P may be 0); the Jacobian
    columns are :math:`A T\,\partial R/\partial p_m` and :math:`A T R` (last).  ``jtj``,
    ``jtr``, ``exp_num``, ``exp_den`` (float64) are filled in place.  Returns ``(Q, n_obs)``.
    """
    n_par = dr.shape[0]
    cols = np.empty(n_par + 1, np.float32)
    q = 0.0
    n_obs = 0
    zero = np.float32(0.0)
    for k in range(start.shape[0] - 1):
        en = 0.0
        ed = 0.0
        for o in range(start[k], start[k + 1]):
            a = alb[pix[o]]
            if a != a:
                a = zero
            wo = w[o]
            if wo > 0:
                n_obs += 1
            tr = t_obs[o] * r[o]
            res = image[o] - a * tr
            q += res * res * wo
            ar = a * r[o]
            arw = ar * wo
            en += image[o] * arw
            ed += ar * arw
            if jtj.shape[0]:
                at = a * t_obs[o]
                for m in range(n_par):
                    cols[m] = at * dr[m, o]
                cols[n_par] = at * r[o]
                for m in range(n_par + 1):
                    jmw = cols[m] * wo
                    jtr[m] += jmw * res
                    for j in range(m, n_par + 1):
                        jtj[m, j] += jmw * cols[j]
        exp_num[k] = en
        exp_den[k] = ed
    for m in range(jtj.shape[0]):
        for j in range(m):
            jtj[m, j] = jtj[j, m]
    return q, n_obs


@njit(cache=True)
def error_numerator(pix, image, tr, w, alb, npix):
    r"""Numerator of eq. 7 per pixel: :math:`\sum (I/(TR) - A)^2 S w` (float64)."""
    num = np.zeros(npix)
    for o in range(pix.shape[0]):
        if w[o] > 0:
            dev = image[o] / tr[o] - alb[pix[o]]
            num[pix[o]] += dev * dev * w[o]
    return num
