r"""Blending weights :math:`w_{ij}^k` (the PhotometryTK manual, section 7, eq. 1).

The weights decrease linearly from the centre of an image (:math:`w = 1`) to its
boundary (:math:`w = 0`) so that the albedo mosaic is seamless.  Each image is
described by compact *profiles*: for every row the first and last valid column,
for every column the first and last valid row.  The weight of pixel
:math:`(r, c)` is the product of a row tent and a column tent,

.. math::

    w(r, c) = t\bigl(c; c_0(r), c_1(r)\bigr)\; t\bigl(r; r_0(c), r_1(c)\bigr),
    \qquad t(x; a, b) = \max\Bigl(0, 1 - \frac{|x - (a+b)/2|}{(b-a)/2}\Bigr).

Profiles cost O(rows + columns) memory, so the weight of any window can be
computed without holding the image.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, vectorize


@dataclass(frozen=True)
class WeightProfile:
    """Per-row valid column range and per-column valid row range of one image (pixel indices).

    Rows (columns) without any valid pixel have ``first > last``.
    """

    row_first: np.ndarray  # (H,) first valid column of each row
    row_last: np.ndarray  # (H,) last valid column of each row
    col_first: np.ndarray  # (W,) first valid row of each column
    col_last: np.ndarray  # (W,) last valid row of each column

    @classmethod
    def full(cls, height: int, width: int) -> "WeightProfile":
        """Profile of an image whose pixels are all valid."""
        return cls(
            np.zeros(height, np.int32),
            np.full(height, width - 1, np.int32),
            np.zeros(width, np.int32),
            np.full(width, height - 1, np.int32),
        )


def profile_from_mask(valid: np.ndarray) -> WeightProfile:
    """Profiles of a boolean validity mask ``(H, W)``: each row's first and last valid column (``W``, ``-1``
    where none), each column's first and last valid row (``H``, ``-1`` where none), in one pass over the
    mask (:func:`_mask_profile`)."""
    valid = np.ascontiguousarray(valid, dtype=bool)
    h, w = valid.shape
    rf, rl = np.empty(h, np.int32), np.empty(h, np.int32)
    cf, cl = np.full(w, h, np.int32), np.full(w, -1, np.int32)
    _mask_profile(valid, rf, rl, cf, cl)
    return WeightProfile(rf, rl, cf, cl)


@njit(cache=True, nogil=True)
def _mask_profile(valid, rf, rl, cf, cl):
    """:func:`profile_from_mask` (``cf`` and ``cl`` come filled with ``H`` and ``-1``): a row's ends by scans from
    either side, which stop at its first valid pixel; the columns' ends updated row by row in one branch-free
    (vectorised) loop."""
    h, w = valid.shape
    for i in range(h):
        row = valid[i]
        a = 0
        while a < w and not row[a]:
            a += 1
        b = w - 1
        while b >= a and not row[b]:
            b -= 1
        rf[i], rl[i] = (a, b) if a < w else (w, -1)
        for j in range(w):
            v = row[j]
            cf[j] = i if (v and cf[j] == h) else cf[j]
            cl[j] = i if v else cl[j]


def merge_profiles(parts: list[tuple[int, WeightProfile]], height: int, width: int) -> WeightProfile:
    """Combine profiles of horizontal strips ``(row_offset, profile)`` into one for the whole image."""
    rf = np.full(height, width, np.int32)
    rl = np.full(height, -1, np.int32)
    cf = np.full(width, height, np.int32)
    cl = np.full(width, -1, np.int32)
    for off, p in parts:
        n = len(p.row_first)
        rf[off : off + n] = p.row_first
        rl[off : off + n] = p.row_last
        has = p.col_first <= p.col_last
        cf = np.where(has, np.minimum(cf, p.col_first + off), cf)
        cl = np.where(has, np.maximum(cl, p.col_last + off), cl)
    return WeightProfile(rf, rl, cf, cl)


@njit(cache=True, nogil=True)
def _tent(x, centre, half):
    """The float64 tent of one point (:func:`tent_about`)."""
    if not half > 0:
        return 0.0
    return min(max(1.0 - abs(x - centre) / half, 0.0), 1.0)


_tent_ufunc = vectorize(["float64(float64, float64, float64)"], cache=True)(_tent.py_func)


def tent_about(x: np.ndarray, centre: np.ndarray, half: np.ndarray, dtype=np.float64) -> np.ndarray:
    r""":math:`\max(0, 1 - |x - c|/h)`: 1 at the centre ``c``, 0 at distance ``h`` and beyond, 0 where ``h = 0``.

    The one implementation of the blending tent of eq. 1.  ``dtype=np.float64`` (the
    solver) evaluates it in float64 (:func:`_tent`, also per pixel in :func:`window_weights`).
    ``dtype=np.float32`` gives PhotometryTK's numerics,
    which the legacy gold needs: ``c``, ``h``, :math:`|x - c|` and the slope :math:`-1/h`
    rounded to float32 and :math:`t = (-1/h)|x - c| + 1` in float32.
    """
    x = np.asarray(x, dtype=np.float64)
    if np.dtype(dtype) == np.float32:
        f32 = np.float32
        h = np.asarray(half).astype(f32)
        dist = np.abs(x - np.asarray(centre).astype(f32).astype(np.float64)).astype(f32)
        with np.errstate(divide="ignore", invalid="ignore"):  # zero half-widths are masked below
            slope = (-1.0 / h.astype(np.float64)).astype(f32)
            t = np.maximum(f32(0.0), slope * dist + f32(1.0)).astype(f32)
        return np.where(h != 0, t, f32(0.0)).astype(f32)
    with np.errstate(divide="ignore", invalid="ignore"):  # the vectorised loop may divide where h = 0 (masked)
        return _tent_ufunc(x, np.asarray(centre, dtype=np.float64), np.asarray(half, dtype=np.float64))


def tent(x: np.ndarray, first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """:math:`t(x; a, b)`: 1 at the centre of ``[a, b]``, 0 at and beyond its ends."""
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(last, dtype=np.float64)
    return tent_about(x, (a + b) / 2.0, (b - a) / 2.0)


@njit(cache=True, nogil=True)
def _row_weights(x, y, c_row, h_row, centre, half, valid, out, n):
    """One row of :func:`_window_weights`: pixel ``j`` (column ``x[j]``) gets the row's tent times its column's
    (``centre[j]``, ``half[j]``) at row ``y``, 0 where not ``valid`` (a loop without branches: vectorised)."""
    zero = np.float32(0.0)
    for j in range(n):
        t = np.float32(_tent(x[j], c_row, h_row) * _tent(y, centre[j], half[j]))
        out[j] = t if valid[j] else zero


@njit(cache=True, nogil=True)
def _window_weights(row_first, row_last, col_first, col_last, row_off, col_off, valid, out):
    """``out[i, j]``: the row tent times the column tent of pixel ``(row_off + i, col_off + j)`` (float64,
    rounded once to float32), 0 where not ``valid``; profiles of rows/columns outside the image are the edge ones.
    The columns' centres and half-widths are taken once per window, then each row in one vectorised loop."""
    n_r, n_c = row_first.shape[0], col_first.shape[0]
    width = out.shape[1]
    x, centre, half = np.empty(width), np.empty(width), np.empty(width)
    for j in range(width):
        c = col_off + j
        cc = min(max(c, 0), n_c - 1)
        a2, b2 = float(col_first[cc]), float(col_last[cc])
        x[j], centre[j], half[j] = float(c), (a2 + b2) / 2.0, (b2 - a2) / 2.0
    for i in range(out.shape[0]):
        r = row_off + i
        rc = min(max(r, 0), n_r - 1)
        a, b = float(row_first[rc]), float(row_last[rc])
        _row_weights(x, float(r), (a + b) / 2.0, (b - a) / 2.0, centre, half, valid[i], out[i], width)


def window_weights(profile: WeightProfile, row_off: int, col_off: int, height: int, width: int) -> np.ndarray:
    """Tent weights (float32) of the image window starting at ``(row_off, col_off)``."""
    return source_weights(profile, row_off, col_off, np.ones((height, width), bool))


def source_weights(profile: WeightProfile, row_off: int, col_off: int, valid: np.ndarray) -> np.ndarray:
    """Blending weights (float32) of the image window at ``(row_off, col_off)``, zero where not ``valid``."""
    valid = np.ascontiguousarray(valid, dtype=bool)
    out = np.empty(valid.shape, np.float32)
    _window_weights(*(np.asarray(a, np.int64) for a in (profile.row_first, profile.row_last, profile.col_first,
                                                        profile.col_last)), int(row_off), int(col_off), valid, out)
    return out
