r"""Fused numba kernels of one iteration over a block's compact observations (eqs. 1, 3, 4, 5, 7).

The prepare step caches each block's observations in chunk-major runs (:mod:`.runs`): chunks
of consecutive pixels; within a chunk, each image's observations (images in tile order) in
runs of consecutive pixels.  :func:`iterate_runs` computes, chunk by chunk, each pixel's
albedo and all the sums of an iteration, with the photometric model's ``point`` (R and
dR/dp) inline; finalise's :func:`.finalise_kernels.finalise_runs` computes the albedo and eq. 7's
error the same way, with this module's run helpers (``_chunk_extent``, ``_spans``,
``_zero_sums``, ``_eq3_run``, ``_albedo_span``: the engine's own, shared by the two kernels so
their albedo bits agree).  Every product is formed in float32 as the NumPy formulas of
:mod:`lunaralbedo.model.updates` form it and summed into float64 accumulators in one fixed
order (each pixel's sums over its images in tile order; fixed lanes for the global sums), so
results do not depend on workers or threads.  ``cache=True``, no fastmath (IEEE semantics, no
reassociation).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..model.photometry import lunar_lambert
from . import haze_kernels as hk


#: Dynamic shadow test of :func:`iterate_runs` (eq. 1's mask of shadow types 2 and 3,
#: :func:`lunaralbedo.model.shadows.dynamic_lit`): none, on the model's R, on a given layer.
NO_SHADOW_TEST, SHADOW_ON_R, SHADOW_ON_LAYER = 0, 1, 2


def point_kind(model) -> int | None:
    """The kernel branch of a model's ``point`` (its ``point_kind``; None: the kernel takes arrays).

    Each model carries its own fast path: ``point`` and the number of the branch of :func:`_point` that
    calls it.  The models' ``point`` functions are reached as globals of :func:`_point`: a numba function
    passed as an argument would make its caller compile again in every process (the argument's type
    names the object).  A model that gets a ``point`` sets ``point_kind`` and adds a branch there."""
    return model.point_kind if (model.point is not None and model.point_kind) else None


@njit(cache=True)
def _point(kind, l0, l1, l2, params):
    """R and dR/dp of one observation: the ``point`` of the model whose ``point_kind`` is ``kind``, or the layers."""
    if kind == 1:
        return lunar_lambert.point(l0, l1, l2, params)
    return l0, l1, l2


#: Lanes of the global sums (Q, then the normal equations' b0, b1, b2, a00, a01, a02, a11, a12,
#: a22): observation ``i`` of a chunk goes to lane ``i % LANES``; lanes are combined in lane order at the end.
LANES = 64
N_SUMS = 10
#: Lanes of each image's exposure sums (eq. 4): observation ``i`` of a run goes to lane ``i % EXP_LANES``.
EXP_LANES = 32
#: Float32 work rows of a chunk in :func:`iterate_runs`.
_R, _D0, _D1, _T, _W, _A, _PN, _PD, _V, _N, _ROWS = range(11)
# int32 keys of float32 bits for the phase-angle range (positive floats keep their bits, negative
# ones get their magnitude bits flipped: the keys order as the floats do; NaN keys exceed +inf's)
_MAG, _MAX32, _MIN32 = np.int32(0x7FFFFFFF), np.int32(0x7FFFFFFF), np.int32(-0x80000000)
_INF_KEY, _NINF_KEY = np.int32(0x7F800000), np.int32(-0x7F800001)


# The loops of one chunk, each its own function: LLVM vectorises a small loop over a few arrays
# where, inlined into one big function, it kept several of them scalar (the normal equations'
# lanes: 2.5 ns per observation in the big function, 1.7 ns as their own).  They stay in this
# file: numba's cache checks a function's own file only, so loops inlined from another module
# could run stale after an edit (docs/architecture.md).
@njit(cache=True)
def _model_rows(kind, g0, g1, g2, params, R, D0, D1, n):
    """R and dR/dp of each observation (:func:`_point`)."""
    if kind == 1:
        for i in range(n):
            R[i], D0[i], D1[i] = _point(1, g0[i], g1[i], g2[i], params)
    else:
        for i in range(n):
            R[i], D0[i], D1[i] = g0[i], g1[i], g2[i]


@njit(cache=True, error_model="numpy")
def _lit_weights(img, wgt, rat, T, thresh, W, n):
    r"""The weights after eq. 1's dynamic shadow test :math:`I/(r T) \ge t` (NaN ratios are shadow, as in ``dynamic_lit``)."""
    zero = np.float32(0.0)
    for i in range(n):
        lit = img[i] / (rat[i] * T[i]) >= thresh
        W[i] = wgt[i] if lit else zero


