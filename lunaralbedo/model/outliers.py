r"""Outlier rejection for eq. 1's cost: a spatial consistency test on every observation, and a robust loss (IRLS).

The cost of the PhotometryTK manual (eq. 1; Nefian et al., "Lunar albedo reconstruction")
is a weighted least-squares sum :math:`Q = \sum w^k_{ij} (I^k_{ij} - A_{ij} T^k R^k_{ij})^2`.
One hot pixel or dropout row then moves the albedo of its pixel by its full error where two
images overlap, and the exposure and phase sums of its image with it.  Two tests give each
observation a factor :math:`m^k_{ij} \in [0, 1]` on its weight (iteratively reweighted least
squares: the albedo, exposure, phase and error updates all use :math:`m\,w`):

**Spatial consistency** (every pixel; what a per-residual loss cannot do where only two
images overlap, since there neither can out-vote the other).  Image k's single-image albedo
:math:`a^k_{ij} = (I^k_{ij} - H_k)/(T^k R^k_{ij})` is compared with the median of its own
neighbourhood (:data:`WINDOW` × :data:`WINDOW` pixels of the same image, :func:`nan_median_filter`):

.. math:: e^k_{ij} = \log a^k_{ij} - \log \operatorname{med}_{N(ij)} a^k.

Texture of the albedo and shading errors of the DEM enter :math:`e` alike in every image;
a defect of one image enters only its own.  An observation is rejected (:math:`m = 0`) when
:math:`|e| > \tau_k` and, where other images see the pixel, :math:`|e - \bar e_{\rm others}| > \tau_k`
(the others do not show the same feature); :math:`\tau_k` is :data:`SIGMAS` robust standard
deviations of image k's :math:`e` (1.4826 × the median absolute deviation, over the tile), at least
:data:`TAU_MIN`.  Where an image is alone, a feature of a few pixels that stands out by more than
:math:`\tau_k` cannot be told from a defect and is rejected: the ``outliers/`` map shows it.

**Robust loss** (where three or more images remain after the spatial test: they can out-vote
one).  With the residual :math:`r = I - H - A T R` of the current albedo and its image's robust
scale :math:`s_k` (1.4826 MAD), :math:`u = r/s_k` and threshold :math:`k` (``ROBUST_THRESHOLD``),
the IRLS weights of the M-estimators are (ASP ``sfs`` offers the Cauchy loss; Huber 1964):

* Cauchy, :math:`\rho(u) = \tfrac{k^2}{2}\log(1 + u^2/k^2)`: :math:`m = 1/(1 + u^2/k^2)`;
* Huber: :math:`m = \min(1, k/|u|)`;
* none: :math:`m = 1`.

Pure NumPy / SciPy (the loss's scalar formula compiled by numba, for the reweight kernels too), no I/O.
"""
from __future__ import annotations

import warnings

import numpy as np
from numba import njit
from scipy import ndimage

#: Side of the neighbourhood of the spatial test, pixels.
WINDOW = 7
#: Rejection threshold of the spatial test in robust standard deviations of an image's :math:`e`.
SIGMAS = 6.0
#: Least threshold of the spatial test (log ratio: 0.15 is 16 %).
TAU_MIN = 0.15
#: The robust losses by name (``ROBUST_LOSS``).
LOSSES = ("cauchy", "huber", "none")
#: Fewest observations of an image (in a tile) for its own robust scale; below, the tile's pooled one.
MIN_SCALE_OBS = 50
#: Fewest images on a pixel where the robust loss applies.
MIN_IMAGES_FOR_LOSS = 3


