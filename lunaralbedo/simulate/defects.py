r"""Defects of real images for the DRG strip: additive haze, outliers, calibrated float I/F recording.

The clean strip records :math:`I = \mathrm{gain}\,A\,T\,R + n` (eq. 1 of the PhotometryTK manual).
Real images break it (ASP ``sfs`` models the first with a per-image haze, and rejects the second
with a robust cost):

* **haze** :math:`H_k` per image, DN: :math:`I = \mathrm{gain}\,A\,T\,R + H_k + n` (scattered
  light, dark-level residue), drawn uniformly from ``SceneSpec.haze_dn``;
* **outliers** on a fraction of each image's pixels (``SceneSpec.outlier_fraction``): half
  in unsaturated hot spots (discs of radius 1-2 px whose signal is multiplied by 1.6-3, kept
  below 250 DN: cosmic rays, unmasked artefacts) and half in dark dropout rows (row segments
  of 8-40 px at 0.3 times the signal);
* **calibrated** recording: float32 I/F, :math:`I = A\,R + n/\mathrm{gain}`, every exposure 1
  (what ISIS ``lronaccal``/``lrowaccal`` write).

Pure NumPy, no I/O; positions in pixels of one image.
"""
from __future__ import annotations

import numpy as np

#: Ceiling of a hot spot's DN (unsaturated: the 8-bit recording keeps it).
HOT_CEILING_DN = 250.0


def outlier_factors(shape: tuple[int, int], fraction: float, rng) -> np.ndarray:
    """Multiplicative factors (float64, 1 where clean) putting ``fraction`` of the pixels in hot spots and dropout rows."""
    h, w = shape
    f = np.ones(shape)
    if fraction <= 0:
        return f
    target = fraction * h * w
    yy, xx = np.mgrid[0:h, 0:w]
    hot = 0.0
    while hot < target / 2:  # hot spots: discs of radius 1-2 px, x1.6-3
        cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(1.0, 2.0)
        disc = (yy - cy) ** 2 + (xx - cx) ** 2 <= r * r
        f[disc & (f == 1)] = rng.uniform(1.6, 3.0)
        hot = np.count_nonzero(f > 1)
    while np.count_nonzero(f != 1) < target:  # dropout rows: segments of 8-40 px at x0.3
        row, n = int(rng.integers(0, h)), int(rng.integers(8, 41))
        c0 = int(rng.integers(0, max(1, w - n)))
        seg = f[row, c0:c0 + n]
        seg[seg == 1] = 0.3
    return f


def apply_outliers(dn_signal: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """The DN signal with ``factors`` applied, hot spots capped at :data:`HOT_CEILING_DN` (never below the clean signal)."""
    out = dn_signal * factors
    hot = factors > 1
    out[hot] = np.maximum(np.minimum(out[hot], HOT_CEILING_DN), dn_signal[hot])
    return out


def calibrated(signal: np.ndarray, noise: float, rng) -> np.ndarray:
    """Float32 I/F: ``signal`` (:math:`A R`, exposure 1) plus Gaussian noise of ``noise`` (I/F units)."""
    return (signal + rng.normal(0.0, noise, signal.shape)).astype(np.float32)
