r"""The reweight pass's spatial consistency test (:mod:`lunaralbedo.model.outliers`) in numba, over a block's runs.

:func:`spatial_flags` does for one block of chunk-major runs (:mod:`.runs`) what
:func:`lunaralbedo.model.outliers.neighbourhood_deviation` and
:func:`~lunaralbedo.model.outliers.spatial_outliers` do for NumPy rasters, without sorting the
observations by image: each image's observations are written into a raster of its own
bounding box straight from its runs, the mean of every :data:`~lunaralbedo.model.outliers.WINDOW`
× WINDOW window of valid values comes from summed-area tables (O(1) a pixel; the box
filters of the NumPy form), the image's threshold :math:`\tau_k` from the median absolute
deviation of :math:`d = \log a - \operatorname{mean}_N \log a` (numba's ``np.median``, of at most
:data:`SCALE_SAMPLE` values), and the window median only where :math:`|d| > \tau_k / 2`.  Then each
observation far out is compared with the mean :math:`e` of the other images at its pixel.  The
other kernels give the pass's log albedo, counts and weights, and the image-major order of the
kept observations, all from the runs.  Float64 throughout, every sum in the
order of the runs (fixed by the data: the same for any number of workers); ``cache=True``,
no fastmath.
"""
from __future__ import annotations

import threading

import numpy as np
from numba import njit

from ..model import outliers, vlog


@njit(cache=True, error_model="numpy")
def _log_run(image, r, w, h, t, loga, used, n):
    """:func:`log_albedo` of one run (its own loop over slices, without branches: LLVM vectorises it)."""
    for i in range(n):
        s = np.float64(image[i]) - h
        x = t * np.float64(r[i])
        u = (w[i] > 0) & (x > 0)
        lg = vlog.log((1e-6 if s < 1e-6 else s) / x)  # max(s, 1e-6), NaN kept
        used[i] = u
        loga[i] = lg if u else np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def log_albedo(run_start, run_image, image, haze, texp, r, w, loga, used):
    r"""Per observation the single-image :math:`\log a = \log(\max(I - H_k, 10^{-6}) / (T_k R))` (float64) and
    whether it is used (eq. 1's weight ``w`` above 0 and :math:`TR > 0`; ``loga`` NaN where not).

    The logarithm is :func:`lunaralbedo.model.vlog.log` (within 1 ulp of libm's; vectorised)."""
    for q in range(run_start.shape[0] - 1):
        k = run_image[q]
        a, b = run_start[q], run_start[q + 1]
        _log_run(image[a:b], r[a:b], w[a:b], np.float64(haze[k]), np.float64(texp[k]), loga[a:b], used[a:b], b - a)


#: Most values the spread of an image's :math:`d` is taken from, evenly spaced in the runs' order (the MAD's
#: relative standard error is then ~1.3 % for Gaussian values): two medians of every observation were a third
#: of the pass.
SCALE_SAMPLE = 1 << 13


@njit(cache=True)
def _mad_sigma(x, n):
    """1.4826 × the median absolute deviation of ``x[:n]`` (NaN for none): :func:`lunaralbedo.model.outliers.robust_sigma`,
    of at most :data:`SCALE_SAMPLE` of them."""
    if n == 0:
        return np.nan
    step = (n + SCALE_SAMPLE - 1) // SCALE_SAMPLE
    v = x[:n:step].copy()
    n = v.shape[0]
    med = np.median(v)
    dev = np.empty(n)
    for i in range(n):
        dev[i] = abs(v[i] - med)
    return 1.4826 * np.median(dev)


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
    p, pc, s, c = work[at:at + wp], work[at + wp:at + 2 * wp], work[at + 2 * wp:at + 2 * wp + wk], work[at + 2 * wp + wk:at + 2 * wp + 2 * wk]
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
def _sample(e, hk, wk, row_count, d):
    """Every ``step``-th number of the raster ``e`` in raster order (``step``: the fewest that keep at most
    :data:`SCALE_SAMPLE` of them) into ``d``; returns how many."""
    m = 0
    for i in range(hk):
        m += row_count[i]
    if not m:
        return 0
    step = (m + SCALE_SAMPLE - 1) // SCALE_SAMPLE
    n, seen = 0, 0  # taken, numbers before this row
    for i in range(hk):
        row = e[i * wk:(i + 1) * wk]
        if row_count[i] == wk:  # no NaN: the numbers' ranks are their columns
            for j in range((step - seen % step) % step, wk, step):
                d[n] = row[j]
                n += 1
        elif row_count[i]:
            r = seen
            for j in range(wk):
                if row[j] == row[j]:
                    if r % step == 0:
                        d[n] = row[j]
                        n += 1
                    r += 1
        seen += row_count[i]
    return n


