"""Independent NumPy oracles of the solver's equations (the PhotometryTK manual, eqs. 1, 3-7), whole arrays at once.

The package computes these sums in its numba kernels (``lunaralbedo/engine/kernels.py``,
``finalise_kernels.py``); the tests compare the kernels with these plain NumPy formulas, written
over a dense (image, row, column) stack.  They are the tests' own, not the package's: the legacy mode
uses only the per-observation terms (``model/updates.albedo_terms``, ``cost_terms``, ``error_terms``).
"""
from __future__ import annotations

import numpy as np

from lunaralbedo.model.updates import _f64sum, albedo_terms, cost_terms, error_terms


def albedo(image, tr, w):
    r"""Albedo that minimises :math:`Q` for fixed exposure and reflectance (eqs. 3 and 6).

    .. math:: A_{ij} = \frac{\sum_k I^k_{ij} T^k R^k_{ij} S^k_{ij} w^k_{ij}}{\sum_k (T^k R^k_{ij})^2 S^k_{ij} w^k_{ij}}

    Eq. 6 (one Gauss-Newton step from any :math:`A`) lands exactly on eq. 3 because
    :math:`Q` is quadratic in :math:`A`.  ``tr`` is :math:`T^k R^k_{ij}`.  Returns
    float32 albedo, NaN where no image contributes.
    """
    num_k, den_k = albedo_terms(image, tr, w)
    num = _f64sum(num_k, axis=0)
    den = _f64sum(den_k, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(den > 0, num / den, np.nan)
    return a.astype(np.float32)


def residuals(image, a, tr, w):
    r""":math:`I - A T R` (float32); pixels without albedo (NaN) count as :math:`A = 0` (their weights are 0)."""
    return image - np.nan_to_num(a)[None] * tr


def cost(res, w):
    r"""The cost :math:`Q = \sum_k\sum_{ij}(I - ATR)^2 S w` of eq. 1 (float64)."""
    return float(_f64sum(cost_terms(res, w)))


def exposure_sums(image, a, r, w):
    r"""Per-image numerator and denominator of the exposure update (eq. 4).

    .. math:: \tilde T^k = T^k + \frac{\sum_{ij}(I - ATR) A R S w}{\sum_{ij} (AR)^2 S w}
              = \frac{\sum_{ij} I A R S w}{\sum_{ij} (AR)^2 S w}

    Returns ``(num, den)`` arrays of shape ``(K,)``; the update is ``num / den``
    after summing over every tile.
    """
    ar = np.nan_to_num(a)[None] * r
    arw = ar * w
    num = _f64sum(image * arw, axis=(1, 2))
    den = _f64sum(ar * arw, axis=(1, 2))
    return num, den


def error_map(image, a, tr, w_shadow, w_blend):
    r"""Per-pixel albedo error (eq. 7).

    .. math:: E_{ij} = \frac{\sum_k (I^k_{ij}/(T^k R^k_{ij}) - A_{ij})^2 S^k_{ij} w^k_{ij}}{\sum_k w^k_{ij}}

    ``w_shadow`` is :math:`S w`, ``w_blend`` is :math:`w`.  NaN where no weight.
    """
    num = _f64sum(error_terms(image, a[None], tr, w_shadow), axis=0)
    den = _f64sum(w_blend, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(den > 0, num / den, np.nan)
    return e.astype(np.float32)


def haze_sums(value, t, r, w):
    r"""Gradient, reduced normal matrix and residual sums of the joint exposure-haze step (FLOAT_HAZE), dense.

    ``value`` is :math:`I - H_k` (image, row, column), ``t`` the exposures, ``r`` the reflectance and
    ``w`` the noise weights.  With the albedo of these weights :math:`A = \sum w\,TR\,v / c`,
    :math:`c = \sum_k w (TR)^2`, the residual :math:`\rho = v - A T R` and :math:`b_k = w T R\,(A R, 1)`:

    .. math:: g_k = \sum_p w \rho (A R, 1), \quad
              S_{kl} = \delta_{kl} \sum_p w \begin{pmatrix} (AR)^2 & AR \\ AR & 1 \end{pmatrix} - \sum_p b_k b_l^T / c.

    Returns ``g`` (2K: T then H per image), ``S`` (2K x 2K) and ``(sum w rho^2, observations, pixels)``.
    """
    v, r, w = (np.asarray(x, np.float64) for x in (value, r, w))
    t = np.asarray(t, np.float64)[:, None, None]
    used = w > 0
    tr = np.where(used, t * r, 0.0)
    c = np.sum(w * tr * tr, axis=0)
    ok = c > 0
    a = np.where(ok, np.sum(w * tr * np.where(used, v, 0.0), axis=0) / np.where(ok, c, 1.0), 0.0)
    use = used & ok[None]
    ar = np.where(use, a[None] * np.where(used, r, 0.0), 0.0)
    wu = np.where(use, w, 0.0)
    res = np.where(use, v - ar * t, 0.0)
    k = v.shape[0]
    g = np.zeros(2 * k)
    g[0::2], g[1::2] = np.sum(wu * ar * res, axis=(1, 2)), np.sum(wu * res, axis=(1, 2))
    s = np.zeros((2 * k, 2 * k))
    idx = np.arange(k)
    s[2 * idx, 2 * idx] = np.sum(wu * ar * ar, axis=(1, 2))
    s[2 * idx, 2 * idx + 1] = s[2 * idx + 1, 2 * idx] = np.sum(wu * ar, axis=(1, 2))
    s[2 * idx + 1, 2 * idx + 1] = np.sum(wu, axis=(1, 2))
    bh = (wu * tr).reshape(k, -1)
    bt = bh * ar.reshape(k, -1)
    inv_c = np.where(ok, 1.0 / np.where(ok, c, 1.0), 0.0).ravel()
    for m, x in ((0, bt), (1, bh)):
        for n, y in ((0, bt), (1, bh)):
            s[m::2, n::2] -= (x * inv_c) @ y.T
    rss = (float(np.sum(wu * res * res)), float(np.count_nonzero(use)), float(np.count_nonzero(ok)))
    return g, s, rss
