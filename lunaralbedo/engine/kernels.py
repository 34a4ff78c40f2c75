r"""Fused numba kernels of one iteration over a tile's compact observations (eqs. 1, 3, 4, 5, 7).

The prepare step gathers observations as 1-D float32 arrays ordered by image, then by pixel
(``pix``: flat index into the block; ``start[k]:start[k+1]`` are image ``k``'s) and caches
them in pixel-major order (:func:`.pixelmajor.pixel_major`, once per block at prepare, see
:mod:`.tilework`): :func:`iterate_pixels` computes each pixel's albedo and all the sums in
one pass, with the photometric model's ``point`` (R and dR/dp) inline; finalise's
:func:`finalise_pixels` sums each pixel's observations as it does.
Every product is formed in float32 as the former NumPy code did and summed into float64
accumulators in one fixed order (fixed lanes for the global sums), so results do not depend on
workers or threads.  ``cache=True``, no fastmath (IEEE semantics, no reassociation).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..model.photometry import lunar_lambert


#: Dynamic shadow test of :func:`iterate_pixels` (eq. 1's mask of shadow types 2 and 3,
#: :func:`lunaralbedo.model.shadows.dynamic_lit`): none, on the model's R, on a given layer.
NO_SHADOW_TEST, SHADOW_ON_R, SHADOW_ON_LAYER = 0, 1, 2


#: The models' ``point`` functions the iterate kernel inlines, by number (0: none, R and dR/dp
#: come as arrays).  They are reached as globals of :func:`_point`: a numba function passed as
#: an argument would make its caller compile again in every process (the argument's type
#: names the object).  A model that gets a ``point`` adds one line here and a branch there.
POINT_KINDS = {"lunaralbedo.model.photometry.lunar_lambert.point": 1}


def point_kind(point) -> int | None:
    """The number of a model's ``point`` in :data:`POINT_KINDS` (None: not inlined by the kernel)."""
    f = getattr(point, "py_func", point)
    return POINT_KINDS.get(f"{getattr(f, '__module__', '')}.{getattr(f, '__qualname__', '')}")


@njit(cache=True)
def _point(kind, l0, l1, l2, params):
    """R and dR/dp of one observation: the model's ``point`` of :data:`POINT_KINDS`, or the layers."""
    if kind == 1:
        return lunar_lambert.point(l0, l1, l2, params)
    return l0, l1, l2


#: Observations per chunk of :func:`iterate_pixels` (whole pixels; a pixel with more is a chunk alone):
#: 1024 keeps its ~50 KB of work rows near the core (the strip's biggest tile, the kernel as one function:
#: 7.5-7.8 ns per observation with 4096, 6.6-7.1 ns with 1024, 6.8-7.4 ns with 256; docs/performance-history.md 0g).
CHUNK = 1024
#: Most observations of one pixel :func:`iterate_pixels` takes (a tile with fewer than 65536
#: images always fits); with :data:`CHUNK` and a pad, the row length of its float32 work
#: buffer, whose rows then start in different L1 sets.
PIXEL_MAX = 65536
STRIDE = PIXEL_MAX + CHUNK + 32
#: Lanes of the global sums (Q, the normal equations): observation ``i``
#: of a chunk goes to lane ``i % LANES``; lanes are combined in lane order at the end.
LANES = 64
#: Lanes of each image's exposure sums, by position ``i % EXP_LANES`` in the chunk.
EXP_LANES = 8
#: Rows of the float32 work buffer; global sums (Q, then the normal equations' b0, b1, b2, a00,
#: a01, a02, a11, a12, a22).
_R, _D0, _D1, _T, _W, _A, _PN, _PD, _ROWS = range(9)
N_SUMS = 10
# int32 keys of float32 bits for the phase-angle range (positive floats keep their bits, negative
# ones get their magnitude bits flipped: the keys order as the floats do; NaN keys exceed +inf's)
_MAG, _MAX32, _MIN32 = np.int32(0x7FFFFFFF), np.int32(0x7FFFFFFF), np.int32(-0x80000000)
_INF_KEY, _NINF_KEY = np.int32(0x7F800000), np.int32(-0x7F800001)


@njit(cache=True)
def _carry_sums(s, p, first, n, half):
    """One round of the per-pixel partial sums, between the two buffers of ``s`` (from the first
    into the second when ``half`` is 1, else back): ``out[i] = (0 if first[i] else prev[i - 1]) + p[i]``
    (elementwise, vectorised)."""
    src = s[:STRIDE] if half == 1 else s[STRIDE:]
    dst = s[STRIDE:] if half == 1 else s[:STRIDE]
    dst[0] = 0.0 + p[0]
    prev, out, p1, f1 = src[:n - 1], dst[1:n], p[1:n], first[1:n]
    for k in range(n - 1):
        out[k] = (0.0 if f1[k] else prev[k]) + p1[k]


