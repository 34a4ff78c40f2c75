r"""Exposure initialisation.

*Seed* (seed 000 section 7, step 1): :math:`T^k = \mathrm{TR\_CONST} / \overline{R^k}`,
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


def mean_reflectance_sums(r, usable):
    """Per-image ``(sum R, count)`` over usable pixels of a tile (float64, shape ``(K,)``)."""
    rs = np.sum(np.where(usable, r, 0.0), axis=(1, 2), dtype=np.float64)
    n = np.count_nonzero(usable, axis=(1, 2)).astype(np.float64)
    return rs, n


def seed_exposure(tr_const, r_sum, r_count, dtype=np.float64):
    r""":math:`T^k = \mathrm{TR\_CONST}/\overline{R^k}` (seed 000 section 7, step 1); images without usable pixels get TR_CONST.

    ``dtype=np.float32`` gives the legacy numerics: the mean and the quotient rounded to float32.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        mean_r = np.where(r_count > 0, r_sum / r_count, np.nan)
    if np.dtype(dtype) == np.float32:
        mean_r, tr_const = mean_r.astype(np.float32), np.float32(tr_const)
        return np.where(np.isfinite(mean_r) & (mean_r > 0), tr_const / mean_r, tr_const).astype(np.float32)
    return np.where(np.isfinite(mean_r) & (mean_r > 0), tr_const / mean_r, float(tr_const))


def log_ratio_sums(image, r, usable, index):
    """Pairwise ``{(j, k): (n, sum d_jk)}`` of one tile, with global image indices ``index``.

    ``usable`` marks pixels with positive image value and reflectance that are
    valid, lit and weighted.  Only pairs with ``j < k`` (global order) are returned.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        logq = np.where(usable, np.log(image) - np.log(r), np.nan).astype(np.float32)
    out = {}
    k_count = logq.shape[0]
    for a in range(k_count):
        ua = usable[a]
        if not ua.any():
            continue
        for b in range(a + 1, k_count):
            both = ua & usable[b]
            n = int(np.count_nonzero(both))
            if n == 0:
                continue
            d = float(np.sum(logq[a][both] - logq[b][both], dtype=np.float64))
            j, k = int(index[a]), int(index[b])
            out[(j, k) if j < k else (k, j)] = (n, d if j < k else -d)
    return out


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
    """
    x0 = np.asarray(x0, dtype=np.float64)
    k = len(x0)
    if not pairs:
        return np.exp(x0)
    nmean = np.mean([n for n, _ in pairs.values()])
    lam = mu * nmean
    m = lam * np.eye(k)
    rhs = lam * x0.copy()
    for (j, i), (n, dsum) in sorted(pairs.items()):
        dbar = dsum / n
        m[j, j] += n
        m[i, i] += n
        m[j, i] -= n
        m[i, j] -= n
        rhs[j] += n * dbar
        rhs[i] -= n * dbar
    x = np.linalg.solve(m, rhs)
    # Fix the free scale exactly: same mean log exposure as the seed initialisation.
    x += np.mean(x0) - np.mean(x)
    return np.exp(x)
