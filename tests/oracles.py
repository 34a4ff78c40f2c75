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
