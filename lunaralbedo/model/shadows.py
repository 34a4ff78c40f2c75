r"""Shadow masks :math:`S_{ij}^k` (seed 000 section 5, SHADOW_TYPE; eq. 1).

:math:`S = 0` marks a pixel in shadow (left out of every sum), :math:`S = 1` a lit one.

* type 0: no pixel is in shadow;
* type 1: in shadow when the image value is below SHADOW_THRESH (static: decided
  once from the image, before the solve);
* type 2: in shadow when :math:`I/(R\,T) < t` with the Lambertian :math:`R = \cos i`;
* type 3: as type 2 with the Lunar-Lambertian :math:`R` of eq. 2.

Types 2 and 3 depend on the exposure :math:`T`, so they are re-evaluated with the
current exposure at every iteration.
"""
from __future__ import annotations

import numpy as np

NONE, THRESHOLD, LAMBERT_RATIO, LUNAR_LAMBERT_RATIO = 0, 1, 2, 3


def static_lit(image: np.ndarray, shadow_type: int, thresh: float) -> np.ndarray:
    """Lit mask decided from the image alone (types 0 and 1; types 2/3 return all lit)."""
    image = np.asarray(image)
    if shadow_type == THRESHOLD:
        with np.errstate(invalid="ignore"):
            return image >= thresh
    return np.isfinite(image) | ~np.isfinite(image)


def usable_pixels(image: np.ndarray, valid: np.ndarray, lit_threshold: float | None = None,
                  saturation: float | None = None) -> np.ndarray:
    """Pixels that can be observations: ``valid``, lit by :func:`static_lit` (shadow type 1) with
    ``lit_threshold`` when it is given, and below ``saturation`` (a DRG's maximum value) when given."""
    good = np.asarray(valid, dtype=bool).copy()
    if lit_threshold is not None:
        good &= static_lit(image, THRESHOLD, lit_threshold)
    if saturation is not None:
        with np.errstate(invalid="ignore"):
            good &= np.asarray(image) < saturation
    return good


def dynamic_lit(image: np.ndarray, reflectance: np.ndarray, exposure: np.ndarray, thresh: float) -> np.ndarray:
    r"""Lit mask of types 2/3: :math:`I/(R\,T) \ge t`; ``exposure`` broadcasts over the image stack."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = image / (reflectance * exposure)
    return np.nan_to_num(ratio, nan=-np.inf) >= thresh
