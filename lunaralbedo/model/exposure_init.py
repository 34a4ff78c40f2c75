r"""Exposure initialisation.

*Seed* (the PhotometryTK manual, section 7, step 1): :math:`T^k = \mathrm{TR\_CONST} / \overline{R^k}`,
the mean reflectance over the image's usable pixels.

*Overlap* (our default): where two images :math:`j, k` see the same pixel,
:math:`I^j/R^j \approx A\,T^j` and :math:`I^k/R^k \approx A\,T^k`, so

.. math:: d_{jk} = \log\frac{I^j}{R^j} - \log\frac{I^k}{R^k} \approx \log T^j - \log T^k

independently of the unknown albedo.  Summing :math:`d` over every shared pixel
gives one equation per overlapping pair; the exposures follow from the
least-squares problem

.. math:: \min_x \sum_{(j,k)} n_{jk}\,(x_j - x_k - \bar d_{jk})^2 + \mu \sum_k (x_k - x^0_k)^2,
          \qquad T^k = e^{x_k},

where :math:`x^0` is the seed initialisation (it fixes the overall scale, which
:math:`A\,T` leaves free, and images without overlaps) and :math:`\mu` is tiny.
This is the gain compensation of panorama stitching (and of ISIS ``equalizer``).
Each tile contributes :math:`(n_{jk}, \sum d_{jk})` sums that a driver adds up.
"""
from __future__ import annotations

import numpy as np
from numba import njit


def mean_reflectance_sums(r, start):
    """Per-image ``(sum R, count)`` over a tile's observations with :math:`R > 0` (float64, shape ``(k,)``).

    Image ``a`` owns observations ``start[a]:start[a+1]``; each sum runs in observation
    order in float64 (numba, no temporaries).
    """
    return _segment_sums(np.asarray(r), np.asarray(start, dtype=np.int64))


@njit(cache=True, nogil=True)
def _segment_sums(r, start):
    k = start.shape[0] - 1
    rs = np.zeros(k)
    n = np.zeros(k)
    for a in range(k):
        acc = 0.0
        m = 0
        for o in range(start[a], start[a + 1]):
            if r[o] > 0:
                acc += np.float64(r[o])
                m += 1
        rs[a] = acc
        n[a] = m
    return rs, n


def seed_exposure(tr_const, r_sum, r_count, dtype=np.float64):
    r""":math:`T^k = \mathrm{TR\_CONST}/\overline{R^k}` (the PhotometryTK manual, section 7, step 1); images without usable pixels get TR_CONST.

    ``dtype=np.float32`` gives the legacy numerics: the mean and the quotient rounded to float32.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        mean_r = np.where(r_count > 0, r_sum / r_count, np.nan)
    if np.dtype(dtype) == np.float32:
        mean_r, tr_const = mean_r.astype(np.float32), np.float32(tr_const)
        return np.where(np.isfinite(mean_r) & (mean_r > 0), tr_const / mean_r, tr_const).astype(np.float32)
    return np.where(np.isfinite(mean_r) & (mean_r > 0), tr_const / mean_r, float(tr_const))


def pair_sums(pix, start, image, r, index, width=None):
    """Pairwise ``{(j, k): (n, sum d_jk)}`` from compact usable observations.

    Image ``a`` owns observations ``start[a]:start[a+1]`` with increasing pixel numbers
    ``pix``; ``index`` maps ``a`` to the global image id.  Shared pixels are found by
    merging the two sorted pixel lists (numba); the differences are formed in float32
    and summed in float64 in pixel order.  ``width`` (the grid's row length, when
    ``pix`` is ``row * width + col``) lets pairs whose column ranges do not meet be skipped.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        logq = (np.log(image) - np.log(r)).astype(np.float32, copy=False)  # float32 already when both are
    pix = np.ascontiguousarray(pix)
    if pix.dtype not in (np.int32, np.int64):
        pix = pix.astype(np.int64)
    a, b, n, d = _pair_sums(pix, np.asarray(start, dtype=np.int64), logq, int(width or 0))
    out = {}
    for aa, bb, nn, dd in zip(a.tolist(), b.tolist(), n.tolist(), d.tolist()):
        j, k = int(index[aa]), int(index[bb])
        out[(j, k) if j < k else (k, j)] = (nn, dd if j < k else -dd)
    return out


@njit(cache=True, nogil=True, inline="always")
def _first_at_least(pix, lo, hi, value):
    """The first index in ``lo:hi`` of the ascending ``pix`` whose pixel is at least ``value`` (``hi``: none):
    a galloping search from ``lo`` (steps 1, 2, 4, ... then a binary search), so that a merge skips a run of
    pixels the other image does not have (the rest of a row beside an overlap) in log steps."""
    step = 1
    while lo + step < hi and pix[lo + step - 1] < value:
        step *= 2
    a, b = lo, min(lo + step, hi)  # pix[a - 1] < value; the answer is in a..b
    while a < b:
        m = (a + b) // 2
        if pix[m] < value:
            a = m + 1
        else:
            b = m
    return a


