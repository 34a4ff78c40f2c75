r"""Camera response recovery by continuous-Poisson maximum likelihood (Kim et al., eqs. 6-15).

Notation of Kim et al., section 3: an observation :math:`n=(i,j)` is pixel (or albedo
sample) :math:`i` seen in image :math:`j` with digital number :math:`z_n`; the sensor
exposure is :math:`x_n = g(z_n)` with :math:`g = f^{-1}` the inverse camera response,
and its mean is :math:`\mu_n = r_i\,t_j\,c_n`.  :math:`c_n` is a known per-observation
factor: 1 in the aligned case of the paper, the reflectance model :math:`R` of Nefian et al.
(eq. 2) when the albedo solver uses it (the unaligned case), so :math:`r_i` is then the
albedo.  Everything here is pure NumPy/SciPy on flat observation arrays (no I/O).

The log-likelihood (eq. 8) is

.. math:: L = \sum_n g(z_n)\ln\mu_n - \mu_n - \ln\Gamma(g(z_n)+1)

subject to :math:`0 \le g(0) \le \dots \le g(255)` (eq. 7).  :math:`r` has the closed form
of eq. 10 (eq. 15 with virtual observations), :math:`t` that of eq. 11 and :math:`g` that
of eq. 12 (eq. 13 approximates :math:`\Psi^{-1}` by exp); with the constraint (7), eq. 12
becomes an isotonic regression of the per-level means of :math:`\ln\mu` followed by
:math:`\Psi^{-1}` (the separable objective is a Bregman one, so pooling adjacent
violators in the mean parameter is exact).  Alternating these converges slowly, so
:func:`~.fit.fit_response` maximises the *profile* likelihood :math:`L(g, r^*(g,t), t)` with
a trust-region Newton method from the alternation's result (eq. 13) as the start
(:mod:`.fit`).

Gauges.  The continuous Poisson "density" (eq. 4) is not normalised in :math:`x`, so
eq. 8 does not fix the overall scale of :math:`g` (it grows without bound as
:math:`g \to 0`).  The fit therefore holds the mean of :math:`\ln g(z_n)` over the observations at
``ln FIT_SCALE`` (1000 counts: the Poisson weighting's Gaussian regime, so the shape hardly
depends on the choice; see :mod:`.fit` for why this pin), and the returned :math:`g` is normalised to
:math:`g(z_{ref}) = 1` (OpenCV's convention, :math:`z_{ref} = 128`), with :math:`r`
rescaled so that :math:`g(z) = r\,t\,c` still holds.  With unknown exposure times the
data also fit :math:`g^\gamma, r^\gamma, t^\gamma` (the exponential ambiguity): see
:func:`.fit.fit_response` (its gauges) and :class:`GeometricSlope`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import isotonic_regression, newton
from scipy.special import digamma, gammaln, polygamma

#: DN levels of 8-bit data.
N_LEVELS = 256
#: Reference DN of the normalisation g(Z_REF) = 1 (as OpenCV's calibrate* functions).
Z_REF = 128
#: Counts of g at the reference level while fitting (eq. 8 does not fix the scale: see module doc).
FIT_SCALE = 1000.0
#: DN range assumed linear by the gamma prior when exposure times are unknown.
MID_RANGE = (64, 192)
#: The geometric gauge is used when its slope is known to this relative standard error ...
GEOMETRY_MAX_REL_SE = 0.05
#: ... and the mid-range log-log slope of g it implies lies in this band (film and scanning; see docs/response.md).
GEOMETRY_SLOPE_BAND = (0.5, 2.0)
#: Geometry this strong (RMS of the projected ln c over the RMS log residual) constrains the refit itself;
#: weaker geometry only sets the power of the prior-gauged curve (docs/response.md, "Identifiability").
GEOMETRY_STRONG = 2.0



@dataclass(frozen=True)
class Observations:
    """Flat observations: pixel index, image index, DN, optional known factor ``c`` (float64)."""

    pixel: np.ndarray
    image: np.ndarray
    dn: np.ndarray
    n_pixels: int
    n_images: int
    factor: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.dn)

    def take(self, keep: np.ndarray) -> "Observations":
        """The subset ``keep`` (boolean mask), pixel indices renumbered densely."""
        uniq, pix = np.unique(self.pixel[keep], return_inverse=True)
        fac = None if self.factor is None else self.factor[keep]
        return Observations(pix.astype(np.int64), self.image[keep], self.dn[keep], len(uniq), self.n_images, fac), uniq


def observations_from_stack(dn: np.ndarray, valid: np.ndarray) -> Observations:
    """Observations of an aligned stack ``(n_images, ...)`` of DN where ``valid`` (the paper's D_j)."""
    n_img = dn.shape[0]
    flat = dn.reshape(n_img, -1)
    ok = valid.reshape(n_img, -1)
    img, pix = np.nonzero(ok)
    return Observations(pix.astype(np.int64), img.astype(np.int32), flat[img, pix].astype(np.int32), flat.shape[1], n_img)


# --------------------------------------------------------------------------- closed forms
def known_factor(obs: Observations, t: np.ndarray) -> np.ndarray:
    """:math:`t_j c_n` per observation (c = 1 when the observations carry no factor)."""
    ct = np.asarray(t, np.float64)[obs.image]
    return ct if obs.factor is None else ct * obs.factor


def radiance_update(x: np.ndarray, obs: Observations, t: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    r"""Eq. 10 (and 15): :math:`r_i = \sum_j g(z_{ij}) / \sum_j t_j c_{ij}`; 0 where a pixel has no observation.

    ``weight`` (per observation, e.g. the quantisation weights :math:`\kappa` of :mod:`.profile`) weighs both sums."""
    w = 1.0 if weight is None else weight
    num = np.bincount(obs.pixel, w * x, obs.n_pixels)
    den = np.bincount(obs.pixel, w * known_factor(obs, t), obs.n_pixels)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, 0.0)


def exposure_update(x: np.ndarray, obs: Observations, r: np.ndarray) -> np.ndarray:
    r"""Eq. 11: :math:`t_j = \sum_i g(z_{ij}) / \sum_i r_i c_{ij}`."""
    cr = r[obs.pixel] if obs.factor is None else r[obs.pixel] * obs.factor
    num = np.bincount(obs.image, x, obs.n_images)
    den = np.bincount(obs.image, cr, obs.n_images)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, 1.0)