@njit(cache=True)
def _count_far(e, t, n):
    """How many of ``e`` (NaN: none) exceed ``t`` in magnitude."""
    k = 0
    for i in range(n):
        k += abs(e[i]) > t
    return k


@njit(cache=True)
def _count_valid(x, n):
    """How many of ``x`` are numbers."""
    k = 0
    for i in range(n):
        k += x[i] == x[i]
    return k


@njit(cache=True)
def _copy(x, y, n):
    """``y = x``."""
    for i in range(n):
        y[i] = x[i]


@njit(cache=True, nogil=True, error_model="numpy")
def spatial_flags(chunks, run_start, run_pixel, run_image, n_img, width, loga, size, sigmas, tau_min, flag, work):
    r"""Set ``flag`` (bool per observation, False on entry) where the spatial test rejects it (:mod:`lunaralbedo.model.outliers`).

    ``loga``: :math:`\log a` per observation (NaN: unused); ``width``: the block's width in pixels
    (observation pixels are numbered row by row); ``size``: the window's side.  The window's mean
    and median take the valid values of the window, NaN (no test) with fewer than half of it valid.
    ``work``: float64 scratch; returns 0, or the size it needs (then nothing is done).
    """
    n_runs = run_start.shape[0] - 1
    rmin = np.full(n_img, 1 << 62)
    rmax = np.full(n_img, -1)
    cmin = np.full(n_img, 1 << 62)
    cmax = np.full(n_img, -1)
    cnt = np.zeros(n_img, np.int64)  # used observations
    tot = np.zeros(n_img, np.int64)  # all
    for q in range(n_runs):  # each image's observations and a box around them
        k = run_image[q]
        o0, o1 = run_start[q], run_start[q + 1]
        cnt[k] += _count_valid(loga[o0:o1], o1 - o0)
        tot[k] += o1 - o0
        p0, p1 = run_pixel[q], run_pixel[q] + o1 - 1 - o0
        r0, r1 = p0 // width, p1 // width
        c0, c1 = (p0 % width, p1 % width) if r0 == r1 else (0, width - 1)  # over a row's end: every column
        rmin[k], rmax[k] = min(rmin[k], r0), max(rmax[k], r1)
        cmin[k], cmax[k] = min(cmin[k], c0), max(cmax[k], c1)
    off = np.zeros(n_img + 1, np.int64)
    widest, tallest, most_cnt = 1, 1, 0
    for k in range(n_img):
        area = (rmax[k] - rmin[k] + 1) * (cmax[k] - cmin[k] + 1) if tot[k] else 0
        off[k + 1] = off[k] + area
        widest = max(widest, cmax[k] - cmin[k] + 1 if tot[k] else 1)
        tallest = max(tallest, rmax[k] - rmin[k] + 1 if tot[k] else 1)
        most_cnt = max(most_cnt, cnt[k])
    a0 = off[n_img]
    ws = window_scratch(widest, size)
    need = 2 * a0 + ws + SCALE_SAMPLE
    if work.shape[0] < need:
        return need
    raster, dev, wwork, d = work[:a0], work[a0:2 * a0], work[2 * a0:2 * a0 + ws], work[2 * a0 + ws:need]
    rbase = np.empty(n_runs, np.int64)  # each run's first observation in its image's raster (a run is contiguous there)
    for q in range(n_runs):
        k = run_image[q]
        rbase[q] = off[k] + (run_pixel[q] // width - rmin[k]) * (cmax[k] - cmin[k] + 1) + run_pixel[q] % width - cmin[k]
    for k in range(n_img):
        if tot[k] < off[k + 1] - off[k]:  # pixels of the box no observation covers
            raster[off[k]:off[k + 1]] = np.nan
        if not cnt[k]:
            dev[off[k]:off[k + 1]] = np.nan
    for q in range(n_runs):
        n = run_start[q + 1] - run_start[q]
        _copy(loga[run_start[q]:run_start[q + 1]], raster[rbase[q]:rbase[q] + n], n)
    tau = np.full(n_img, tau_min)
    win = np.empty(size * size)
    cand = np.empty(max(most_cnt, 1), np.int64)  # deviations that may exceed tau / 2: few
    row_count = np.empty(tallest, np.int64)
    h = size // 2
    for k in range(n_img):
        if not cnt[k]:
            continue
        hk, wk = rmax[k] - rmin[k] + 1, cmax[k] - cmin[k] + 1
        ras, e = raster[off[k]:off[k + 1]], dev[off[k]:off[k + 1]]
        nc = window_deviations(ras, hk, wk, size, cnt[k] < hk * wk, e, wwork, row_count, tau_min / 2, cand)
        m = _sample(e, hk, wk, row_count, d)
        tau[k] = max(tau_min, sigmas * _mad_sigma(d, m)) if m else tau_min
        for x_ in range(nc):  # the window's median where the mean says it may matter
            p = cand[x_]
            if not abs(e[p]) > tau[k] / 2:
                continue
            i, j = p // wk, p % wk
            n = 0
            for ii in range(max(i - h, 0), min(i + h + 1, hk)):
                for jj in range(max(j - h, 0), min(j + h + 1, wk)):
                    x = ras[ii * wk + jj]
                    if x == x:
                        win[n] = x
                        n += 1
            e[p] = ras[p] - np.median(win[:n]) if 2 * n > size * size else np.nan
    for ch in range(chunks.shape[0] - 1):  # the few observations far out: against the other images' mean e
        for q in range(chunks[ch], chunks[ch + 1]):
            t, n = tau[run_image[q]], run_start[q + 1] - run_start[q]
            if not _count_far(dev[rbase[q]:rbase[q] + n], t, n):
                continue
            for o in range(run_start[q], run_start[q + 1]):
                ev = dev[rbase[q] + o - run_start[q]]
                if not abs(ev) > t:
                    continue
                p = run_pixel[q] + o - run_start[q]
                se, others = 0.0, 0.0
                for r in range(chunks[ch], chunks[ch + 1]):  # a pixel's observations are in its chunk's runs
                    if r != q and run_pixel[r] <= p < run_pixel[r] + run_start[r + 1] - run_start[r]:
                        x = dev[rbase[r] + p - run_pixel[r]]
                        if x == x:
                            se += x
                            others += 1.0
                flag[o] = others < 1 or abs(ev - se / others) > t
    return 0


@njit(cache=True, nogil=True)
def most_runs_on_a_pixel(chunks, run_start, run_pixel):
    """The most runs (hence images) that meet at one pixel of a block: a bound of the images on a pixel, from the
    runs alone (each chunk's runs: the most at any run's first pixel)."""
    most = 0
    for ch in range(chunks.shape[0] - 1):
        for a in range(chunks[ch], chunks[ch + 1]):
            n = 0
            for b in range(chunks[ch], chunks[ch + 1]):
                n += run_pixel[b] <= run_pixel[a] < run_pixel[b] + run_start[b + 1] - run_start[b]
            most = max(most, n)
    return most


@njit(cache=True, nogil=True)
def kept_on_pixel(run_start, run_pixel, keep, npix, least, many):
    """``many``: the kept observations (``keep``) whose pixel has at least ``least`` kept ones (pixels
    ``0..npix-1``); returns how many."""
    n = np.zeros(npix, np.int32)
    for q in range(run_start.shape[0] - 1):
        p0 = run_pixel[q] - run_start[q]
        for o in range(run_start[q], run_start[q + 1]):
            n[p0 + o] += keep[o]
    total = 0
    for q in range(run_start.shape[0] - 1):
        p0 = run_pixel[q] - run_start[q]
        for o in range(run_start[q], run_start[q + 1]):
            many[o] = keep[o] and n[p0 + o] >= least
            total += many[o]
    return total


@njit(cache=True)
def _finish_run(base, used, flag, w_new, n):
    """:func:`finish` of one run without robust loss factors: the weights and the used and rejected counts."""
    nu, nr = 0, 0
    for i in range(n):
        w_new[i] = np.float32(0.0) if flag[i] else base[i]
        nu += used[i]
        nr += used[i] & flag[i]
    return nu, nr


@njit(cache=True, nogil=True)
def finish(run_start, run_image, base, used, flag, keep, m, w_new, counts):
    """The effective weights ``w_new = 0`` (rejected) or ``m w`` (float32; ``m`` empty: 1), and per local image
    (``counts``, 3 rows) the used, rejected and down-weighted (sum of 1 - m) observations, summed in run order."""
    ones = m.shape[0] == 0
    for q in range(run_start.shape[0] - 1):
        k, a, b = run_image[q], run_start[q], run_start[q + 1]
        if ones:  # counts summed per run (integers: exact in any order), in a loop LLVM vectorises
            nu, nr = _finish_run(base[a:b], used[a:b], flag[a:b], w_new[a:b], b - a)
            counts[0, k] += nu
            counts[1, k] += nr
            continue
        for o in range(a, b):
            w_new[o] = np.float32(0.0) if flag[o] else np.float32(base[o] * m[o])
            counts[0, k] += used[o]
            counts[1, k] += used[o] and flag[o]
            counts[2, k] += 1.0 - m[o] if keep[o] else 0.0


@njit(cache=True, nogil=True)
def image_major(run_start, run_pixel, run_image, n_img, sel):
    """The observations with ``sel`` image by image (a stable sort by image, from the runs: no sort), their pixels
    and each image's first position (``n_img + 1``)."""
    start = np.zeros(n_img + 1, np.int64)
    for q in range(run_start.shape[0] - 1):
        for o in range(run_start[q], run_start[q + 1]):
            start[run_image[q] + 1] += sel[o]
    for k in range(n_img):
        start[k + 1] += start[k]
    at = start[:-1].copy()
    order, pix = np.empty(start[n_img], np.int64), np.empty(start[n_img], np.int64)
    for q in range(run_start.shape[0] - 1):
        k = run_image[q]
        for o in range(run_start[q], run_start[q + 1]):
            if sel[o]:
                order[at[k]] = o
                pix[at[k]] = run_pixel[q] + o - run_start[q]
                at[k] += 1
    return order, pix, start


#: Float64 scratch of the reweight kernels per thread, kept between blocks for one reweight pass (:func:`release`):
#: memory fresh from the system costs a page fault per 4 kB, which made this pass's arrays cost more than its work.
_WORK: dict = {}
_LOCK = threading.Lock()


def workspace(name: str, n: int) -> np.ndarray:
    """This thread's float64 scratch ``name``: at least ``n`` values."""
    key = (threading.get_ident(), name)
    with _LOCK:
        buf = _WORK.get(key)
    if buf is None or len(buf) < n:
        buf = np.empty(n + n // 4 + 1024)
        with _LOCK:
            _WORK[key] = buf
    return buf


def release() -> None:
    """Drop every thread's scratch (the end of a reweight pass)."""
    with _LOCK:
        _WORK.clear()


def spatial_test(arrays: dict, loga: np.ndarray, width: int) -> np.ndarray:
    r"""The observations of a block (chunk-major runs) the spatial test rejects (bool), from their :math:`\log a`."""
    flag = np.zeros(len(loga), bool)
    args = (np.asarray(arrays["chunks"], np.int64), np.asarray(arrays["run_start"], np.int64), np.asarray(arrays["run_pixel"], np.int64),
            np.asarray(arrays["run_image"], np.int64), len(arrays["index"]), width, loga, outliers.WINDOW,
            outliers.SIGMAS, outliers.TAU_MIN, flag)
    need = spatial_flags(*args, workspace("spatial", 3 * len(loga)))
    if need:
        spatial_flags(*args, workspace("spatial", need))
    return flag
