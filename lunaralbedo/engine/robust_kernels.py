r"""The reweight pass's spatial consistency test (:mod:`lunaralbedo.model.outliers`) in numba, over a block's runs.

:func:`spatial_flags` does for one block of chunk-major runs (:mod:`.runs`) what
:func:`lunaralbedo.model.outliers.neighbourhood_deviation` and
:func:`~lunaralbedo.model.outliers.spatial_outliers` do for NumPy rasters, without sorting the
observations by image: each image's observations are written into a raster of its own
bounding box straight from its runs (a run is contiguous there), each value less the mean
of the valid values of its :data:`~lunaralbedo.model.outliers.WINDOW` × WINDOW window
(:func:`.window_kernels.window_deviations`: box sums row by row, the box filters of the NumPy
form) into a raster of deviations :math:`d = \log a - \operatorname{mean}_N \log a`, the
image's threshold :math:`\tau_k` from the median absolute deviation of at most
:data:`~.window_kernels.SCALE_SAMPLE` of them, and the window median only where
:math:`|d| > \tau_k / 2` (and there only where the observation may lie beyond :math:`\tau_k`, or
where another image's far observation needs its deviation: :func:`_beyond_median`).  Then each
observation far out is compared with the mean :math:`e` of the other images at its pixel.
The other kernels give the pass's log albedo (a logarithm LLVM vectorises,
:mod:`lunaralbedo.model.vlog`), counts and weights, and the image-major order of the kept
observations, all from the runs.  The rasters of
:math:`\log a` and of :math:`d` are float32 (half the memory traffic of the pass's two
biggest arrays; their rounding, :math:`6 \cdot 10^{-8}` relative, is far below the test's
thresholds of :math:`\tau_k / 2 \ge 0.075`), every sum, mean, median and spread float64, every
sum in a fixed order (fixed by the data: the same for any number of workers);
``cache=True``, no fastmath.  Loops over a run or a row are functions of their own over
slices: LLVM vectorises those.
"""
from __future__ import annotations

import threading

import numpy as np
from numba import njit

from ..model import outliers, vlog
from .window_kernels import SCALE_SAMPLE, mad_sigma, median, sample, window_deviations, window_scratch


#: The float32 normal range: the ratio :math:`a` is clamped into it (beyond, the inputs are absurd), so that
#: :math:`\log a` is a number wherever the observation is used.
_A_MIN, _A_MAX = np.float32(1.17549435e-38), np.float32(3.4028235e38)


@njit(cache=True, error_model="numpy")
def _log_run(image, r, w, h, t, loga, used, n):
    r"""One run's single-image :math:`\log a = \log(\max(I - H_k, 10^{-6}) / (T_k R))` (float32, NaN where not used)
    and whether each observation is used (:func:`usable`; :math:`T_k R > 0` from the signs: the float64 product of
    two float32 is exact); returns how many :math:`\log a` are numbers.  Float32 arithmetic, the logarithm
    :func:`lunaralbedo.model.vlog.logf` (within 1 float32 ulp): ~2e-7 relative, far below the test's thresholds; no
    branch: LLVM vectorises the loop eight values at a time."""
    n_ok = 0
    for i in range(n):
        ri = r[i]
        u = (w[i] > 0) & (((t > 0) & (ri > 0)) | ((t < 0) & (ri < 0)))
        s = np.float32(image[i]) - h
        a = (np.float32(1e-6) if s < np.float32(1e-6) else s) / (t * ri)  # max(s, 1e-6), NaN kept
        a = _A_MIN if a < _A_MIN else (_A_MAX if a > _A_MAX else a)
        v = vlog.logf(a) if u else np.float32(np.nan)
        used[i] = u
        loga[i] = v
        n_ok += v == v
    return n_ok


@njit(cache=True)
def _usable_run(r, w, t, used, n):
    """:func:`usable` of one run (its own loop: vectorised)."""
    for i in range(n):
        used[i] = (w[i] > 0) & (t * np.float64(r[i]) > 0)


@njit(cache=True, nogil=True)
def usable(run_start, run_image, texp, r, w, used):
    """Whether each observation is used by the reweight pass: eq. 1's weight ``w`` above 0 and :math:`T_k R > 0`."""
    for q in range(run_start.shape[0] - 1):
        a, b = run_start[q], run_start[q + 1]
        _usable_run(r[a:b], w[a:b], np.float64(texp[run_image[q]]), used[a:b], b - a)