def inverse_digamma(y: np.ndarray) -> np.ndarray:
    r""":math:`\Psi^{-1}(y)` by Newton's method (scipy) from Minka's starting point."""
    y = np.asarray(y, np.float64)
    x0 = np.where(y >= -2.22, np.exp(y) + 0.5, -1.0 / (y - digamma(1.0)))
    return newton(lambda x: digamma(x) - y, x0, fprime=lambda x: polygamma(1, x), tol=1e-12, maxiter=50)


def response_closed_form(log_mu: np.ndarray, level: np.ndarray, n_levels: int, exact: bool = True) -> np.ndarray:
    r"""Eq. 12 (``exact``) or eq. 13 under the constraint (7); NaN at levels without data.

    Per level :math:`k` the mean :math:`m_k` of :math:`\ln\mu` over its observations is made
    non-decreasing by a count-weighted isotonic regression, then
    :math:`g(k) = \Psi^{-1}(m_k) - 1` (eq. 12, clipped at 0) or :math:`e^{m_k}` (eq. 13).
    """
    cnt = np.bincount(level, minlength=n_levels).astype(np.float64)
    s = np.bincount(level, log_mu, n_levels)
    have = cnt > 0
    m = np.full(n_levels, np.nan)
    m[have] = isotonic_regression(s[have] / cnt[have], weights=cnt[have]).x
    if exact:
        out = np.full(n_levels, np.nan)
        out[have] = np.maximum(inverse_digamma(m[have]) - 1.0, 0.0)
        return out
    return np.exp(m)


def log_likelihood(x: np.ndarray, mu: np.ndarray) -> float:
    """Eq. 8 summed over the observations (float64)."""
    return float(np.sum(x * np.log(mu) - mu - gammaln(x + 1.0)))