@njit(cache=True)
def _carry_back(ends, src, dst, first, n, t):
    """One round carrying each pixel's albedo back from its last observation: ``dst[i] = ends[i]``
    where ``i`` ends a pixel, else ``src[i + 1]`` (``ends`` itself in the first round)."""
    nxt = ends[1:n] if t == 1 else src[1:n]
    e, out, last = ends[:n - 1], dst[:n - 1], first[1:n + 1]
    for k in range(n - 1):
        out[k] = e[k] if last[k] else nxt[k]
    dst[n - 1] = ends[n - 1]


# The loops of one chunk of :func:`iterate_pixels`, each its own function: LLVM vectorises a
# small loop over a few arrays where, inlined into the one big function, it kept several of them
# scalar (the normal equations' lanes: 2.5 ns per observation in the big function, 1.7 ns as their own).
# They stay in this file: numba's cache checks a function's own file only, so loops inlined from
# another module could run stale after an edit (docs/architecture.md).
@njit(cache=True)
def _model_rows(kind, g0, g1, g2, params, R, D0, D1, n):
    """R and dR/dp of each observation (:func:`_point`)."""
    if kind == 1:
        for i in range(n):
            R[i], D0[i], D1[i] = _point(1, g0[i], g1[i], g2[i], params)
    else:
        for i in range(n):
            R[i], D0[i], D1[i] = g0[i], g1[i], g2[i]


@njit(cache=True)
def _exposures(ims, texp, T, n):
    """Each observation's exposure (a gather: scalar)."""
    for i in range(n):
        T[i] = texp[ims[i]]


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
def _eq3_terms(img, T, R, W, PN, PD, SN, SD, n):
    r"""Eq. 3's terms :math:`I\,TR\,w` and :math:`(TR)^2 w`, each observation's first partial sums, and the count of used observations."""
    used = 0
    for i in range(n):
        wo = W[i]
        used += wo > 0
        tr = T[i] * R[i]
        trw = tr * wo
        pn = img[i] * trw
        pd = tr * trw
        PN[i] = pn
        PD[i] = pd
        SN[i] = 0.0 + pn
        SD[i] = 0.0 + pd
    return used


@njit(cache=True, error_model="numpy")
def _ratios(sn, sd, out, n):
    """Eq. 3's quotient at every observation (float32; NaN where no weight)."""
    for i in range(n):
        out[i] = np.float32(sn[i] / sd[i]) if sd[i] > 0 else np.float32(np.nan)


@njit(cache=True)
def _finite(ap, A, n):
    """The albedo of each observation's pixel, 0 where it has none (NaN)."""
    zero = np.float32(0.0)
    for i in range(n):
        a = ap[i]
        A[i] = a if a == a else zero


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
def _exposure_lanes(A, R, W, img, ims, PN, PD, expl, n):
    """Eq. 4's terms, then each image's exposure sums in :data:`EXP_LANES` lanes by position (a scatter: scalar)."""
    for i in range(n):
        ar = A[i] * R[i]
        arw = ar * W[i]
        PN[i] = img[i] * arw
        PD[i] = ar * arw
    for i in range(n):
        e = (ims[i] * EXP_LANES + i % EXP_LANES) * 2
        expl[e] += PN[i]
        expl[e + 1] += PD[i]