@njit(cache=True, nogil=True)
def _pair_sums(pix, start, logq, width):
    """Shared pixels of every pair of images by a merge of their sorted pixel lists: ``(a, b, n, sum d)``."""
    k_count = start.shape[0] - 1
    lo = np.zeros(k_count, np.int64)
    hi = np.full(k_count, -1, np.int64)
    clo = np.zeros(k_count, np.int64)
    chi = np.full(k_count, -1, np.int64)
    for a in range(k_count):
        if start[a + 1] > start[a]:
            lo[a], hi[a] = pix[start[a]], pix[start[a + 1] - 1]
            if width > 0:  # the image's column range: its pixels ascend, so a row's first pixel moves forward (no division per pixel)
                cmin, cmax = width, -1
                row0 = (pix[start[a]] // width) * width
                for o in range(start[a], start[a + 1]):
                    while pix[o] >= row0 + width:
                        row0 += width
                    c = pix[o] - row0
                    cmin = min(cmin, c)
                    cmax = max(cmax, c)
                clo[a], chi[a] = cmin, cmax
    npair = k_count * (k_count - 1) // 2
    out_a = np.empty(npair, np.int64)
    out_b = np.empty(npair, np.int64)
    out_n = np.empty(npair, np.int64)
    out_d = np.empty(npair, np.float64)
    m = 0
    for a in range(k_count):
        for b in range(a + 1, k_count):
            if hi[b] < lo[a] or hi[a] < lo[b] or start[a + 1] == start[a] or start[b + 1] == start[b]:
                continue
            if width > 0 and (chi[b] < clo[a] or chi[a] < clo[b]):
                continue
            i, j = start[a], start[b]
            ie, je = start[a + 1], start[b + 1]
            n = 0
            d = 0.0
            while i < ie and j < je:
                if pix[i] < pix[j]:
                    i = _first_at_least(pix, i + 1, ie, pix[j])
                elif pix[j] < pix[i]:
                    j = _first_at_least(pix, j + 1, je, pix[i])
                else:
                    d += logq[i] - logq[j]
                    n += 1
                    i += 1
                    j += 1
            if n:
                out_a[m], out_b[m], out_n[m], out_d[m] = a, b, n, d
                m += 1
    return out_a[:m], out_b[:m], out_n[:m], out_d[:m]


def merge_pair_sums(total, part):
    """Add one tile's pair sums into ``total`` (in place); call in a fixed tile order."""
    for key, (n, d) in part.items():
        n0, d0 = total.get(key, (0, 0.0))
        total[key] = (n0 + n, d0 + d)
    return total


def overlap_exposure(pairs, x0, mu=1e-6):
    r"""Solve the log-ratio least squares for :math:`T = e^x` (see module docstring).

    ``pairs`` is ``{(j, k): (n, sum d)}``, ``x0`` the log of the seed exposures.
    ``mu`` is relative to the mean pair count.

    The normal matrix :math:`\lambda I + \sum n_{jk}(e_j - e_k)(e_j - e_k)^T` is a
    weighted graph Laplacian with one non-zero per image and per overlapping pair,
    so it is assembled sparse (CSC) and factorised by SuperLU: memory and time grow
    with the number of pairs, not with :math:`K^2` (10^5 images: see
    docs/performance.md).  A direct factorisation rather than LSQR/LSMR: the tiny
    :math:`\mu` makes the system ill-conditioned (condition ~ 1/mu for a long strip),
    where Krylov solvers need thousands of iterations to reach the same answer.
    """
    from scipy.sparse import csc_matrix
    from scipy.sparse.linalg import spsolve

    x0 = np.asarray(x0, dtype=np.float64)
    k = len(x0)
    if not pairs:
        return np.exp(x0)
    keys = sorted(pairs)
    jj = np.array([a for a, _ in keys], dtype=np.int64)
    ii = np.array([b for _, b in keys], dtype=np.int64)
    n = np.array([pairs[key][0] for key in keys], dtype=np.float64)
    dsum = np.array([pairs[key][1] for key in keys], dtype=np.float64)
    lam = mu * float(np.mean(n))
    diag = np.full(k, lam)
    np.add.at(diag, jj, n)
    np.add.at(diag, ii, n)
    rows = np.concatenate([np.arange(k), jj, ii])
    cols = np.concatenate([np.arange(k), ii, jj])
    vals = np.concatenate([diag, -n, -n])
    m = csc_matrix((vals, (rows, cols)), shape=(k, k))  # duplicates are summed
    rhs = lam * x0.copy()
    np.add.at(rhs, jj, dsum)  # n * dbar = sum d
    np.add.at(rhs, ii, -dsum)
    x = np.asarray(spsolve(m, rhs), dtype=np.float64)
    # Fix the free scale exactly: same mean log exposure as the seed initialisation.
    x += np.mean(x0) - np.mean(x)
    return np.exp(x)