# --------------------------------------------------------------------------- sparse levels
@dataclass(frozen=True)
class Levels:
    """The DN range fitted, its free levels (knots) and the interpolation of the others.

    ``lo..hi`` (inclusive) is the fitted range; ``knots`` the levels with at least
    ``min_count`` observations (free parameters); every level in the range gets
    :math:`\\ln g` by linear interpolation between neighbouring knots (``matrix``,
    shape (hi-lo+1, n_knots)), which keeps (7).
    """

    lo: int
    hi: int
    knots: np.ndarray
    matrix: np.ndarray
    counts: np.ndarray  # (N_LEVELS,) observations per DN (before exclusions)

    @property
    def dn(self) -> np.ndarray:
        return np.arange(self.lo, self.hi + 1)


def choose_levels(dn: np.ndarray, min_count: int, exclude=(0, 255), n_levels: int = N_LEVELS) -> Levels:
    """Free levels: DN with >= ``min_count`` observations, not in ``exclude`` (saturated)."""
    counts = np.bincount(dn, minlength=n_levels)
    ok = counts >= min_count
    ok[list(exclude)] = False
    knots = np.flatnonzero(ok)
    if len(knots) < 3:
        from ..errors import InputError

        raise InputError(f"only {len(knots)} DN levels have >= {min_count} observations; cannot fit a response curve")
    lo, hi = int(knots[0]), int(knots[-1])
    dn_range = np.arange(lo, hi + 1)
    m = np.zeros((len(dn_range), len(knots)))
    pos = np.searchsorted(knots, dn_range)
    for row, (z, p) in enumerate(zip(dn_range, pos)):
        if knots[p] == z:
            m[row, p] = 1.0
        else:
            a, b = knots[p - 1], knots[p]
            w = (z - a) / (b - a)
            m[row, p - 1], m[row, p] = 1.0 - w, w
    return Levels(lo, hi, knots, m, counts)


@dataclass(frozen=True)
class GeometricSlope:
    r"""The within-pixel, within-image regression of :math:`\ln g(z_n)` on :math:`\ln c_n`.

    With :math:`g(z_n) = r_i t_j c_n` exactly, :math:`\ln g(z_n) = a_i + b_j + \beta \ln c_n`
    with :math:`\beta = 1`; a curve off by the exponential ambiguity (:math:`g^\gamma`) gives
    :math:`\beta = \gamma`.  ``weight`` holds :math:`w_n = \tilde c_n / \sum \tilde c_n^2`
    (:math:`\tilde c` = :math:`\ln c` with the pixel and image effects projected out, by
    scipy's ``lsqr``), so :math:`\beta = \sum_n w_n \ln g(z_n)` is linear in :math:`\ln g`.
    """

    weight: np.ndarray
    spread: float  # RMS of the projected ln c: the geometric variation that identifies beta
    dof: int
    design: object  # the sparse fixed-effect design (pixels, images), for the residual

    @classmethod
    def of(cls, obs: "Observations") -> "GeometricSlope":
        import scipy.sparse as sparse
        from scipy.sparse.linalg import lsqr

        n = len(obs)
        rows = np.arange(n)
        design = sparse.hstack([sparse.csr_matrix((np.ones(n), (rows, obs.pixel)), shape=(n, obs.n_pixels)),
                                sparse.csr_matrix((np.ones(n), (rows, obs.image)), shape=(n, obs.n_images))]).tocsr()
        lc = np.log(obs.factor)
        ct = lc - design @ lsqr(design, lc, atol=1e-12, btol=1e-12, iter_lim=2000)[0]
        ss = float(ct @ ct)
        dof = max(n - len(np.unique(obs.pixel)) - obs.n_images, 1)
        return cls(ct / ss if ss > 0 else np.zeros(n), float(np.sqrt(ss / n)), dof, design)

    def slope(self, log_x: np.ndarray) -> tuple[float, float]:
        """:math:`\beta` and its standard error for the log exposures ``log_x`` of the observations."""
        from scipy.sparse.linalg import lsqr

        beta = float(self.weight @ log_x)
        y = log_x - self.design @ lsqr(self.design, log_x, atol=1e-12, btol=1e-12, iter_lim=2000)[0]
        ss = 1.0 / max(float(self.weight @ self.weight), 1e-300)  # sum of the projected ln c squared
        res = y - beta * self.weight * ss
        return beta, float(np.sqrt(res @ res / self.dof / ss))