@njit(cache=True, nogil=True, error_model="numpy")  # IEEE division: I / 0 is inf (lit), 0 / 0 NaN (shadow)
def iterate_pixels(kind, offsets, image_of, image, w, l0, l1, l2, params, texp, n_par, n_cols,
                   shadow, ratio, thresh, alpha, exp_num, exp_den, jtj, jtr, alb):
    r"""One iteration over pixel-major observations: albedo (eq. 3), then Q (eq. 1), the exposure
    sums (eq. 4) and the parameters' normal equations (eq. 5), pixel by pixel.

    ``kind`` picks the model's ``point(l0, l1, l2, params) -> (R, dR/dp_0, dR/dp_1)``
    (:data:`POINT_KINDS`, :mod:`lunaralbedo.model.photometry.pointwise`); 0: the layers are R
    and its derivatives.  ``params`` and the layers are float32.  ``texp`` (float32) are the exposures of the
    local images ``image_of``.  ``shadow``/``ratio``/``thresh``: dynamic shadow test
    :math:`I/(\rho T) \ge t` on R or on the layer ``ratio`` (:data:`SHADOW_ON_R`, ...).
    ``n_cols`` Jacobian columns (``n_par`` derivatives, then R; 0: no parameter sums); ``alpha``
    (size 0: not wanted) gives the phase-angle range of the used observations.  ``exp_num``,
    ``exp_den`` (float64) are added to, ``jtj``, ``jtr`` (float64) filled; ``alb`` (float32 per
    pixel, or size 0) gets the albedo.  Returns ``(Q, n_obs, alpha_min, alpha_max)``.

    Observations go in chunks of whole pixels, in flat loops over the chunk, nearly all of them
    elementwise so that LLVM vectorises them (AVX2; ``tests/test_kernels.py`` checks the packed
    instructions): R and dR/dp (the model's ``point``, whose ``exp`` is
    :mod:`~lunaralbedo.model.photometry.vexp`), the weights after the shadow test, eq. 3's terms,
    each pixel's albedo, then the terms of the sums.  The float32 products are formed as the
    former image-major NumPy code formed them.  Eq. 3's float64 sums run over each pixel's
    observations in tile order, ``((0 + p0) + p1) + ...``, as :func:`albedo` sums them, so the
    albedo is the same bits; they are built for every observation at once, round ``t`` extending
    each partial sum by one more observation (:func:`_carry_sums`), and the albedo is carried
    back from each pixel's last observation (:func:`_carry_back`).  The global sums (Q and the
    normal equations) go to :data:`LANES` float64 lanes by position in the chunk, updated
    elementwise (vectorised with no sum reassociated), each image's exposure sums to
    :data:`EXP_LANES` lanes (a scatter: scalar, as is the gather of the exposures); lanes are
    added in lane order at the end.  These sums equal image-major ones within float64 rounding,
    in one order fixed by the data alone: no dependence on workers or threads.  The phase-angle
    range is an integer min / max of the angles' bits (order-free, vectorised).  The float32 work
    rows are slices of one array at constant distances: LLVM then sees that they do not overlap
    (numba arrays carry no ``noalias``; too many possibly overlapping arrays and it gives up).
    Each loop is a small function of its own (``_model_rows`` ... ``_exposure_lanes``): LLVM
    vectorises each before it is inlined, where the loops written out in this one function left
    the lanes of the normal equations scalar (docs/performance-history.md, section 0g).  Chunks of
    :data:`CHUNK` observations keep the work rows in the L1/L2 caches.
    """
    nimg = texp.shape[0]
    buf = np.empty(_ROWS * STRIDE, np.float32)
    R, D0, D1 = buf[_R * STRIDE:(_R + 1) * STRIDE], buf[_D0 * STRIDE:(_D0 + 1) * STRIDE], buf[_D1 * STRIDE:(_D1 + 1) * STRIDE]
    T, W, A = buf[_T * STRIDE:(_T + 1) * STRIDE], buf[_W * STRIDE:(_W + 1) * STRIDE], buf[_A * STRIDE:(_A + 1) * STRIDE]
    PN, PD = buf[_PN * STRIDE:(_PN + 1) * STRIDE], buf[_PD * STRIDE:(_PD + 1) * STRIDE]
    sums64 = np.empty(4 * STRIDE)  # eq. 3's float64 partial sums (numerator, denominator), two buffers each
    SN, SD = sums64[:2 * STRIDE], sums64[2 * STRIDE:]
    first = np.empty(STRIDE + 1, np.uint8)  # 1 where a pixel starts
    acc = np.zeros(N_SUMS * LANES)
    expl = np.zeros(2 * nimg * EXP_LANES)
    want_alb = alb.shape[0] > 0
    want_alpha = alpha.shape[0] > 0
    shadow_on = shadow != NO_SHADOW_TEST
    n_obs = 0
    abits = alpha.view(np.int32)
    kmin, kmax = _MAX32, _MIN32
    npx = offsets.shape[0] - 1
    j0 = 0
    while j0 < npx:
        s0 = offsets[j0]
        j1 = max(j0 + 1, np.searchsorted(offsets, s0 + CHUNK, "right") - 1)  # whole pixels, <= CHUNK observations
        s1 = offsets[j1]
        n = s1 - s0
        npc = j1 - j0
        if n > PIXEL_MAX:
            raise ValueError("a pixel with more observations than iterate_pixels takes (PIXEL_MAX)")
        off = offsets[j0:j1 + 1]
        most = 0  # most observations of one pixel in the chunk
        for jj in range(npc):
            most = max(most, off[jj + 1] - off[jj])
        img, wgt, ims = image[s0:s1], w[s0:s1], image_of[s0:s1]
        _model_rows(kind, l0[s0:s1], l1[s0:s1], l2[s0:s1], params, R, D0, D1, n)
        _exposures(ims, texp, T, n)
        if shadow_on:
            _lit_weights(img, wgt, ratio[s0:s1] if shadow == SHADOW_ON_LAYER else R, T, thresh, W, n)
        else:
            W[:n] = wgt
        if want_alpha:
            kmin, kmax = _alpha_keys(abits[s0:s1], W, n, kmin, kmax)
        n_obs += _eq3_terms(img, T, R, W, PN, PD, SN, SD, n)
        # eq. 3 per pixel, over the observations: each one's partial sums of its pixel's terms in
        # tile order (round t extends them by one more observation back: ((0 + p0) + p1) + ...,
        # the order of albedo()), the albedo where they end, then carried back over the pixel
        first[:n + 1] = 0
        for jj in range(npc):
            first[off[jj] - s0] = 1
        first[n] = 1  # past the last pixel
        for t in range(1, most):
            _carry_sums(SN, PN, first, n, t % 2)
            _carry_sums(SD, PD, first, n, t % 2)
        sn = SN[STRIDE:] if most % 2 == 0 else SN[:STRIDE]
        sd = SD[STRIDE:] if most % 2 == 0 else SD[:STRIDE]
        _ratios(sn, sd, PN, n)
        for t in range(1, most):
            _carry_back(PN, A if t % 2 == 1 else PD, PD if t % 2 == 1 else A, first, n, t)
        ap = PN if most == 1 else (PD if most % 2 == 0 else A)  # the albedo of each observation's pixel
        if want_alb:
            for jj in range(npc):
                alb[j0 + jj] = ap[off[jj] - s0]
        _finite(ap, A, n)
        if n_cols:
            _normal_lanes(A, T, R, W, D0, D1, img, acc, n, n_par)
        else:
            _cost_lanes(A, T, R, W, img, acc, n)
        _exposure_lanes(A, R, W, img, ims, PN, PD, expl, n)
        j0 = j1
    sums = np.zeros(N_SUMS)
    for m in range(N_SUMS):
        for lane in range(LANES):
            sums[m] += acc[m * LANES + lane]
    for k in range(nimg):
        num = 0.0
        den = 0.0
        for lane in range(EXP_LANES):
            num += expl[(k * EXP_LANES + lane) * 2]
            den += expl[(k * EXP_LANES + lane) * 2 + 1]
        exp_num[k] += num
        exp_den[k] += den
    if n_cols:
        nrm = np.array([[sums[4], sums[5], sums[6]], [sums[5], sums[7], sums[8]], [sums[6], sums[8], sums[9]]])
        for m in range(n_cols):
            jtr[m] = sums[1 + m]
            for i in range(n_cols):
                jtj[m, i] = nrm[m, i]
    amin, amax = np.inf, -np.inf
    if kmin <= kmax:
        ends = np.array([kmin ^ ((kmin >> 31) & _MAG), kmax ^ ((kmax >> 31) & _MAG)], np.int32).view(np.float32)
        amin, amax = float(ends[0]), float(ends[1])
    return sums[0], n_obs, amin, amax


