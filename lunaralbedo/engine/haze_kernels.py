r"""The joint exposure-haze step's sums (FLOAT_HAZE 1; :mod:`lunaralbedo.model.haze`): loops of the fused iterate kernel.

With haze, :func:`.kernels.iterate_runs` takes each image's haze off its values in a work row
(its albedo, Q, exposure and phase sums are then those of :math:`I = T A R + H`) and, in the
same sweep over a chunk's runs, calls these loops for the gradient and the reduced normal
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
weights, see docs/solver.md).

Each image's per-observation terms go to :data:`HAZE_LANES` float64 lanes by position in its
run, the pair terms of two runs meeting at pixels to :data:`PAIR_LANES` lanes by position in
their overlap, and lanes are added in lane order: float64 sums in one order fixed by the data
(the same for any number of workers), elementwise loops that LLVM vectorises.  ``cache=True``,
no fastmath.  (numba's cache checks a function's own file only: after editing this file,
``make clean`` drops the iterate kernel's cached code that inlined it.)
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: Lanes of an image's haze sums: g_T, g_H, S_TT, S_TH, S_HH and the weighted squared residuals.
HAZE_LANES = 16
N_HAZE_SUMS = 6
#: Lanes of the pair terms of two runs (TT, TH, HT, HH).
PAIR_LANES = 16


@njit(cache=True)
def values_less_haze(img, h, V, n):
    """``V = I - H`` of one run (float32, as NumPy's float32 subtraction)."""
    for i in range(n):
        V[i] = img[i] - h


@njit(cache=True, error_model="numpy")
def noise_weights(W, w, base, N, n, robust):
    """The noise weight of each observation: 0 where eq. 1's weight ``W`` (after the shadow test) is 0, else the
    robust factor ``w / base`` (effective over cached weight, float32) with ``robust``, else 1."""
    one, zero = np.float32(1.0), np.float32(0.0)
    if robust:
        for i in range(n):
            m = w[i] / base[i]
            N[i] = m if W[i] > 0 else zero
    else:
        for i in range(n):
            N[i] = one if W[i] > 0 else zero


@njit(cache=True)
def pixel_run(V, R, N, t, CP, CN, n):
    r""":math:`c_p` and the albedo's numerator :math:`\sum w\,TR\,(I - H)` of one run added to its consecutive pixels."""
    for i in range(n):
        wo = np.float64(N[i])
        tr = t * np.float64(R[i])
        wtr = wo * tr
        CP[i] += wtr * tr if wo > 0 else 0.0
        CN[i] += wtr * np.float64(V[i]) if wo > 0 else 0.0


@njit(cache=True, error_model="numpy")
def albedo_span(CP, CN, AH, IC, n):
    """The haze step's albedo ``AH`` and ``IC = 1/c_p`` of a span's pixels (0 where none); returns how many have one."""
    used = 0
    for i in range(n):
        c = CP[i]
        ok = c > 0
        ic = 1.0 / c if ok else 0.0
        IC[i] = ic
        AH[i] = CN[i] * ic
        used += ok
    return used


@njit(cache=True)
def run_lanes(V, R, N, AH, IC, t, lanes, n):
    r"""One run's per-observation terms into its image's lanes, with its own share of :math:`b_p b_p^T / c_p`
    (the term of an observation with itself, :math:`b_o b_o^T / c_p`: pairs of different images are
    :func:`chunk_pairs`'); returns the observations used."""
    used = 0
    L = HAZE_LANES
    for g in range(0, n, L):
        v_, r_, n_, a_, ic_ = V[g:g + L], R[g:g + L], N[g:g + L], AH[g:g + L], IC[g:g + L]
        for lane in range(min(L, n - g)):
            wo = np.float64(n_[lane])
            ok = (wo > 0) & (ic_[lane] > 0)
            ro = np.float64(r_[lane])
            ar = a_[lane] * ro if ok else 0.0
            res = np.float64(v_[lane]) - ar * t if ok else 0.0
            w = wo if ok else 0.0
            wa = w * ar
            h = w * t * ro if ok else 0.0  # b_o's haze entry; its exposure entry is A R h
            hic = h * ic_[lane]
            eic = ar * hic
            lanes[lane] += wa * res
            lanes[L + lane] += w * res
            lanes[2 * L + lane] += wa * ar - eic * (ar * h)
            lanes[3 * L + lane] += wa - eic * h
            lanes[4 * L + lane] += w - hic * h
            lanes[5 * L + lane] += w * res * res
            used += ok
    return used


@njit(cache=True)
def b_entries(R, N, AH, IC, t, HH, HE, n):
    r"""Each observation's entries of :math:`b_p`: haze ``HH`` :math:`= w T R`, exposure ``HE`` :math:`= A R\,w T R` (0 where unused)."""
    for i in range(n):
        wo = np.float64(N[i])
        ok = (wo > 0) & (IC[i] > 0)
        ro = np.float64(R[i])
        h = wo * t * ro if ok else 0.0
        HH[i] = h
        HE[i] = AH[i] * ro * h


@njit(cache=True)
def pair_terms(HHa, HEa, HHb, HEb, IC, acc, n):
    r""":math:`\sum_p b_a b_b / c_p` of two runs over their ``n`` common pixels: (TT, TH, HT, HH) into ``acc[:4]``
    (``acc[4:]``: the lanes)."""
    L = PAIR_LANES
    lanes = acc[4:]
    for m in range(4 * L):
        lanes[m] = 0.0
    for g in range(0, n, L):
        ha_, ea_, hb_, eb_, ic_ = HHa[g:g + L], HEa[g:g + L], HHb[g:g + L], HEb[g:g + L], IC[g:g + L]
        for lane in range(min(L, n - g)):
            x = ha_[lane] * ic_[lane]
            y = ea_[lane] * ic_[lane]
            lanes[lane] += y * eb_[lane]
            lanes[L + lane] += y * hb_[lane]
            lanes[2 * L + lane] += x * eb_[lane]
            lanes[3 * L + lane] += x * hb_[lane]
    for m in range(4):
        s = 0.0
        for lane in range(L):
            s += lanes[m * L + lane]
        acc[m] = s


@njit(cache=True)
def chunk_pairs(run_start, run_pixel, run_image, r0, r1, s0, lo, HH, HE, IC, hs, acc):
    r"""Subtract :math:`b_p b_p^T / c_p` of a chunk's pixels from ``hs``: every pair of its runs of different images
    (each pair once, its transpose the same numbers: ``hs`` stays exactly symmetric) over the pixels they share
    (``acc``: 4 + 4 :data:`PAIR_LANES` float64); an observation's term with itself is :func:`run_lanes`'."""
    for qa in range(r0, r1):
        ka, pa, na, oa = run_image[qa], run_pixel[qa], run_start[qa + 1] - run_start[qa], run_start[qa] - s0
        for qb in range(qa + 1, r1):
            kb, pb, nb, ob = run_image[qb], run_pixel[qb], run_start[qb + 1] - run_start[qb], run_start[qb] - s0
            p0, p1 = max(pa, pb), min(pa + na, pb + nb)
            if p1 <= p0:
                continue
            ia, ib = oa + p0 - pa, ob + p0 - pb
            pair_terms(HH[ia:], HE[ia:], HH[ib:], HE[ib:], IC[p0 - lo:], acc, p1 - p0)
            hs[2 * ka, 2 * kb] -= acc[0]
            hs[2 * ka, 2 * kb + 1] -= acc[1]
            hs[2 * ka + 1, 2 * kb] -= acc[2]
            hs[2 * ka + 1, 2 * kb + 1] -= acc[3]
            hs[2 * kb, 2 * ka] -= acc[0]
            hs[2 * kb + 1, 2 * ka] -= acc[1]
            hs[2 * kb, 2 * ka + 1] -= acc[2]
            hs[2 * kb + 1, 2 * ka + 1] -= acc[3]


@njit(cache=True)
def add_lanes(lanes, hg, hs, hrss):
    """The images' lanes (``(images, N_HAZE_SUMS * HAZE_LANES)``) added, in lane order, to ``hg``, ``hs``'s diagonal blocks and ``hrss[0]``."""
    L = HAZE_LANES
    for k in range(lanes.shape[0]):
        s = np.zeros(N_HAZE_SUMS)
        for m in range(N_HAZE_SUMS):
            for lane in range(L):
                s[m] += lanes[k, m * L + lane]
        hg[2 * k] += s[0]
        hg[2 * k + 1] += s[1]
        hs[2 * k, 2 * k] += s[2]
        hs[2 * k, 2 * k + 1] += s[3]
        hs[2 * k + 1, 2 * k] += s[3]
        hs[2 * k + 1, 2 * k + 1] += s[4]
        hrss[0] += s[5]


@njit(cache=True, error_model="numpy")
def haze_chunk(run_start, run_pixel, run_image, r0, r1, s0, lo, nsp, spans, V, R, W, w, base, robust, texp, N,
               CP, CN, AH, IC, HH, HE, hlanes, hs, pacc, hrss, n):
    """One chunk's terms, from the iterate kernel's rows (``V`` values less haze, ``R``, ``W`` eq. 1's weights after
    the shadow test, ``w`` and ``base`` for the robust factor) and its disjoint pixel ``spans`` (:func:`.kernels._spans`)."""
    noise_weights(W, w, base, N, n, robust)
    for q in range(nsp):
        for i in range(spans[q, 0], spans[q, 1]):
            CP[i] = 0.0
            CN[i] = 0.0
    for r in range(r0, r1):
        a, b, p = run_start[r] - s0, run_start[r + 1] - s0, run_pixel[r] - lo
        pixel_run(V[a:b], R[a:b], N[a:b], np.float64(texp[run_image[r]]), CP[p:p + b - a], CN[p:p + b - a], b - a)
    for q in range(nsp):
        a, b = spans[q, 0], spans[q, 1]
        hrss[2] += albedo_span(CP[a:b], CN[a:b], AH[a:b], IC[a:b], b - a)
    for r in range(r0, r1):
        a, b, p, k = run_start[r] - s0, run_start[r + 1] - s0, run_pixel[r] - lo, run_image[r]
        hrss[1] += run_lanes(V[a:b], R[a:b], N[a:b], AH[p:p + b - a], IC[p:p + b - a], np.float64(texp[k]), hlanes[k], b - a)
    if r1 - r0 > 1:  # the images of a pixel coupled through its albedo
        for r in range(r0, r1):
            a, b, p = run_start[r] - s0, run_start[r + 1] - s0, run_pixel[r] - lo
            b_entries(R[a:b], N[a:b], AH[p:p + b - a], IC[p:p + b - a], np.float64(texp[run_image[r]]), HH[a:b], HE[a:b], b - a)
        chunk_pairs(run_start, run_pixel, run_image, r0, r1, s0, lo, HH, HE, IC, hs, pacc)