def second_differences(n: int) -> np.ndarray:
    r"""The (n-2, n) matrix :math:`D_2` of second differences, :math:`(D_2 v)_k = v_k - 2 v_{k+1} + v_{k+2}`.

    The roughness of the curve is :math:`\lVert D_2 \ln g \rVert^2` over consecutive DN: zero for
    :math:`g \propto e^{a z}`, large for waves.
    """
    return np.diff(np.eye(max(n, 2)), 2, axis=0)


def roughness_weights(dn: np.ndarray, n_levels: int = N_LEVELS) -> np.ndarray:
    r"""Weight of the roughness at DN ``dn``: the hat :math:`\min(z, n-1-z) / ((n-1)/2)` (Debevec and Malik's
    weighting, applied to the second difference, so the penalty weighs its square).

    Toe and shoulder, where one DN step is a large step in exposure and the true curve bends
    most, are smoothed least; the straight middle most.
    """
    z = np.asarray(dn, np.float64)
    return np.maximum(np.minimum(z, n_levels - 1 - z), 1.0) / ((n_levels - 1) / 2)


def bin_widths(n: int) -> np.ndarray:
    r"""The (n, n) matrix of each DN bin's width in :math:`\ln g`: central differences
    :math:`(\ln g_{k+1} - \ln g_{k-1})/2`, one-sided at the ends of the range.

    A DN :math:`z` records an exposure anywhere in its bin :math:`[g(z-\tfrac12), g(z+\tfrac12)]`: its
    probability is the noise density at :math:`g(z)` times the bin's width :math:`g(z)\,w_z` (midpoint rule).
    """
    m = np.zeros((n, n))
    if n < 2:
        return m
    i = np.arange(1, n - 1)
    m[i, i + 1], m[i, i - 1] = 0.5, -0.5
    m[0, :2] = (-1.0, 1.0)
    m[-1, -2:] = (-1.0, 1.0)
    return m


def gauge_prior(lev: Levels, mid=MID_RANGE) -> np.ndarray:
    r"""The prior gauge: weights ``a`` over the knots with ``a @ ln g = 1`` meaning "g linear over ``mid``".

    ``a @ ln g`` is the least-squares slope of :math:`\ln g` against :math:`\ln z` over the
    knots in ``mid`` (all knots when fewer than three are).
    """
    z = lev.knots.astype(float)
    sel = (z >= mid[0]) & (z <= mid[1])
    sel = sel if sel.sum() >= 3 else np.ones_like(sel)
    lz = np.where(sel, np.log(z), 0.0)
    lz[sel] -= lz[sel].mean()
    return lz / np.sum(lz**2)


def choose_gauge(beta: float, se: float, spread: float, mode: str = "auto") -> tuple[bool, str]:
    """Whether the geometric slope ``beta`` (s.e. ``se``) replaces the prior gauge, and why.

    ``mode`` "auto" needs geometric variation (``spread`` of the projected ln c > 0), the
    slope determined (relative s.e. below ``GEOMETRY_MAX_REL_SE``) and the mid-range log-log
    slope of g it implies, 1/beta, inside ``GEOMETRY_SLOPE_BAND``; "geometry" needs only a
    positive slope.
    """
    if not spread > 1e-9:
        return False, "no reflectance variation within pixels across images: the geometry cannot fix gamma"
    if not beta > 0:
        return False, f"geometric slope {beta:.3g} is not positive: the reflectance variation does not show in the DN"
    if mode == "geometry":
        return True, "requested"
    if se / beta > GEOMETRY_MAX_REL_SE:
        return False, f"geometric slope {beta:.3f} +- {se:.3f}: too uncertain (> {GEOMETRY_MAX_REL_SE:.0%})"
    lo, hi = GEOMETRY_SLOPE_BAND
    if not lo <= 1.0 / beta <= hi:
        return False, (f"geometric slope {beta:.3f} +- {se:.3f} implies a mid-range log-log slope of g of "
                       f"{1 / beta:.2f}, outside the plausible {lo:g}-{hi:g}: taken as model error")
    return True, f"geometric slope {beta:.3f} +- {se:.3f} (mid-range log-log slope of g {1 / beta:.2f})"