@njit(cache=True, nogil=True, error_model="numpy")  # IEEE division, as the NumPy formulas (model/updates.albedo, error_terms)
def finalise_pixels(offsets, pixels, image, image_of, texp, r, w, blend, alb, err):
    r"""Eq. 3's albedo and eq. 7's error of a block's pixel-major observations, in one pass, into ``alb`` and ``err``.

    ``texp`` (float32) are the exposures of the local images ``image_of``, ``r`` the model's R
    and ``w`` the weights of the observations (float32); ``blend`` (per pixel) eq. 7's
    denominator, the sum of blending weights.  ``alb`` (float32 per pixel of the block) gets
    :math:`A = \sum I\,TR\,w / \sum (TR)^2 w` (NaN where no weight), each pixel's float64
    sums over its images in tile order, as :func:`iterate_pixels` sums them (the same bits);
    ``err`` (float32 per pixel, or size 0: not wanted) gets
    :math:`\sum_{w>0} (I/(TR) - A)^2 w / \sum S` (float64 numerator and quotient; 0 where
    the pixel has a blending weight and no observation, NaN where it has none), the bits of the
    former NumPy code (``np.where(den > 0, num / den, nan)`` cast to float32).
    """
    nan = np.float32(np.nan)
    want_err = err.shape[0] > 0
    for p in range(alb.shape[0]):
        alb[p] = nan
    if want_err:
        for p in range(err.shape[0]):
            err[p] = np.float32(0.0 / blend[p]) if blend[p] > 0 else nan
    for j in range(pixels.shape[0]):
        p = pixels[j]
        num, den = 0.0, 0.0
        for o in range(offsets[j], offsets[j + 1]):
            tr = texp[image_of[o]] * r[o]
            trw = tr * w[o]
            num += image[o] * trw
            den += tr * trw
        if den > 0:
            alb[p] = num / den
        if want_err and blend[p] > 0:
            a = alb[p]
            acc = 0.0
            for o in range(offsets[j], offsets[j + 1]):
                if w[o] > 0:
                    dev = image[o] / (texp[image_of[o]] * r[o]) - a
                    acc += dev * dev * w[o]
            err[p] = acc / blend[p]
