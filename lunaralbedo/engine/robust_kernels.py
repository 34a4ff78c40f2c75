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
def _value_areas(ras, hk, wk, sv):
    """:func:`_summed_areas` of the values of a raster without NaN."""
    w1 = wk + 1
    for j in range(w1):
        sv[j] = 0.0
    for i in range(hk):
        up, at, row = i * w1, (i + 1) * w1, i * wk
        sv[at] = 0.0
        rv = 0.0
        for j in range(wk):
            rv += ras[row + j]
            sv[at + j + 1] = sv[up + j + 1] + rv


@njit(cache=True)
def _summed_areas(ras, hk, wk, sv, sc, counts):
    """Summed-area tables (``(hk + 1) x (wk + 1)``, flat, into ``sv``, ``sc``) of the valid values of an ``hk x wk``
    raster (NaN: none) and (with ``counts``) of their count: the sum over rows ``< i`` and columns ``< j`` at
    ``i (wk + 1) + j``."""
    if not counts:
        _value_areas(ras, hk, wk, sv)
        return
    w1 = wk + 1
    for j in range(w1):
        sv[j] = 0.0
        sc[j] = 0.0
    for i in range(hk):
        up, at, row = i * w1, (i + 1) * w1, i * wk
        sv[at] = 0.0
        sc[at] = 0.0
        rv, rc = 0.0, 0.0
        for j in range(wk):
            x = ras[row + j]
            ok = x == x
            rv += x if ok else 0.0
            rc += 1.0 if ok else 0.0
            sv[at + j + 1] = sv[up + j + 1] + rv
            sc[at + j + 1] = sc[up + j + 1] + rc