def residual_analysis(x: np.ndarray, mu: np.ndarray, level: np.ndarray, n_levels: int, n_params: int,
                      weight: np.ndarray | None = None) -> dict:
    r"""Per-DN residuals, goodness of fit and uncertainty of :math:`\ln g`.

    Per level: count, mean and standard deviation of :math:`\ln(\mu/g)` (the model's
    exposure against the curve's) and the standard error of :math:`\ln g` (std/√n).
    Global: Pearson :math:`\chi^2` per degree of freedom, :math:`\sum (x-\mu)^2/\mu / (N-p)`
    (about 1 when the Poisson noise model holds at the fitted scale; with ``weight`` :math:`\kappa` per
    observation, :math:`\sum \kappa (x-\mu)^2/\mu`: the quantisation-weighted noise model), and the RMS of
    :math:`\ln(\mu/x)`.
    """
    d = np.log(mu / x)
    cnt = np.bincount(level, minlength=n_levels).astype(np.float64)
    s1 = np.bincount(level, d, n_levels)
    s2 = np.bincount(level, d * d, n_levels)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / cnt
        std = np.sqrt(np.maximum(s2 / cnt - mean**2, 0.0))
        se = std / np.sqrt(cnt)
    dof = max(len(x) - n_params, 1)
    return {
        "count": cnt, "bias_log": mean, "std_log": std, "se_log_g": se,
        "chi2_per_dof": float(np.sum((1.0 if weight is None else weight) * (x - mu) ** 2 / mu) / dof),
        "rms_log": float(np.sqrt(np.mean(d * d))), "n_obs": int(len(x)), "n_params": int(n_params),
    }


def log_rms_error(g_est: np.ndarray, g_true: np.ndarray) -> float:
    """RMS of :math:`\\ln g_{est} - \\ln g_{true}` after the one global scale (mean log ratio) is removed."""
    d = np.log(g_est) - np.log(g_true)
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean((d - d.mean()) ** 2)))


def radiance_map(dn: np.ndarray, valid: np.ndarray, lut: np.ndarray, exposure: np.ndarray) -> np.ndarray:
    r"""Eq. 10 on a whole aligned stack: :math:`r = \sum_j g(z_j) / \sum_j t_j` over valid, fitted DN.

    ``dn`` (n_images, h, w) integers, ``lut`` g over 0..255 (NaN where not fitted), float32
    result with NaN where no image has a usable value.
    """
    x = lut[dn]
    ok = valid & np.isfinite(x)
    num = np.sum(np.where(ok, x, 0.0), axis=0, dtype=np.float64)
    den = np.sum(np.where(ok, np.asarray(exposure, np.float64)[:, None, None], 0.0), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, np.nan).astype(np.float32)


def alternation(obs: Observations, lev_idx: np.ndarray, lev: Levels, t, t_free: bool, passes: int):
    """The paper's alternation (10), (11), (13) from a linear g; returns (g over the range, t, log-likelihoods).

    g is kept at the fit's scale (mean of ln x over the observations = ln FIT_SCALE) and, with
    unknown exposures, on the prior's gauge (a power after each pass), so the likelihoods
    compare with the Newton ones.
    """
    gauge = gauge_prior(lev) if t_free else None
    g = np.arange(lev.lo, lev.hi + 1, dtype=np.float64)
    g *= FIT_SCALE / np.exp(np.mean(np.log(g[lev_idx])))
    hist = []
    for _ in range(passes):
        x = g[lev_idx]
        r = radiance_update(x, obs, t)
        if t_free:
            t = exposure_update(x, obs, r)
            t = t / t[0]
            r = radiance_update(x, obs, t)
        mu = r[obs.pixel] * (t[obs.image] if obs.factor is None else t[obs.image] * obs.factor)
        hist.append(log_likelihood(x, mu))
        g_new = response_closed_form(np.log(mu), lev_idx, len(g), exact=False)
        lg = np.log(g_new[lev.knots - lev.lo])
        if gauge is not None and gauge @ lg > 0:
            lg /= gauge @ lg
        g = np.exp(lev.matrix @ lg)
        g *= FIT_SCALE / np.exp(np.mean(np.log(g[lev_idx])))
    return g, t, hist