@njit(cache=True)
def _window_values(ras, hk, wk, p, h, win):
    """The numbers of the window of half-side ``h`` around raster index ``p`` (an ``hk x wk`` raster) into ``win``;
    returns how many."""
    i, j = p // wk, p % wk
    n = 0
    for ii in range(max(i - h, 0), min(i + h + 1, hk)):
        for jj in range(max(j - h, 0), min(j + h + 1, wk)):
            x = ras[ii * wk + jj]
            if x == x:
                win[n] = x
                n += 1
    return n


@njit(cache=True)
def _beyond_median(x, win, n, t):
    r"""Whether :math:`|x - \operatorname{med}| > t` for the median of ``win[:n]`` (``n`` odd), without it: ``x - v``
    falls as ``v`` rises (IEEE subtraction is monotonic), so the median is ``t`` below ``x`` when more than half
    of the values are, and above likewise."""
    below, above = 0, 0
    for i in range(n):
        below += (x - win[i]) > t
        above += (win[i] - x) > t
    return below > n // 2 or above > n // 2


@njit(cache=True, nogil=True, error_model="numpy")
def spatial_flags(chunks, run_start, run_pixel, run_image, n_img, width, image, haze, texp, r, w, size, sigmas, tau_min,
                  used, flag, work):
    r"""Set ``used`` (:func:`usable`) and ``flag`` (False on entry) where the spatial test rejects an observation
    (:mod:`lunaralbedo.model.outliers`).

    ``image``, ``r``, ``w``: each observation's value, reflectance R and eq. 1's weight; ``haze``, ``texp``: each
    local image's :math:`H_k`, :math:`T_k`.  Each observation's :math:`\log a` (:func:`_log_run`) goes straight
    into its image's raster (float32, as the deviations' raster).  ``width``: the block's width in
    pixels (observation pixels are numbered row by row); ``size``: the window's side.  The window's mean and median
    take the valid values of the window, NaN (no test) with fewer than half of it valid.  ``work``: float64
    scratch; returns 0, or the size it needs (then nothing is done).
    """
    n_runs = run_start.shape[0] - 1
    rmin = np.full(n_img, 1 << 62)
    rmax = np.full(n_img, -1)
    cmin = np.full(n_img, 1 << 62)
    cmax = np.full(n_img, -1)
    cnt = np.zeros(n_img, np.int64)  # observations with a log albedo
    tot = np.zeros(n_img, np.int64)  # all
    for q in range(n_runs):  # each image's observations and a box around them
        k = run_image[q]
        o0, o1 = run_start[q], run_start[q + 1]
        tot[k] += o1 - o0
        p0, p1 = run_pixel[q], run_pixel[q] + o1 - 1 - o0
        r0, r1 = p0 // width, p1 // width
        c0, c1 = (p0 % width, p1 % width) if r0 == r1 else (0, width - 1)  # over a row's end: every column
        rmin[k], rmax[k] = min(rmin[k], r0), max(rmax[k], r1)
        cmin[k], cmax[k] = min(cmin[k], c0), max(cmax[k], c1)
    off = np.zeros(n_img + 1, np.int64)
    widest, tallest, most = 1, 1, 1
    for k in range(n_img):
        area = (rmax[k] - rmin[k] + 1) * (cmax[k] - cmin[k] + 1) if tot[k] else 0
        off[k + 1] = off[k] + area
        widest = max(widest, cmax[k] - cmin[k] + 1 if tot[k] else 1)
        tallest = max(tallest, rmax[k] - rmin[k] + 1 if tot[k] else 1)
        most = max(most, tot[k])
    a0 = off[n_img]
    ws = window_scratch(widest, size)
    need = a0 + ws + SCALE_SAMPLE
    if work.shape[0] < need:
        return need
    w32 = work[:a0].view(np.float32)
    raster, dev, wwork, d = w32[:a0], w32[a0:2 * a0], work[a0:a0 + ws], work[a0 + ws:need]
    rbase = np.empty(n_runs, np.int64)  # each run's first observation in its image's raster (a run is contiguous there)
    for q in range(n_runs):
        k = run_image[q]
        rbase[q] = off[k] + (run_pixel[q] // width - rmin[k]) * (cmax[k] - cmin[k] + 1) + run_pixel[q] % width - cmin[k]
    tau = np.full(n_img, tau_min)
    win = np.empty(size * size)
    cand = np.empty(most, np.int64)  # deviations that may exceed tau / 2: few
    far, n_far = np.empty(a0, np.int64), 0  # those beyond tau (all the test may reject), in the rasters
    later, n_later = np.empty(a0, np.int64), 0  # those within, whose window median is not taken yet (ascending)
    row_count = np.empty(tallest, np.int64)
    h = size // 2
    for k in range(n_img):
        if tot[k] < off[k + 1] - off[k]:  # pixels of the box no observation covers
            raster[off[k]:off[k + 1]] = np.nan
    for q in range(n_runs):  # the log albedo into the rasters
        k, a, b = run_image[q], run_start[q], run_start[q + 1]
        cnt[k] += _log_run(image[a:b], r[a:b], w[a:b], np.float32(haze[k]), np.float32(texp[k]),
                           raster[rbase[q]:rbase[q] + b - a], used[a:b], b - a)
    for k in range(n_img):
        if not cnt[k]:
            dev[off[k]:off[k + 1]] = np.nan
            continue
        hk, wk = rmax[k] - rmin[k] + 1, cmax[k] - cmin[k] + 1
        ras, e = raster[off[k]:off[k + 1]], dev[off[k]:off[k + 1]]
        nc = window_deviations(ras, hk, wk, size, cnt[k] < hk * wk, e, wwork, row_count, tau_min / 2, cand)
        m = sample(e, hk, wk, row_count, d)
        tau[k] = max(tau_min, sigmas * mad_sigma(d, m)) if m else tau_min
        for x_ in range(nc):  # the window's median where the mean says it may matter
            p = cand[x_]
            if not abs(e[p]) > tau[k] / 2:
                continue
            n = _window_values(ras, hk, wk, p, h, win)
            if 2 * n <= size * size:
                e[p] = np.nan
                continue
            if n & 1 and not _beyond_median(np.float64(ras[p]), win, n, tau[k]):  # not far out: its median only
                later[n_later] = off[k] + p                                   # if another image's far one needs it
                n_later += 1
                continue
            e[p] = ras[p] - median(win, n)
            if abs(e[p]) > tau[k]:
                far[n_far] = off[k] + p
                n_far += 1
    by_image = np.argsort(run_image, kind="mergesort")  # each image's runs, ascending in its raster
    first = np.searchsorted(run_image[by_image], np.arange(n_img + 1))
    at = rbase[by_image]
    for x_ in range(n_far):  # the few observations far out: against the other images' mean e
        gp = far[x_]
        k = np.searchsorted(off, gp, side="right") - 1
        q = by_image[first[k] + np.searchsorted(at[first[k]:first[k + 1]], gp, side="right") - 1]  # the run holding it
        o, t, ev = run_start[q] + gp - rbase[q], tau[k], dev[gp]
        ch = np.searchsorted(chunks, q, side="right") - 1
        p = run_pixel[q] + o - run_start[q]
        se, others = 0.0, 0.0
        for qq in range(chunks[ch], chunks[ch + 1]):  # a pixel's observations are in its chunk's runs
            if qq != q and run_pixel[qq] <= p < run_pixel[qq] + run_start[qq + 1] - run_start[qq]:
                g = rbase[qq] + p - run_pixel[qq]
                x = dev[g]
                at_l = np.searchsorted(later[:n_later], g)
                if at_l < n_later and later[at_l] == g:  # its window's median now
                    k2 = run_image[qq]
                    n = _window_values(raster[off[k2]:off[k2 + 1]], rmax[k2] - rmin[k2] + 1, cmax[k2] - cmin[k2] + 1,
                                       g - off[k2], h, win)
                    x = raster[g] - median(win, n)
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


def spatial_test(arrays: dict, width: int, haze, texp, r, w, used: np.ndarray) -> np.ndarray:
    r"""The observations of a block (chunk-major runs) the spatial test rejects (bool), and ``used`` (:func:`usable`):
    ``haze``, ``texp`` each local image's :math:`H_k`, :math:`T_k`; ``r``, ``w`` each observation's R and eq. 1's
    weight (:func:`spatial_flags`)."""
    n = len(used)
    flag = np.zeros(n, bool)
    args = (np.asarray(arrays["chunks"], np.int64), np.asarray(arrays["run_start"], np.int64), np.asarray(arrays["run_pixel"], np.int64),
            np.asarray(arrays["run_image"], np.int64), len(arrays["index"]), width, arrays["image"], haze, texp, r, w,
            outliers.WINDOW, outliers.SIGMAS, outliers.TAU_MIN, used, flag)
    need = spatial_flags(*args, workspace("spatial", 3 * n))
    if need:
        spatial_flags(*args, workspace("spatial", need))
    return flag
