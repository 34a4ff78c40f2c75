r"""Each value of an image's raster less the mean of its window, and the spread of those deviations, in numba.

The spatial test of the outlier pass (:mod:`lunaralbedo.model.outliers`, :func:`.robust_kernels.spatial_flags`)
compares each observation's :math:`\log a` with its :data:`~lunaralbedo.model.outliers.WINDOW` ×
WINDOW neighbourhood in its own image.  :func:`window_deviations` gives :math:`d = \log a -
\operatorname{mean}_N \log a` for a raster from box sums row by row: each row's sums over
the window's columns go into a ring of WINDOW rows, each output row is the sum of WINDOW
of them, in loops over contiguous rows that LLVM vectorises (O(WINDOW) a pixel, every sum
in a fixed order, no summed-area table: its differences of large sums cost digits and two
more passes over memory).  :func:`mad_sigma` is the image's robust spread from a sample of
its :math:`d` (:func:`sample`), with medians by :func:`median` (quickselect with a
branch-free partition: numba's ``np.median`` mispredicts a branch for every other value and
took a tenth of the pass).  The rasters may be float32; every sum, mean and median is
float64; no fastmath, ``cache=True``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: Most values the spread of an image's :math:`d` is taken from, evenly spaced in raster order (the MAD's
#: relative standard error is then ~1.3 % for Gaussian values): two medians of every observation were a third
#: of the pass.
SCALE_SAMPLE = 1 << 13


@njit(cache=True)
def _select(a, lo, hi, k):
    """The ``k``-th smallest of ``a[lo:hi]`` (numbers), ``a`` reordered so that ``a[:k] <= a[k]``: quickselect, the
    median of three as pivot, Lomuto's partition without a branch (a swap every step, the boundary advanced by the
    comparison)."""
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        x, y, z = a[lo], a[mid], a[hi - 1]  # the median of the three to the end
        if (x <= y) == (y <= z):
            a[mid], a[hi - 1] = z, y
        elif (y <= x) == (x <= z):
            a[lo], a[hi - 1] = z, x
        pivot = a[hi - 1]
        j = lo
        for i in range(lo, hi - 1):  # a[lo:j] < pivot <= a[j:i]
            v = a[i]
            a[i] = a[j]
            a[j] = v
            j += v < pivot
        a[hi - 1] = a[j]
        a[j] = pivot
        if j == k:
            return pivot
        if k < j:
            hi = j
        else:
            lo = j + 1
    return a[lo]


@njit(cache=True)
def median(a, n):
    """The median of ``a[:n]`` (numbers; ``a`` reordered), the same value as ``np.median``: the middle one, or the
    mean of the two middle ones."""
    h = n >> 1
    hi = _select(a, 0, n, h)
    if n & 1:
        return hi
    lo = a[0]
    for i in range(1, h):  # a[:h] <= a[h]: the largest of them is the other middle value
        lo = max(lo, a[i])
    return (lo + hi) / 2


@njit(cache=True)
def mad_sigma(x, n):
    """1.4826 × the median absolute deviation of ``x[:n]`` (numbers; NaN for none), ``x`` reordered:
    :func:`lunaralbedo.model.outliers.robust_sigma`."""
    if n == 0:
        return np.nan
    med = median(x, n)
    for i in range(n):
        x[i] = abs(x[i] - med)
    return 1.4826 * median(x, n)


@njit(cache=True)
def _pad_row(x, p, pc, n, holes):
    """``p = x`` with NaN (no value) as 0 and, with ``holes``, ``pc`` 1 where ``x`` is a number, else 0."""
    if holes:
        for i in range(n):
            v = x[i]
            ok = v == v
            p[i] = v if ok else 0.0
            pc[i] = 1.0 if ok else 0.0
    else:
        for i in range(n):
            p[i] = x[i]


@njit(cache=True)
def _box_row(p, out, n, size):
    """``out[j] = p[j] + ... + p[j + size - 1]``, left to right (the window of 7 in one expression: its sums stay in
    registers; any other size adds the same terms in the same order)."""
    if size == 7:
        for j in range(n):
            out[j] = p[j] + p[j + 1] + p[j + 2] + p[j + 3] + p[j + 4] + p[j + 5] + p[j + 6]
        return
    for j in range(n):
        out[j] = p[j]
    for t in range(1, size):
        for j in range(n):
            out[j] += p[j + t]


@njit(cache=True)
def _box_col(ring, rows, out, n, size):
    """``out[j] = ring[rows[0], j] + ... + ring[rows[size - 1], j]``, in that order (:func:`_box_row`)."""
    if size == 7:
        a, b, c, d, e, f, g = rows[0], rows[1], rows[2], rows[3], rows[4], rows[5], rows[6]
        for j in range(n):
            out[j] = ring[a, j] + ring[b, j] + ring[c, j] + ring[d, j] + ring[e, j] + ring[f, j] + ring[g, j]
        return
    for j in range(n):
        out[j] = ring[rows[0], j]
    for t in range(1, size):
        r = rows[t]
        for j in range(n):
            out[j] += ring[r, j]


@njit(cache=True, error_model="numpy")
def _deviation_row(x, s, c, e, n, half):
    """``e = x - s / c``, the value less its window's mean, where the window holds at least ``half`` values (``c``
    of them), else NaN."""
    for i in range(n):
        e[i] = x[i] - s[i] / c[i] if c[i] >= half else np.nan


@njit(cache=True)
def _deviation_full(x, s, inv, e, n):
    """``e = x - s inv`` (``inv``: 1 / the window's count, NaN where it holds fewer than half its values)."""
    for i in range(n):
        e[i] = x[i] - s[i] * inv[i]


@njit(cache=True)
def _count_row(e, n, lim):
    """How many of ``e`` are numbers, and how many exceed ``lim`` in magnitude."""
    k, big = 0, 0
    for i in range(n):
        k += e[i] == e[i]
        big += abs(e[i]) > lim
    return k, big


@njit(cache=True, error_model="numpy")
def window_deviations(ras, hk, wk, size, holes, dev, work, row_count, lim, cand):
    r"""``dev``: each value of an ``hk x wk`` raster (flat; NaN: none) less the mean of the valid values of its ``size``
    × ``size`` window (NaN with fewer than half of it valid); ``row_count``: each row's numbers of ``dev``;
    ``cand[:nc]`` where :math:`|dev| >` ``lim`` (raster indices, ascending); returns ``nc``.

    Box sums row by row: each row's sums over ``size`` columns (into a ring of ``size`` rows), then the sums of
    ``size`` of those rows: O(size) a pixel in loops LLVM vectorises, every sum in a fixed order (columns, then
    rows, ascending).  ``holes`` False: every value is a number, the counts are the window's area in the
    raster.  ``work``: float64 scratch of :func:`window_scratch` values.
    """
    h = size // 2
    half = (size * size + 1) // 2
    wp = wk + 2 * h
    ring = work[:(size + 1) * wk].reshape((size + 1, wk))  # the last row: zeros (rows beyond the raster)
    ringc = work[(size + 1) * wk:2 * (size + 1) * wk].reshape((size + 1, wk))
    at = 2 * (size + 1) * wk
    p, pc = work[at:at + wp], work[at + wp:at + 2 * wp]
    s, c = work[at + 2 * wp:at + 2 * wp + wk], work[at + 2 * wp + wk:at + 2 * wp + 2 * wk]
    p[:], pc[:], ring[size], ringc[size] = 0.0, 0.0, 0.0, 0.0
    inv = ringc[:size]  # without holes: 1 / the count of a window of r + 1 rows at column j (NaN: below half)
    if not holes:
        for r in range(1, min(size, hk) + 1):
            for j in range(wk):
                a = r * (min(j + h + 1, wk) - max(j - h, 0))
                inv[r - 1, j] = 1.0 / a if a >= half else np.nan
    rows = np.empty(size, np.int64)
    nc = 0
    for ii in range(hk + h):
        if ii < hk:  # row ii's sums over the window's columns, into the ring
            _pad_row(ras[ii * wk:(ii + 1) * wk], p[h:h + wk], pc[h:h + wk], wk, holes)
            _box_row(p, ring[ii % size], wk, size)
            if holes:
                _box_row(pc, ringc[ii % size], wk, size)
        i = ii - h
        if i < 0:
            continue
        for t in range(size):  # row i's window sums: the sums of its rows, ascending
            r = i - h + t
            rows[t] = r % size if 0 <= r < hk else size
        _box_col(ring, rows, s, wk, size)
        if holes:
            _box_col(ringc, rows, c, wk, size)
        e = dev[i * wk:(i + 1) * wk]
        if holes:
            _deviation_row(ras[i * wk:(i + 1) * wk], s, c, e, wk, half)
        else:
            _deviation_full(ras[i * wk:(i + 1) * wk], s, inv[min(i + h + 1, hk) - max(i - h, 0) - 1], e, wk)
        row_count[i], big = _count_row(e, wk, lim)
        if big:
            for j in range(wk):
                if abs(e[j]) > lim:
                    cand[nc] = i * wk + j
                    nc += 1
    return nc


@njit(cache=True)
def window_scratch(width, size):
    """The float64 scratch :func:`window_deviations` needs for rasters up to ``width`` wide."""
    return 2 * (size + 1) * width + 2 * (width + 2 * (size // 2)) + 2 * width


@njit(cache=True)
def sample(e, hk, wk, row_count, d):
    """Every ``step``-th number of the raster ``e`` in raster order (``step``: the fewest that keep at most
    :data:`SCALE_SAMPLE` of them) into ``d``; returns how many."""
    m = 0
    for i in range(hk):
        m += row_count[i]
    if not m:
        return 0
    step = (m + SCALE_SAMPLE - 1) // SCALE_SAMPLE
    n, seen, take = 0, 0, 0  # taken, numbers before this row, the rank of the next one taken
    for i in range(hk):
        row = e[i * wk:(i + 1) * wk]
        if row_count[i] == wk:  # no NaN: the numbers' ranks are their columns
            for j in range(take - seen, wk, step):
                d[n] = row[j]
                n += 1
                take += step
        elif row_count[i]:
            r = seen
            for j in range(wk):
                if row[j] == row[j]:
                    if r == take:
                        d[n] = row[j]
                        n += 1
                        take += step
                    r += 1
        seen += row_count[i]
    return n