@njit(cache=True)
def _alpha_keys(ab, W, n, kmin, kmax):
    """The range of the used phase angles' keys: an integer min / max of their float32 bits (order-free, vectorised)."""
    for i in range(n):
        b = ab[i]
        key = np.int32(b ^ ((b >> 31) & _MAG))  # float32 bits -> int32 in the floats' order
        used = (W[i] > 0) & (key <= _INF_KEY) & (key >= _NINF_KEY)  # not NaN
        kmin = min(kmin, key if used else _MAX32)
        kmax = max(kmax, key if used else _MIN32)
    return kmin, kmax


@njit(cache=True)
def _cost_lanes(A, T, R, W, img, acc, n):
    """Eq. 1's terms into the lanes of Q (no parameter fitted)."""
    for g in range(0, n, LANES):
        a_, t_, r_, w_, im_ = A[g:g + LANES], T[g:g + LANES], R[g:g + LANES], W[g:g + LANES], img[g:g + LANES]
        for lane in range(min(LANES, n - g)):
            res = im_[lane] - a_[lane] * (t_[lane] * r_[lane])
            acc[lane] += res * res * w_[lane]


@njit(cache=True)
def _normal_lanes(A, T, R, W, D0, D1, img, acc, n, n_par):
    """Eq. 1's and eq. 5's terms (columns dR/dp_0, dR/dp_1 when present, then R) into the lanes,
    :data:`LANES` observations at a time, elementwise over the lanes (vectorised, no reassociation)."""
    zero = np.float32(0.0)
    for g in range(0, n, LANES):
        a_, t_, r_, w_, d0_, d1_ = A[g:g + LANES], T[g:g + LANES], R[g:g + LANES], W[g:g + LANES], D0[g:g + LANES], D1[g:g + LANES]
        im_ = img[g:g + LANES]
        for lane in range(min(LANES, n - g)):
            a = a_[lane]
            t = t_[lane]
            ro = r_[lane]
            wo = w_[lane]
            res = im_[lane] - a * (t * ro)
            at = a * t
            c0 = at * d0_[lane] if n_par > 0 else at * ro
            c1 = (at * d1_[lane] if n_par > 1 else at * ro) if n_par > 0 else zero
            c2 = at * ro if n_par > 1 else zero
            j0_, j1_, j2_ = c0 * wo, c1 * wo, c2 * wo
            acc[lane] += res * res * wo
            acc[LANES + lane] += j0_ * res
            acc[2 * LANES + lane] += j1_ * res
            acc[3 * LANES + lane] += j2_ * res
            acc[4 * LANES + lane] += j0_ * c0
            acc[5 * LANES + lane] += j0_ * c1
            acc[6 * LANES + lane] += j0_ * c2
            acc[7 * LANES + lane] += j1_ * c1
            acc[8 * LANES + lane] += j1_ * c2
            acc[9 * LANES + lane] += j2_ * c2