@njit(cache=True, nogil=True, error_model="numpy")
def spatial_flags(chunks, run_start, run_pixel, run_image, n_img, width, loga, size, sigmas, tau_min, flag, work):
    r"""Set ``flag`` (bool per observation, False on entry) where the spatial test rejects it (:mod:`lunaralbedo.model.outliers`).

    ``loga``: :math:`\log a` per observation (NaN: unused); ``width``: the block's width in pixels
    (observation pixels are numbered row by row); ``size``: the window's side.  The window's mean
    and median take the valid values of the window, NaN (no test) with fewer than half of it valid.
    ``work``: float64 scratch; returns 0, or the size it needs (then nothing is done).
    """
    n_obs = loga.shape[0]
    rmin = np.full(n_img, 1 << 62)
    rmax = np.full(n_img, -1)
    cmin = np.full(n_img, 1 << 62)
    cmax = np.full(n_img, -1)
    cnt = np.zeros(n_img, np.int64)
    for q in range(run_start.shape[0] - 1):  # each image's used observations and a box around them
        k = run_image[q]
        o0, o1 = run_start[q], run_start[q + 1]
        used = 0
        for o in range(o0, o1):
            used += loga[o] == loga[o]
        if not used:
            continue
        cnt[k] += used
        while loga[o0] != loga[o0]:  # the run's first and last used observations
            o0 += 1
        while loga[o1 - 1] != loga[o1 - 1]:
            o1 -= 1
        p0, p1 = run_pixel[q] + o0 - run_start[q], run_pixel[q] + o1 - 1 - run_start[q]
        r0, r1 = p0 // width, p1 // width
        c0, c1 = (p0 % width, p1 % width) if r0 == r1 else (0, width - 1)  # over a row's end: every column
        rmin[k], rmax[k] = min(rmin[k], r0), max(rmax[k], r1)
        cmin[k], cmax[k] = min(cmin[k], c0), max(cmax[k], c1)
    off = np.zeros(n_img + 1, np.int64)
    most_sat, most_cnt = 0, 0
    for k in range(n_img):
        area = (rmax[k] - rmin[k] + 1) * (cmax[k] - cmin[k] + 1) if cnt[k] else 0
        off[k + 1] = off[k] + area
        most_sat = max(most_sat, (rmax[k] - rmin[k] + 2) * (cmax[k] - cmin[k] + 2) if cnt[k] else 0)
        most_cnt = max(most_cnt, cnt[k])
    a0, a1 = off[n_img], off[n_img] + n_obs
    a2 = a1 + 2 * most_sat
    a3 = a2 + most_cnt
    if work.shape[0] < a3:
        return a3
    raster, e = work[:a0], work[a0:a1]
    sv, sc, d = work[a1:a1 + most_sat], work[a1 + most_sat:a2], work[a2:a3]
    for i in range(a0):
        raster[i] = np.nan
    for q in range(run_start.shape[0] - 1):
        k = run_image[q]
        wk = cmax[k] - cmin[k] + 1
        row, col = run_pixel[q] // width, run_pixel[q] % width
        for o in range(run_start[q], run_start[q + 1]):
            if loga[o] == loga[o]:
                raster[off[k] + (row - rmin[k]) * wk + col - cmin[k]] = loga[o]
            col += 1
            if col == width:
                row, col = row + 1, 0
    h = size // 2
    half = (size * size + 1) // 2
    tau = np.full(n_img, tau_min)
    win = np.empty(size * size)
    for k in range(n_img):
        hk, wk = rmax[k] - rmin[k] + 1, cmax[k] - cmin[k] + 1
        full = cnt[k] == hk * wk  # no hole: a window's count is its area within the raster
        ras = raster[off[k]:off[k + 1]]
        if cnt[k]:
            _summed_areas(ras, hk, wk, sv, sc, not full)
        w1 = wk + 1
        m, nc = 0, 0
        cand = np.empty((cnt[k], 3), np.int64)  # observations whose d may exceed tau / 2 (tau >= tau_min): few
        for q in range(run_start.shape[0] - 1):  # d = log a - the window's mean, the image's observations in run order
            if run_image[q] != k:
                continue
            i, j = run_pixel[q] // width - rmin[k], run_pixel[q] % width - cmin[k]
            for o in range(run_start[q], run_start[q + 1]):
                if o > run_start[q]:
                    j += 1
                    if j + cmin[k] == width:
                        i, j = i + 1, -cmin[k]
                e[o] = np.nan
                if loga[o] != loga[o]:
                    continue
                i0, i1, j0, j1 = max(i - h, 0), min(i + h + 1, hk), max(j - h, 0), min(j + h + 1, wk)
                a, b, c_, d_ = i1 * w1 + j1, i0 * w1 + j1, i1 * w1 + j0, i0 * w1 + j0
                c = np.float64((i1 - i0) * (j1 - j0)) if full else sc[a] - sc[b] - sc[c_] + sc[d_]
                if c >= half:
                    ev = loga[o] - (sv[a] - sv[b] - sv[c_] + sv[d_]) / c
                    e[o] = ev
                    d[m] = ev
                    m += 1
                    if abs(ev) > tau_min / 2:
                        cand[nc, 0], cand[nc, 1], cand[nc, 2] = o, i, j
                        nc += 1
        if not cnt[k]:
            continue
        s = _mad_sigma(d, m)
        tau[k] = max(tau_min, sigmas * s) if m else tau_min
        for x_ in range(nc):  # the window's median where the mean says it may matter
            o, i, j = cand[x_, 0], cand[x_, 1], cand[x_, 2]
            if not abs(e[o]) > tau[k] / 2:
                continue
            c = 0
            for ii in range(max(i - h, 0), min(i + h + 1, hk)):
                for jj in range(max(j - h, 0), min(j + h + 1, wk)):
                    x = ras[ii * wk + jj]
                    if x == x:
                        win[c] = x
                        c += 1
            e[o] = loga[o] - np.median(win[:c]) if 2 * c > size * size else np.nan
    for ch in range(chunks.shape[0] - 1):  # the few observations far out: against the other images' mean e
        for q in range(chunks[ch], chunks[ch + 1]):
            t = tau[run_image[q]]
            for o in range(run_start[q], run_start[q + 1]):
                ev = e[o]
                if not abs(ev) > t:
                    continue
                p = run_pixel[q] + o - run_start[q]
                se, others = 0.0, 0.0
                for r in range(chunks[ch], chunks[ch + 1]):  # a pixel's observations are in its chunk's runs
                    if r != q and run_pixel[r] <= p < run_pixel[r] + run_start[r + 1] - run_start[r]:
                        x = e[run_start[r] + p - run_pixel[r]]
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


@njit(cache=True, nogil=True)
def finish(run_start, run_image, base, used, flag, keep, m, w_new, counts):
    """The effective weights ``w_new = 0`` (rejected) or ``m w`` (float32; ``m`` empty: 1), and per local image
    (``counts``, 3 rows) the used, rejected and down-weighted (sum of 1 - m) observations, summed in run order."""
    ones = m.shape[0] == 0
    for q in range(run_start.shape[0] - 1):
        k = run_image[q]
        for o in range(run_start[q], run_start[q + 1]):
            mo = 1.0 if ones else m[o]
            w_new[o] = np.float32(0.0) if flag[o] else np.float32(base[o] * mo)
            counts[0, k] += used[o]
            counts[1, k] += used[o] and flag[o]
            counts[2, k] += 1.0 - mo if keep[o] else 0.0


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
