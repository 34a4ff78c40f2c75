r"""Fused numba kernels of one iteration over a tile's compact observations (eqs. 1, 3, 4, 5, 7).

The prepare step gathers observations as 1-D float32 arrays ordered by image, then by pixel
(``pix``: flat index into the block; ``start[k]:start[k+1]`` are image ``k``'s) and caches
them in pixel-major order (:func:`pixel_major`, once per block at prepare, see
:mod:`.tilework`): :func:`iterate_pixels` computes each pixel's albedo and all the sums in
one pass, with the photometric model's ``point`` (R and dR/dp) inline; finalise's
:func:`albedo` and :func:`error_numerator` take any order with a pixel per observation.
Every product is formed in float32 as the former NumPy code did and summed into float64
accumulators in one fixed sequential order, so results do not depend on workers or threads.
``cache=True``, no fastmath (IEEE semantics, no reassociation).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..model.photometry import lunar_lambert


#: Dynamic shadow test of :func:`iterate_pixels` (eq. 1's mask of shadow types 2 and 3,
#: :func:`lunaralbedo.model.shadows.dynamic_lit`): none, on the model's R, on a given layer.
NO_SHADOW_TEST, SHADOW_ON_R, SHADOW_ON_LAYER = 0, 1, 2


@njit(cache=True)
def by_pixel(pix, start, npix, image_of):
    """Pixel-major order of image-major observations (counting sort, stable: images stay in tile order).

    Returns ``(order, offsets, pixels)`` and fills ``image_of`` (local image per position):
    observation ``order[q]`` goes to position ``q``; pixel ``pixels[j]`` owns positions
    ``offsets[j]:offsets[j+1]``.
    """
    nxt = np.zeros(npix, np.int64)
    for o in range(pix.shape[0]):
        nxt[pix[o]] += 1
    m = 0
    for p in range(npix):
        m += nxt[p] > 0
    pixels = np.empty(m, np.int32)
    offsets = np.empty(m + 1, np.int32)
    j = 0
    pos = 0
    for p in range(npix):
        c = nxt[p]
        if c > 0:
            pixels[j] = p
            offsets[j] = pos
            nxt[p] = pos
            pos += c
            j += 1
    offsets[m] = pos
    order = np.empty(pix.shape[0], np.int64)
    for k in range(start.shape[0] - 1):
        for o in range(start[k], start[k + 1]):
            q = nxt[pix[o]]
            nxt[pix[o]] = q + 1
            order[q] = o
            image_of[q] = k
    return order, offsets, pixels


def pixel_major(obs, npix: int, names) -> dict:
    """A tile's compact observations (image-major, :mod:`.observations`) in pixel-major order.

    ``offsets``/``pixels`` (int32) per pixel with observations, ``image_of`` (uint16, or int32
    beyond 65535 images) the local image of each observation, the arrays ``names`` permuted,
    and ``index``.  ~18 bytes per observation for value, weight and two layers.
    """
    index = np.asarray(obs["index"])
    if len(obs["pix"]) >= 2**31:
        raise ValueError(f"{len(obs['pix'])} observations in one tile: more than int32 offsets hold")
    image_of = np.empty(len(obs["pix"]), np.uint16 if len(index) < 2**16 else np.int32)
    order, offsets, pixels = by_pixel(np.asarray(obs["pix"]), np.asarray(obs["start"]), npix, image_of)
    out = {"offsets": offsets, "pixels": pixels, "image_of": image_of, "index": index}
    for n in names:
        out[n] = np.asarray(obs[n])[order]
    return out


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


#: Observations per chunk of :func:`iterate_pixels` (whole pixels; buffers stay in L1/L2).
CHUNK = 4096


@njit(cache=True)
def _points(kind, l0, l1, l2, params, s0, s1, R, D0, D1):
    """R and dR/dp of observations ``s0:s1`` into chunk buffers (a tight loop: no sums live across ``exp``)."""
    for o in range(s0, s1):
        r, d0, d1 = _point(kind, l0[o], l1[o], l2[o], params)
        R[o - s0] = r
        D0[o - s0] = d0
        D1[o - s0] = d1


@njit(cache=True, error_model="numpy")  # IEEE division: I / 0 is inf (lit), 0 / 0 NaN (shadow)
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
    ``exp_den``, ``jtj``, ``jtr`` (float64) are filled; ``alb`` (float32 per pixel, or size 0)
    gets the albedo.  Returns ``(Q, n_obs, alpha_min, alpha_max)``.

    Observations go in chunks of whole pixels, in flat loops over the chunk: R and dR/dp
    (:func:`_points`), the albedo terms, each pixel's albedo, then the sums.  The float32 products are those of the former
    image-major NumPy/numba code: the albedo equals :func:`albedo`'s bit for bit (each pixel sums
    its images in tile order) and so do the exposure sums for the same R (each image sums its
    pixels in row-major order); Q and the normal equations are float64 sums in pixel-major order
    (equal to image-major sums within float64 rounding).  One fixed order: no dependence on
    workers or threads.
    """
    zero = np.float32(0.0)
    cap = CHUNK + texp.shape[0]  # a chunk holds whole pixels (at most one observation per image each)
    R, D0, D1 = np.empty(cap, np.float32), np.empty(cap, np.float32), np.empty(cap, np.float32)
    T, W, A = np.empty(cap, np.float32), np.empty(cap, np.float32), np.empty(cap, np.float32)
    PN, PD = np.empty(cap, np.float32), np.empty(cap, np.float32)
    want_alb = alb.shape[0] > 0
    want_alpha = alpha.shape[0] > 0
    q = 0.0
    n_obs = 0
    amin = np.inf
    amax = -np.inf
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    b0 = b1 = b2 = 0.0
    npx = offsets.shape[0] - 1
    j0 = 0
    while j0 < npx:
        s0 = offsets[j0]
        j1 = j0 + 1
        while j1 < npx and offsets[j1 + 1] - s0 <= CHUNK:
            j1 += 1
        s1 = offsets[j1]
        n = s1 - s0
        _points(kind, l0, l1, l2, params, s0, s1, R, D0, D1)
        img = image[s0:s1]
        # per observation: exposure, weight after the shadow test, eq. 3's numerator and denominator terms
        for i in range(n):
            t = texp[image_of[s0 + i]]
            wo = w[s0 + i]
            if shadow != NO_SHADOW_TEST:
                rho = R[i] if shadow == SHADOW_ON_R else ratio[s0 + i]
                if not img[i] / (rho * t) >= thresh:  # NaN ratios are shadow, as in dynamic_lit
                    wo = zero
            n_obs += wo > 0
            T[i] = t
            W[i] = wo
            tr = t * R[i]
            trw = tr * wo
            PN[i] = img[i] * trw
            PD[i] = tr * trw
        # per pixel: the albedo (its images in tile order), 0 in the sums where there is none
        for j in range(j0, j1):
            num = 0.0
            den = 0.0
            for i in range(offsets[j] - s0, offsets[j + 1] - s0):
                num += PN[i]
                den += PD[i]
            a = np.float32(num / den) if den > 0 else np.float32(np.nan)
            if want_alb:
                alb[j] = a
            if a != a:
                a = zero
            for i in range(offsets[j] - s0, offsets[j + 1] - s0):
                A[i] = a
        # per observation: eq. 1, eq. 4, eq. 5
        for i in range(n):
            k = image_of[s0 + i]
            a = A[i]
            t = T[i]
            ro = R[i]
            wo = W[i]
            res = img[i] - a * (t * ro)
            arw = (a * ro) * wo
            q += res * res * wo
            exp_num[k] += img[i] * arw
            exp_den[k] += (a * ro) * arw
            if n_cols:
                at = a * t
                # columns in order: dR/dp_0, dR/dp_1 (when present), then R
                c0 = at * D0[i] if n_par > 0 else at * ro
                c1 = (at * D1[i] if n_par > 1 else at * ro) if n_par > 0 else zero
                c2 = at * ro if n_par > 1 else zero
                j0_, j1_, j2_ = c0 * wo, c1 * wo, c2 * wo
                b0 += j0_ * res
                b1 += j1_ * res
                b2 += j2_ * res
                a00 += j0_ * c0
                a01 += j0_ * c1
                a02 += j0_ * c2
                a11 += j1_ * c1
                a12 += j1_ * c2
                a22 += j2_ * c2
        if want_alpha:
            for i in range(n):
                if W[i] > 0:
                    amin = min(amin, alpha[s0 + i])
                    amax = max(amax, alpha[s0 + i])
        j0 = j1
    if n_cols:
        acc = np.array([[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]])
        vec = np.array([b0, b1, b2])
        for m in range(n_cols):
            jtr[m] = vec[m]
            for i in range(n_cols):
                jtj[m, i] = acc[m, i]
    return q, n_obs, amin, amax


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
def error_numerator(pix, image, tr, w, alb, npix):
    r"""Numerator of eq. 7 per pixel: :math:`\sum (I/(TR) - A)^2 S w` (float64)."""
    num = np.zeros(npix)
    for o in range(pix.shape[0]):
        if w[o] > 0:
            dev = image[o] / tr[o] - alb[pix[o]]
            num[pix[o]] += dev * dev * w[o]
    return num