@njit(cache=True)
def _chunk_extent(chunks, run_start, run_pixel):
    """The most observations, pixels (first to last pixel of its runs) and runs of one chunk."""
    most_obs, most_px, most_runs = 1, 1, 1
    for c in range(chunks.shape[0] - 1):
        r0, r1 = chunks[c], chunks[c + 1]
        lo, hi = run_pixel[r0], run_pixel[r0]
        for r in range(r0, r1):
            lo = min(lo, run_pixel[r])
            hi = max(hi, run_pixel[r] + run_start[r + 1] - run_start[r])
        most_obs = max(most_obs, run_start[r1] - run_start[r0])
        most_px = max(most_px, hi - lo)
        most_runs = max(most_runs, r1 - r0)
    return most_obs, most_px, most_runs


@njit(cache=True)
def _spans(run_start, run_pixel, r0, r1, lo, order, spans):
    """The pixels of runs ``r0:r1`` as disjoint ``[start, end)`` rows of ``spans`` (pixels from
    ``lo``; the union of the runs' intervals, ascending); returns their number."""
    for i in range(r1 - r0):  # the runs by first pixel (insertion sort: a chunk has a few runs)
        r = r0 + i
        j = i
        while j > 0 and run_pixel[order[j - 1]] > run_pixel[r]:
            order[j] = order[j - 1]
            j -= 1
        order[j] = r
    m = -1
    for i in range(r1 - r0):
        r = order[i]
        a = run_pixel[r] - lo
        b = a + run_start[r + 1] - run_start[r]
        if m >= 0 and a <= spans[m, 1]:
            spans[m, 1] = max(spans[m, 1], b)
        else:
            m += 1
            spans[m, 0] = a
            spans[m, 1] = b
    return m + 1


@njit(cache=True)
def _fill(x, v, n):
    """``x[:n] = v`` (a plain loop: numba's slice assignment checks shapes and broadcasts, 0.2 ns per observation here)."""
    for i in range(n):
        x[i] = v


@njit(cache=True)
def _zero_sums(SN, SD, n):
    """A span's per-pixel float64 sums set to 0."""
    for i in range(n):
        SN[i] = 0.0
        SD[i] = 0.0


@njit(cache=True)
def _eq3_run(img, R, W, t, SN, SD, n):
    r"""Eq. 3's terms :math:`I\,TR\,w` and :math:`(TR)^2 w` of one run (one image, exposure ``t``)
    added to its consecutive pixels' float64 sums; returns the count of used observations."""
    used = 0
    for i in range(n):
        wo = W[i]
        used += wo > 0
        tr = t * R[i]
        trw = tr * wo
        SN[i] += img[i] * trw
        SD[i] += tr * trw
    return used


@njit(cache=True, error_model="numpy")
def _albedo_span(SN, SD, out, n):
    """Eq. 3's quotient of a span's pixels (float32; NaN where no weight)."""
    for i in range(n):
        out[i] = np.float32(SN[i] / SD[i]) if SD[i] > 0 else np.float32(np.nan)


@njit(cache=True)
def _albedo_obs(AP, A, n):
    """The albedo of each observation of a run, from its consecutive pixels, 0 where they have none (NaN)."""
    zero = np.float32(0.0)
    for i in range(n):
        a = AP[i]
        A[i] = a if a == a else zero


@njit(cache=True)
def _exposure_terms(A, R, W, img, PN, PD, n):
    r"""Eq. 4's terms :math:`I\,AR\,w` and :math:`(AR)^2 w` of each observation."""
    for i in range(n):
        ar = A[i] * R[i]
        arw = ar * W[i]
        PN[i] = img[i] * arw
        PD[i] = ar * arw


@njit(cache=True)
def _run_lanes(PN, PD, lanes, n):
    """One run's eq. 4 terms into its image's :data:`EXP_LANES` lanes (numerator, then denominator), by position in the run."""
    for g in range(0, n, EXP_LANES):
        pn, pd = PN[g:g + EXP_LANES], PD[g:g + EXP_LANES]
        for lane in range(min(EXP_LANES, n - g)):
            lanes[lane] += pn[lane]
            lanes[EXP_LANES + lane] += pd[lane]


