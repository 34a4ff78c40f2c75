r"""Exposures with a Gaussian prior around known values (``EXPOSURE_MODE prior``).

The exposure update of the PhotometryTK manual (eq. 4 of Nefian et al., "Lunar albedo
reconstruction", and of the PhotometryTK manual),

.. math:: T^k = \frac{\sum_{ij} I^k_{ij} A_{ij} R^k_{ij} w^k_{ij}}{\sum_{ij} (A_{ij} R^k_{ij})^2 w^k_{ij}},

is the minimum of eq. 1's cost :math:`Q` over :math:`T^k` for a fixed albedo.  With
exposures known beforehand (calibrated I/F cubes, e.g. ISIS ``lronaccal``/``lrowaccal``
output, or exposure times from the labels), ``EXPOSURE_MODE prior`` minimises instead the
negative log posterior

.. math:: \frac{Q}{\sigma_n^2} + \sum_k \frac{(T^k - T^k_0)^2}{(\sigma\,T^k_0)^2},

with :math:`\sigma_n^2 = Q / N` the residual variance per (weighted) observation of the
current pass (DN², the DRGs' units) and :math:`\sigma` the relative standard deviation of the
prior (setting ``EXPOSURE_PRIOR_SIGMA``, default 0.02: the given exposures are trusted to
about 2 %).  Its minimum over :math:`T^k` for the current albedo is

.. math:: T^k = \frac{n_k/\sigma_n^2 + T^k_0\,\lambda_k}{d_k/\sigma_n^2 + \lambda_k},
   \qquad \lambda_k = (\sigma\,T^k_0)^{-2},

where :math:`n_k, d_k` are eq. 4's numerator and denominator.  An image with many
observations follows its data (:math:`d_k/\sigma_n^2 \gg \lambda_k`), one with few keeps
its prior.  The prior fixes the overall scale that :math:`A\,T` otherwise leaves free, so the
solver does not re-pin the geometric mean of the exposures in this mode.  Pure NumPy, no I/O.
"""
from __future__ import annotations

import numpy as np


def prior_weight(t0, sigma: float) -> np.ndarray:
    r"""The prior's weight :math:`\lambda_k = (\sigma T^k_0)^{-2}` per image (``t0`` > 0, ``sigma`` > 0 relative)."""
    t0 = np.asarray(t0, np.float64)
    return 1.0 / (sigma * t0) ** 2


def exposure_update_prior(t, num, den, t0, sigma: float, q: float, n_obs: int) -> np.ndarray:
    r"""Eq. 4 with the Gaussian prior of the module docstring (float64).

    Parameters
    ----------
    t : current exposures (kept where an image has no data and no prior weight).
    num, den : eq. 4's summed numerator :math:`\sum I A R w` and denominator :math:`\sum (A R)^2 w` per image.
    t0 : the prior's exposures :math:`T_0` (> 0).
    sigma : relative standard deviation of the prior.
    q, n_obs : the pass's cost :math:`Q` (eq. 1) and its number of used observations;
        :math:`\sigma_n^2 = Q/N` (floored at :math:`10^{-12}` for a noise-free scene).
    """
    t = np.asarray(t, np.float64)
    var = max(q / n_obs, 1e-12) if n_obs else 1.0
    lam = prior_weight(t0, sigma)
    num_ = np.asarray(num, np.float64) / var + lam * np.asarray(t0, np.float64)
    den_ = np.asarray(den, np.float64) / var + lam
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den_ > 0, num_ / den_, t)
