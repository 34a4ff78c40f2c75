"""Interpolation with the legacy (Vision Workbench) numerics, vectorised.

* bilinear: float64 arithmetic, result rounded to float32 (the legacy float
  images), constant edge extension;
* bicubic: Catmull-Rom kernel in float64 with the legacy 0.25 normalisation,
  result rounded to float32, constant edge extension.

Coordinates are fractional pixel indices (column ``x``, row ``y``) on the
centre-of-pixel convention of :mod:`.vwgeo`.
"""
from __future__ import annotations

import numpy as np


def _clamped(img: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    h, w = img.shape
    return img[np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)]


def bilinear_f32(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of an image at ``(x, y)``: float64 arithmetic, float32 result."""
    img = np.asarray(img, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    nx, ny = x - x0, y - y0
    top = _clamped(img, y0, x0) * (1 - nx) + _clamped(img, y0, x0 + 1) * nx
    bottom = _clamped(img, y0 + 1, x0) * (1 - nx) + _clamped(img, y0 + 1, x0 + 1) * nx
    return (top * (1 - ny) + bottom * ny).astype(np.float32)


def bicubic_f32(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bicubic (Catmull-Rom) samples of ``img`` at ``(x, y)``, float64 sums, float32 result."""
    img = np.asarray(img, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    nx = x - x0
    ny = y - y0
    s = (((2 - nx) * nx - 1) * nx, (3 * nx - 5) * nx * nx + 2, ((4 - 3 * nx) * nx + 1) * nx, (nx - 1) * nx * nx)
    t = (((2 - ny) * ny - 1) * ny, (3 * ny - 5) * ny * ny + 2, ((4 - 3 * ny) * ny + 1) * ny, (ny - 1) * ny * ny)
    result = None
    for r in range(4):
        row = s[0] * _clamped(img, y0 + r - 1, x0 - 1)
        for c in range(1, 4):
            row = row + s[c] * _clamped(img, y0 + r - 1, x0 + c - 1)
        result = t[r] * row if result is None else result + t[r] * row
    return (result * 0.25).astype(np.float32)