@njit(cache=True, nogil=True, error_model="numpy")  # IEEE division: I / 0 is inf (lit), 0 / 0 NaN (shadow)
def iterate_runs(kind, chunks, run_start, run_pixel, run_image, image, w, l0, l1, l2, params, texp, n_par, n_cols,
                 shadow, ratio, thresh, alpha, exp_num, exp_den, jtj, jtr, alb, haze, base, hg, hs, hrss):
    r"""One iteration over a block's observations in chunk-major runs (:mod:`.runs`): albedo
    (eq. 3), then Q (eq. 1), the exposure sums (eq. 4) and the parameters' normal equations
    (eq. 5), chunk by chunk.

    ``kind`` picks the model's ``point(l0, l1, l2, params) -> (R, dR/dp_0, dR/dp_1)``
    (the model's ``point_kind``, :mod:`lunaralbedo.model.photometry.pointwise`); 0: the layers are R
    and its derivatives.  ``params`` and the layers are float32.  ``texp`` (float32) are the
    exposures of the local images ``run_image``.  ``shadow``/``ratio``/``thresh``: dynamic
    shadow test :math:`I/(\rho T) \ge t` on R or on the layer ``ratio`` (:data:`SHADOW_ON_R`, ...).
    ``n_cols`` Jacobian columns (``n_par`` derivatives, then R; 0: no parameter sums); ``alpha``
    (size 0: not wanted) gives the phase-angle range of the used observations.  ``exp_num``,
    ``exp_den`` (float64; size 0: eq. 4 not wanted, its terms not computed) are added to, ``jtj``, ``jtr``
    (float64) filled; ``alb`` (float32 per
    pixel of the block, or size 0) gets the albedo where the block has observations.  Returns
    ``(Q, n_obs, alpha_min, alpha_max)``.

    ``haze`` (float32 per local image; size 0: no haze, FLOAT_HAZE 0): every sum is of the values
    less their image's haze, and the joint exposure-haze step's gradient, reduced normal matrix and
    residual sums (:mod:`.haze_kernels`) are added to ``hg`` (2 per image), ``hs`` (square) and
    ``hrss`` (3) in the same sweep (``hg`` of size 0: the haze is only taken off), with noise weights: the robust factor ``w / base`` (``base``:
    the cached weights when ``w`` are robust ones, else size 0) where eq. 1's weight is not 0.

    A chunk's loops are flat over its observations where they need no pixel (R and dR/dp, whose
    ``exp`` is :mod:`~lunaralbedo.model.photometry.vexp`; the weights after the shadow test;
    eq. 4's terms; the lanes of the global sums) and run by run where they do: a run's terms
    add into its consecutive pixels' float64 sums, and its pixels' albedo is read back, as
    contiguous slices, so nearly every loop is elementwise and LLVM vectorises it
    (``tests/test_kernels.py`` checks the packed instructions).  Eq. 3's sums of a pixel run
    over its images in tile order, ``((0 + p0) + p1) + ...``, as the NumPy oracle of eq. 3 in ``tests/oracles.py``
    sums them: the same bits.  The quotient is taken once per pixel, over the union of the
    chunk's runs (:func:`_spans`).  The global sums (Q and the normal equations) go to
    :data:`LANES` float64 lanes by position in the chunk, each image's exposure sums to
    :data:`EXP_LANES` lanes by position in its run (a run has one image: no gather of exposures,
    no scatter of sums), updated elementwise (vectorised with no sum reassociated); lanes are
    added in lane order at the end.  These sums equal image-major ones within float64 rounding,
    in one order fixed by the data alone: no dependence on workers or threads.  The phase-angle
    range is an integer min / max of the angles' bits (order-free, vectorised).  The float32 work
    rows are slices of one array at constant distances: LLVM then sees that they do not overlap
    (numba arrays carry no ``noalias``; too many possibly overlapping arrays and it gives up).
    """
    nimg = texp.shape[0]
    most_obs, most_px, most_runs = _chunk_extent(chunks, run_start, run_pixel)
    stride = most_obs + 32  # rows start in different L1 sets
    buf = np.empty(_ROWS * stride, np.float32)
    R, D0, D1 = buf[_R * stride:(_R + 1) * stride], buf[_D0 * stride:(_D0 + 1) * stride], buf[_D1 * stride:(_D1 + 1) * stride]
    T, W, A = buf[_T * stride:(_T + 1) * stride], buf[_W * stride:(_W + 1) * stride], buf[_A * stride:(_A + 1) * stride]
    PN, PD = buf[_PN * stride:(_PN + 1) * stride], buf[_PD * stride:(_PD + 1) * stride]
    SN, SD = np.empty(most_px), np.empty(most_px)  # eq. 3's float64 sums of the chunk's pixels
    AP = np.empty(most_px, np.float32)
    order, spans = np.empty(most_runs, np.int32), np.empty((most_runs, 2), np.int32)
    acc = np.zeros(N_SUMS * LANES)
    want_exp = exp_num.shape[0] > 0  # eq. 4's sums (size 0: not wanted, FLOAT_HAZE: the joint step's or held)
    expl = np.zeros(2 * nimg * EXP_LANES if want_exp else 0)
    want_alb = alb.shape[0] > 0
    with_haze, robust = haze.shape[0] > 0, base.shape[0] > 0
    joint = with_haze and hg.shape[0] > 0  # the joint step's sums too (else the haze is only taken off)
    V, N = buf[_V * stride:(_V + 1) * stride], buf[_N * stride:(_N + 1) * stride]
    hpx, hobs = (most_px, stride) if joint else (0, 0)
    CP, CN, AH, IC = np.empty(hpx), np.empty(hpx), np.empty(hpx), np.empty(hpx)  # the haze step's per-pixel sums
    HH, HE = np.empty(hobs), np.empty(hobs)  # each observation's entries of b_p
    hlanes = np.zeros((nimg if joint else 0, hk.N_HAZE_SUMS * hk.HAZE_LANES))
    pacc = np.empty(4 + 4 * hk.PAIR_LANES)
    want_alpha = alpha.shape[0] > 0
    shadow_on = shadow != NO_SHADOW_TEST
    n_obs = 0
    abits = alpha.view(np.int32)
    kmin, kmax = _MAX32, _MIN32
    for c in range(chunks.shape[0] - 1):
        r0, r1 = chunks[c], chunks[c + 1]
        s0, s1 = run_start[r0], run_start[r1]
        n = s1 - s0
        lo = run_pixel[r0]
        for r in range(r0, r1):
            lo = min(lo, run_pixel[r])
        img, wgt = image[s0:s1], w[s0:s1]
        if with_haze:  # the values less their image's haze, in a work row
            for r in range(r0, r1):
                a, b = run_start[r] - s0, run_start[r + 1] - s0
                hk.values_less_haze(img[a:b], haze[run_image[r]], V[a:b], b - a)
            img = V[:n]
        _model_rows(kind, l0[s0:s1], l1[s0:s1], l2[s0:s1], params, R, D0, D1, n)
        for r in range(r0, r1):
            _fill(T[run_start[r] - s0:], texp[run_image[r]], run_start[r + 1] - run_start[r])
        if shadow_on:
            _lit_weights(img, wgt, ratio[s0:s1] if shadow == SHADOW_ON_LAYER else R, T, thresh, W, n)
            Wc = W
        else:
            Wc = wgt  # the weights as they are (a copy cost 0.5 ns per observation)
        if want_alpha:
            kmin, kmax = _alpha_keys(abits[s0:s1], Wc, n, kmin, kmax)
        nsp = _spans(run_start, run_pixel, r0, r1, lo, order, spans)
        for q in range(nsp):
            _zero_sums(SN[spans[q, 0]:spans[q, 1]], SD[spans[q, 0]:spans[q, 1]], spans[q, 1] - spans[q, 0])
        for r in range(r0, r1):
            a, b, p = run_start[r] - s0, run_start[r + 1] - s0, run_pixel[r] - lo
            n_obs += _eq3_run(img[a:b], R[a:b], Wc[a:b], texp[run_image[r]], SN[p:p + b - a], SD[p:p + b - a], b - a)
        for q in range(nsp):
            a, b = spans[q, 0], spans[q, 1]
            _albedo_span(SN[a:b], SD[a:b], AP[a:b], b - a)
            if want_alb:
                alb[lo + a:lo + b] = AP[a:b]
        for r in range(r0, r1):
            a, b, p = run_start[r] - s0, run_start[r + 1] - s0, run_pixel[r] - lo
            _albedo_obs(AP[p:p + b - a], A[a:b], b - a)
        if want_exp:
            _exposure_terms(A, R, Wc, img, PN, PD, n)
            for r in range(r0, r1):
                a, b, k = run_start[r] - s0, run_start[r + 1] - s0, run_image[r]
                _run_lanes(PN[a:b], PD[a:b], expl[2 * EXP_LANES * k:2 * EXP_LANES * (k + 1)], b - a)
        if n_cols:
            _normal_lanes(A, T, R, Wc, D0, D1, img, acc, n, n_par)
        else:
            _cost_lanes(A, T, R, Wc, img, acc, n)
        if joint:
            hk.haze_chunk(run_start, run_pixel, run_image, r0, r1, s0, lo, nsp, spans, img, R, Wc, wgt, base[s0:s1] if robust else base,
                        robust, texp, N, CP, CN, AH, IC, HH, HE, hlanes, hs, pacc, hrss, n)
    sums = np.zeros(N_SUMS)
    for m in range(N_SUMS):
        for lane in range(LANES):
            sums[m] += acc[m * LANES + lane]
    for k in range(nimg if want_exp else 0):
        num, den = 0.0, 0.0
        for lane in range(EXP_LANES):
            num += expl[2 * EXP_LANES * k + lane]
            den += expl[2 * EXP_LANES * k + EXP_LANES + lane]
        exp_num[k] += num
        exp_den[k] += den
    if n_cols:
        nrm = np.array([[sums[4], sums[5], sums[6]], [sums[5], sums[7], sums[8]], [sums[6], sums[8], sums[9]]])
        for m in range(n_cols):
            jtr[m] = sums[1 + m]
            for i in range(n_cols):
                jtj[m, i] = nrm[m, i]
    if joint:
        hk.add_lanes(hlanes, hg, hs, hrss)
    amin, amax = _key_range(kmin, kmax)
    return sums[0], n_obs, amin, amax


@njit(cache=True)
def _key_range(kmin, kmax):
    """The float32 phase angles of the int32 keys ``kmin``, ``kmax`` (``(inf, -inf)``: none)."""
    if kmin > kmax:
        return np.inf, -np.inf
    ends = np.array([kmin ^ ((kmin >> 31) & _MAG), kmax ^ ((kmax >> 31) & _MAG)], np.int32).view(np.float32)
    return float(ends[0]), float(ends[1])


@njit(cache=True, nogil=True)
def alpha_range(alpha, w):
    """The range of the phase angles ``alpha`` (float32) of the observations with ``w > 0`` (NaN left out;
    ``(inf, -inf)``: none): what :func:`iterate_runs` gives over the same observations, once.

    Without a dynamic shadow test the weights, hence this range, are the same in every pass:
    the prepare step stores it with the block (``alpha_range``) and the kernel is not asked for it.
    """
    kmin, kmax = _alpha_keys(alpha.view(np.int32), w, alpha.shape[0], _MAX32, _MIN32)
    return _key_range(kmin, kmax)
