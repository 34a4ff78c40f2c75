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

from ..model import updates


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


@njit(cache=True, inline="always")
def _terms(o, pix, image, r, w, t_obs, alb):
    """Float32 terms of observation ``o``: albedo (0 where none), weight, R, residual, and the
    eq. 1 and eq. 4 products ``res^2 w``, ``I A R w``, ``(A R)^2 w``."""
    a = alb[pix[o]]
    if a != a:
        a = np.float32(0.0)
    wo = w[o]
    ro = r[o]
    res = image[o] - a * (t_obs[o] * ro)
    arw = (a * ro) * wo
    return a, wo, ro, res, res * res * wo, image[o] * arw, (a * ro) * arw


def iteration_sums(pix, start, image, r, w, t_obs, alb, dr, jtj, jtr, exp_num, exp_den):
    r"""Cost (eq. 1), exposure sums (eq. 4) and the parameters' normal equations (eq. 5) in one pass.

    ``dr`` is ``(P, n)`` float32 (:math:`\partial R/\partial p_m`; P may be 0); the Jacobian
    columns are :math:`A T\,\partial R/\partial p_m` and :math:`A T R` (last); ``jtj``
    ``(P+1, P+1)`` and ``jtr`` may be empty (no parameter sums wanted).  ``jtj``, ``jtr``,
    ``exp_num``, ``exp_den`` (float64) are filled in place.  Returns ``(Q, n_obs)``.
    Up to two parameters run a kernel with the sums in registers.
    """
    if jtj.shape[0] == 0:
        return _sums2(pix, start, image, r, w, t_obs, alb, dr, 0, jtj, jtr, exp_num, exp_den)
    if dr.shape[0] <= 2:
        return _sums2(pix, start, image, r, w, t_obs, alb, dr, dr.shape[0] + 1, jtj, jtr, exp_num, exp_den)
    # more parameters (no such model yet): Q and exposures fused, normal equations in NumPy
    q, n_obs = _sums2(pix, start, image, r, w, t_obs, alb, dr, 0, jtj, jtr, exp_num, exp_den)
    a = np.nan_to_num(alb)[pix]
    res = image - a * (t_obs * r)
    jtj[:], jtr[:] = updates.phase_sums(res, (a * t_obs)[None], np.ones(1, np.float32), list(dr), r, w)
    return q, n_obs


@njit(cache=True)
def _sums2(pix, start, image, r, w, t_obs, alb, dr, n_cols, jtj, jtr, exp_num, exp_den):
    """:func:`iteration_sums` for at most 3 Jacobian columns, accumulated in local scalars."""
    n_par = n_cols - 1 if n_cols > 0 else 0
    q = 0.0
    n_obs = 0
    zero = np.float32(0.0)
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    b0 = b1 = b2 = 0.0
    for k in range(start.shape[0] - 1):
        en = 0.0
        ed = 0.0
        for o in range(start[k], start[k + 1]):
            a, wo, ro, res, dq, dn, dd = _terms(o, pix, image, r, w, t_obs, alb)
            n_obs += wo > 0
            q += dq
            en += dn
            ed += dd
            if n_cols:
                at = a * t_obs[o]
                # columns in order: dR/dp_0, dR/dp_1 (when present), then R
                c0 = at * dr[0, o] if n_par > 0 else at * ro
                c1 = (at * dr[1, o] if n_par > 1 else at * ro) if n_par > 0 else zero
                c2 = at * ro if n_par > 1 else zero
                j0, j1, j2 = c0 * wo, c1 * wo, c2 * wo
                b0 += j0 * res
                b1 += j1 * res
                b2 += j2 * res
                a00 += j0 * c0
                a01 += j0 * c1
                a02 += j0 * c2
                a11 += j1 * c1
                a12 += j1 * c2
                a22 += j2 * c2
        exp_num[k] = en
        exp_den[k] = ed
    if n_cols:
        acc = np.array([[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]])
        vec = np.array([b0, b1, b2])
        for m in range(n_cols):
            jtr[m] = vec[m]
            for j in range(n_cols):
                jtj[m, j] = acc[m, j]
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
