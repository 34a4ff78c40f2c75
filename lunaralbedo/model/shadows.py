r"""Shadow masks :math:`S_{ij}^k` (the PhotometryTK manual, section 5, SHADOW_TYPE; eq. 1).

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

import math

import numpy as np
from numba import njit

NONE, THRESHOLD, LAMBERT_RATIO, LUNAR_LAMBERT_RATIO = 0, 1, 2, 3


def static_lit(image: np.ndarray, shadow_type: int, thresh: float) -> np.ndarray:
    """Lit mask decided from the image alone (types 0 and 1; types 2/3 return all lit)."""
    image = np.asarray(image)
    if shadow_type == THRESHOLD:
        with np.errstate(invalid="ignore"):
            return image >= thresh
    return np.isfinite(image) | ~np.isfinite(image)


def dynamic_lit(image: np.ndarray, reflectance: np.ndarray, exposure: np.ndarray, thresh: float) -> np.ndarray:
    r"""Lit mask of types 2/3: :math:`I/(R\,T) \ge t`; ``exposure`` broadcasts over the image stack."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = image / (reflectance * exposure)
    return np.nan_to_num(ratio, nan=-np.inf) >= thresh


def window_pixels(dn, alpha=None, nodata=None, lut=None, lit_threshold=None, saturation=None):
    """Value, validity and usability of the pixels of one DRG window, in one pass (:func:`_window_pixels`).

    ``dn`` ``(h, w)``: band 1 as read; ``alpha``: the alpha band (valid where > 0) or None;
    ``nodata``: the band's nodata value or None; ``lut``: a camera response over 0..255 applied
    to the DN (Kim et al.; valid where it is finite) or None.  Returns ``value`` (float32, the DN
    or its response, 0 where not valid), ``valid`` (finite, not nodata, alpha > 0) and
    ``usable`` (valid, lit by :func:`static_lit` of the DN with ``lit_threshold`` (shadow type
    1), below ``saturation``: a saturated pixel is left out; None when both are None): the
    arrays of the former NumPy steps, bit for bit (``tests/test_prepare_kernels.py``).
    """
    dn = np.ascontiguousarray(dn)
    h, w = dn.shape
    value, valid, usable = np.empty((h, w), np.float32), np.empty((h, w), bool), np.empty((h, w), bool)
    _window_pixels(dn, np.ascontiguousarray(alpha) if alpha is not None else np.ones((0, 0), dn.dtype),
                   np.nan if nodata is None else float(nodata), nodata is not None,
                   np.asarray(lut, np.float32) if lut is not None else np.zeros(0, np.float32),
                   np.nan if lit_threshold is None else float(lit_threshold), lit_threshold is not None,
                   np.nan if saturation is None else float(saturation), saturation is not None, value, valid, usable)
    return value, valid, (usable if (lit_threshold is not None or saturation is not None) else None)


@njit(cache=True, nogil=True)
def _window_pixels(dn, alpha, nodata, has_nodata, lut, thresh, has_thresh, saturation, has_saturation,
                   value, valid, usable):
    """:func:`window_pixels`: the float32 DN compared with float32 nodata and thresholds (NumPy 2 compares a
    float32 array with a Python float in float32), its response ``lut[int(clip(nan_to_num(v), 0, n - 1))]``."""
    h, w = dn.shape
    nd, t32, s32 = np.float32(nodata), np.float32(thresh), np.float32(saturation)
    n_lut = lut.shape[0]
    top = np.float32(n_lut - 1)
    for r in range(h):
        for c in range(w):
            v = np.float32(dn[r, c])
            ok = math.isfinite(v)
            if has_nodata:
                ok = ok and v != nd
            if alpha.shape[0]:
                ok = ok and alpha[r, c] > 0
            x = v
            if n_lut:
                k = v
                if k != k:
                    k = np.float32(0.0)
                k = min(max(k, np.float32(0.0)), top)  # +-inf clip to the ends as nan_to_num's extremes do
                x = lut[np.intp(k)]
                ok = ok and math.isfinite(x)
            good = ok
            if has_thresh:
                good = good and v >= t32
            if has_saturation:
                good = good and v < s32
            value[r, c] = x if ok else np.float32(0.0)
            valid[r, c] = ok
            usable[r, c] = good