def nan_median_filter(x: np.ndarray, size: int = WINDOW) -> np.ndarray:
    """Median over ``size`` × ``size`` windows ignoring NaN (float64); NaN where fewer than half the window is valid.

    Two rank filters: NaN (and outside the array) as +inf gives the median rank from above,
    as -inf from below; they are finite only with at least half of the window valid, and
    their mean is the median of the valid values (exact for an odd count, the mean of the two
    middle values' neighbours otherwise).
    """
    x = np.asarray(x, np.float64)
    bad = ~np.isfinite(x)
    hi = ndimage.median_filter(np.where(bad, np.inf, x), size=size, mode="constant", cval=np.inf)
    lo = ndimage.median_filter(np.where(bad, -np.inf, x), size=size, mode="constant", cval=-np.inf)
    with np.errstate(invalid="ignore"):
        out = 0.5 * (hi + lo)
    out[~(np.isfinite(hi) & np.isfinite(lo))] = np.nan
    return out


def neighbourhood_deviation(raster: np.ndarray, rows: np.ndarray, cols: np.ndarray, size: int = WINDOW):
    r""":math:`e` at ``(rows, cols)`` of one image's ``raster`` of :math:`\log a` (NaN: no observation), and :math:`\tau`.

    The median of every window is what the test needs, but it is the expensive part; so
    first the mean of each window's valid values (two box filters, O(1) a pixel) gives
    :math:`d = \log a - \operatorname{mean}_N \log a` everywhere and the image's threshold
    :math:`\tau` (from :math:`d`'s robust spread); only where :math:`|d| > \tau/2` -- a defect pulls
    the mean of its window by less than half its own deviation while it covers less than
    half the window -- the median of the window is taken (:func:`nan_median_filter`'s rule:
    NaN with fewer than half the window valid).  Elsewhere :math:`e = d`, below :math:`\tau/2`.
    """
    x = np.asarray(raster, np.float64)
    valid = np.isfinite(x)
    box = ndimage.uniform_filter(np.where(valid, x, 0.0), size, mode="constant")
    frac = ndimage.uniform_filter(valid.astype(np.float64), size, mode="constant")
    v = x[rows, cols]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(frac * size * size >= (size * size + 1) // 2, box / frac, np.nan)[rows, cols]
    e = v - mean
    tau = max(TAU_MIN, SIGMAS * robust_sigma(e)) if np.isfinite(e).any() else TAU_MIN
    cand = np.flatnonzero(np.abs(np.nan_to_num(e)) > tau / 2)
    if len(cand):
        h = size // 2
        pad = np.pad(x, h, constant_values=np.nan)
        off = np.arange(size)
        win = pad[rows[cand][:, None, None] + off[None, :, None], cols[cand][:, None, None] + off[None, None, :]]
        win = win.reshape(len(cand), -1)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # windows without a valid value: NaN, as wanted
            med = np.nanmedian(win, axis=1)
        e[cand] = np.where(2 * np.isfinite(win).sum(axis=1) > size * size, v[cand] - med, np.nan)
    return e, tau


def robust_sigma(x: np.ndarray) -> float:
    """1.4826 × the median absolute deviation from the median of ``x`` (finite values; NaN for none)."""
    x = np.asarray(x, np.float64)
    x = x[np.isfinite(x)]
    if not len(x):
        return float("nan")
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def standing_out(e: np.ndarray) -> np.ndarray:
    r"""Which of one image's log ratios ``e`` (e.g. :math:`\log(I/(T A R))`, NaN or inf: no model) lie farther than
    :math:`\tau = \max(` :data:`TAU_MIN`, :data:`SIGMAS` robust standard deviations of ``e``) from its median (the
    spatial test's threshold); a ratio that is not finite stands out."""
    e = np.asarray(e, np.float64)
    ok = np.isfinite(e)
    if not ok.any():
        return ~ok
    tau = max(TAU_MIN, SIGMAS * robust_sigma(e[ok]))
    return ~(np.abs(e - np.median(e[ok])) <= tau)


def spatial_outliers(e: np.ndarray, pixel: np.ndarray, tau: np.ndarray) -> np.ndarray:
    r"""Rejected observations of the spatial test (module docstring).

    Parameters
    ----------
    e : :math:`e` per observation (NaN: not tested, e.g. not used or no neighbourhood).
    pixel : the pixel of each observation (int >= 0, e.g. its number in the block).
    tau : the threshold :math:`\tau_k` of each observation's image.
    """
    ok = np.isfinite(e)
    ev = np.where(ok, e, 0.0)
    inv = np.asarray(pixel, np.int64)  # pixel numbers 0..n-1 (a block's): counted directly
    s = np.bincount(inv, ev)
    m = np.bincount(inv, ok.astype(np.float64))
    others = m[inv] - ok
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_others = (s[inv] - ev) / others
    far = ok & (np.abs(ev) > tau)
    return far & ((others < 1) | (np.abs(ev - mean_others) > tau))


#: The robust losses' numbers in compiled code (:func:`loss_weight`).
LOSS_CODES = {"none": 0, "cauchy": 1, "huber": 2}


@njit(cache=True, nogil=True)
def loss_weight(u, code, k):
    """The IRLS weight m of one normalised residual ``u`` (float) for the loss numbered ``code`` (:data:`LOSS_CODES`),
    threshold ``k`` > 0: Cauchy :math:`1/(1 + u^2/k^2)`, Huber :math:`\\min(1, k/|u|)`, none 1 (module docstring).
    The one formula of the NumPy form (:func:`loss_weights`) and of the reweight pass's kernels."""
    a = abs(u)
    if code == 1:
        return 1.0 / (1.0 + (a / k) ** 2)
    if code == 2:
        return 1.0 if a <= k else k / a  # min(1, k/|u|), without dividing by 0
    return 1.0


@njit(cache=True, nogil=True)
def _loss_array(u, code, k, out):
    for i in range(u.shape[0]):
        out[i] = loss_weight(u[i], code, k)


def loss_weights(u: np.ndarray, loss: str, k: float) -> np.ndarray:
    """IRLS weights of the robust loss ``loss`` (:data:`LOSSES`) for normalised residuals ``u``, threshold ``k``
    (float64, :func:`loss_weight` of each)."""
    if loss not in LOSS_CODES:
        raise ValueError(f"unknown robust loss {loss!r}; one of {', '.join(LOSSES)}")
    u = np.ascontiguousarray(u, np.float64)
    out = np.empty(u.shape)
    _loss_array(u.reshape(-1), LOSS_CODES[loss], float(k), out.reshape(-1))
    return out


def loss_rho(u: np.ndarray, loss: str, k: float) -> np.ndarray:
    r"""Twice the robust loss :math:`2\rho(u)` of normalised residuals ``u`` (module docstring; ``none``: :math:`u^2`),
    the cost whose IRLS weights are :func:`loss_weights`: :math:`u^2` near 0 for every loss.

    * Cauchy: :math:`k^2 \log(1 + u^2/k^2)`;
    * Huber: :math:`u^2` for :math:`|u| \le k`, else :math:`2k|u| - k^2`.
    """
    u = np.abs(np.asarray(u, np.float64))
    if loss == "cauchy":
        return k * k * np.log1p((u / k) ** 2)
    if loss == "huber":
        return np.where(u <= k, u * u, 2.0 * k * u - k * k)
    if loss == "none":
        return u * u
    raise ValueError(f"unknown robust loss {loss!r}; one of {', '.join(LOSSES)}")


def lost_fraction(base: np.ndarray, effective: np.ndarray, pixel: np.ndarray, n_pixels: int) -> np.ndarray:
    r"""Per pixel (``pixel``: each observation's, 0..n_pixels-1) the fraction of its observations' weight the robust
    weights took away, :math:`\sum (1 - m) / \#\{w > 0\}` (float32; NaN where no observation has weight)."""
    base = np.asarray(base, np.float64)
    used = base > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        lost = np.where(used, 1.0 - np.asarray(effective, np.float64) / base, 0.0)
        return (np.bincount(pixel, lost, n_pixels) / np.bincount(pixel, used.astype(np.float64), n_pixels)).astype(np.float32)
