r"""Maximum of the profile likelihood of Kim et al. (eq. 8 under eq. 7): trust-region Newton in an active set.

The objective, Kim et al.'s profile likelihood with :math:`r` at eq. 10, its gradient and exact Hessian in the
increments :math:`S \ge 0` of :math:`\ln g` (and :math:`\ln t` when the exposures are unknown), is
:class:`.profile.Profile`.  The start is the paper's alternation of eqs. 10, 11 and 13 (ten passes).

Eq. 7 by an active set (:func:`_solve`, Lawson-Hanson style): scipy's ``trust-exact``
maximises over the increments that are not pooled, unconstrained.  When some come out
negative the step goes only as far as the first one reaching 0, which is pooled (held at 0:
adjacent levels share one g, as isotonic regression pools them); once the free increments
are optimal, the pooled one whose multiplier most wants it open is released.  The fit is
**converged** when the first-order (KKT) conditions of -L/N hold to ``GTOL_ACCEPT``
(gradient of the free parameters, plus the gauge's multiplier, below it; no pooled step
wanting to open by more), and reported as not converged after ``MAX_ITER`` Newton
iterations or ``MAX_PASSES`` passes.  (The earlier log-increment parametrisation put an
active bound at :math:`-\infty`: trust-exact never settled on the Apollo DRGs.)

Two additions to Kim et al. (both off by default here; :func:`.smoothing.fit_regularised` turns them on):

* ``smoothing`` :math:`\lambda`: the objective is :math:`-L + \tfrac{\lambda}{2}\lVert W D_2 \ln g\rVert^2`
  (second differences over the DN range, :func:`.model.roughness_weights`), a quadratic form in :math:`S`.
* ``bins``: the DN is quantised, so its probability is the density at :math:`x = g(z)` times the
  width of its bin, :math:`g(z)\,w_z` with :math:`w_z` the central difference of :math:`\ln g`
  (:func:`.model.bin_widths`).  This adds :math:`\sum_n \ln w_{z_n} + N \ln s` to eq. 8, where
  :math:`s` is the count scale (the mean of :math:`g(z_n)` in counts, in logs): the likelihood
  becomes a proper distribution of the DN, so an observed DN cannot have an empty (flat) bin and
  the scale, which eq. 8 alone leaves free, is the noise level the data show.  Each DN also gets its
  quantisation weight :math:`\kappa_z` (:func:`.profile.quantisation_weights`: the noise convolved with the
  bin's uniform distribution, Sheppard's correction), so a toe or shoulder DN whose bin spans many photon
  standard deviations weighs what it is worth.  The fit alternates the shape at fixed scale and weights
  (the Newton/active-set solve) with the scale at a fixed shape (a 1-D bounded maximum, scipy's
  ``minimize_scalar``) and the weights it implies, at most ``MAX_SCALE_ROUNDS`` times.

Unknown exposure times: the gauge of the exponential ambiguity, g linear over DN 64-192
(:func:`.model.gauge_prior`, a linear equality in :math:`S`), is eliminated through its null space;
:func:`.model.choose_gauge` then decides whether the geometric slope :math:`\beta` of
:class:`.model.GeometricSlope` replaces it: strong geometry (``GEOMETRY_STRONG``) refits with
:math:`\beta = 1` as the constraint; weaker geometry applies the power :math:`1/\beta` to the fitted
g, r, t (a constraint on :math:`\beta` alone would let eq. 8's compression bend the rest of the curve).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import null_space
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits

from .model import (GEOMETRY_STRONG, MID_RANGE, Z_REF, GeometricSlope, Levels, Observations, alternation, choose_gauge,
                    choose_levels, gauge_prior, known_factor, radiance_update, residual_analysis)
from .profile import Profile

#: Convergence: largest violation of the first-order (KKT) conditions of -L/N (per observation).
GTOL_ACCEPT = 1e-6
#: Newton iterations (all active-set passes together) before the fit is reported as not converged.
MAX_ITER = 500
#: Active-set passes before the fit is reported as not converged.
MAX_PASSES = 200
#: Rounds of (count scale and quantisation weights, shape) when the DN bins are modelled.
MAX_SCALE_ROUNDS = 10
#: BLAS threads during a fit: its matrices are a few hundred wide, where threads only cost (on a loaded 2-core
#: machine one fit took 8x the CPU time with OpenBLAS's 2 threads); limited inside the call only.
BLAS_THREADS = 1


@dataclass
class ResponseFit:
    """Result of :func:`fit_response` (``g`` over ``levels.dn``, normalised to g(z_ref) = 1)."""

    levels: Levels
    g: np.ndarray
    g_initial: np.ndarray  # the start from the closed-form alternation (eq. 13), same normalisation
    exposure: np.ndarray
    radiance: np.ndarray  # per pixel of the observations; NaN where left out
    loglik: list[float]  # eq. 8 per pass of the alternation, then per feasible Newton/active-set point
    z_ref: int
    n_juggle: int
    gamma: dict = field(default_factory=dict)
    residuals: dict = field(default_factory=dict)
    converged: bool = True
    message: str = ""
    passes: int = 1  # active-set passes of the Newton fit
    newton: int = 0  # Newton iterations over all passes (``loglik`` records the feasible points only)
    smoothing: dict = field(default_factory=dict)  # the weight of the penalty and how it was chosen (.smoothing)

    def lut(self, n_levels: int = 256) -> np.ndarray:
        """g as a float32 look-up table over 0..n_levels-1; NaN outside the fitted range."""
        out = np.full(n_levels, np.nan, np.float32)
        out[self.levels.lo:self.levels.hi + 1] = self.g
        return out


def _kkt(p, grad, nv, pooled, a_s):
    """Largest violation of the first-order conditions (bounds S >= 0 on pooled increments, gauge a_s @ S = 1)."""
    free = np.ones(len(p), bool)
    free[:nv] = ~pooled
    lam = 0.0
    if a_s is not None:
        af = a_s[free[:nv]]
        lam = -float(af @ grad[:nv][free[:nv]]) / max(float(af @ af), 1e-300)
    lg = grad.copy()
    if a_s is not None:
        lg[:nv] += lam * a_s
    viol = np.abs(lg)
    viol[:nv][pooled] = np.maximum(-lg[:nv][pooled], 0.0)  # a pooled step may only want to stay shut
    return float(viol.max()) if len(viol) else 0.0, lg


def _solve(prof: Profile, p0: np.ndarray, a_s: np.ndarray | None, record, max_iter: int):
    """Minimise -L/N over (S >= 0, u) with ``a_s @ S = 1`` (if given): active set around trust-exact.

    Returns ``(p, converged, passes, newton_iterations, message)``.
    """
    nv = prof.nv
    p = p0.copy()
    pooled = p[:nv] <= 0.0
    p[:nv][pooled] = 0.0
    its = 0
    for passes in range(1, MAX_PASSES + 1):
        free = np.flatnonzero(~pooled)
        # S over the free increments = s0 + Z y (the gauge eliminated); u unconstrained
        if a_s is not None:
            af = a_s[free]
            if not af @ af > 0:  # every step the gauge measures is pooled: it cannot hold
                break
            s0, z = af / (af @ af), null_space(af[None, :])
        else:
            s0, z = np.zeros(len(free)), np.eye(len(free))
        nu = len(p) - nv
        e = np.zeros((len(p), z.shape[1] + nu))
        e[free, :z.shape[1]] = z
        e[nv:, z.shape[1]:] = np.eye(nu)
        base = np.zeros(len(p))
        base[free] = s0
        y0 = np.linalg.lstsq(e, p - base, rcond=None)[0]

        def fun(y):
            val, grad = prof.fun(base + e @ y)
            return val, e.T @ grad

        def record_y(y, *_):
            q = base + e @ y
            if np.all(q[:nv] >= 0):  # the history shows feasible points only (eq. 7 holds)
                record(q)

        ident = e.shape[0] == e.shape[1] and np.array_equal(e, np.eye(len(e)))  # nothing pooled, no gauge

        def hess(y):
            h = prof.hess(base + e @ y)
            return h if ident else e.T @ h @ e

        res = minimize(fun, y0, jac=True, hess=hess, method="trust-exact",
                       callback=record_y, options=dict(maxiter=max(max_iter - its, 1), gtol=1e-10))
        its += res.nit
        p_new = base + e @ res.x
        neg = ~pooled & (p_new[:nv] < 0.0)
        if neg.any():  # eq. 7 violated: go only as far as the first step reaching 0 and pool it (Lawson-Hanson)
            s_old, s_new = p[:nv][neg], p_new[:nv][neg]
            alpha = float(np.min(s_old / (s_old - s_new)))
            p = p + alpha * (p_new - p)
            pooled |= p[:nv] <= 1e-12 * max(1.0, float(np.max(p[:nv])))
            p[:nv][pooled] = 0.0
            record(p)
            continue
        p = p_new
        prof._eval(p)
        viol, lg = _kkt(p, prof._grad, nv, pooled, a_s)
        if viol < GTOL_ACCEPT:
            return p, True, passes, its, f"KKT conditions hold to {viol:.1e} ({int(pooled.sum())} pooled steps)"
        opening = np.flatnonzero(pooled & (lg[:nv] < -GTOL_ACCEPT))
        if len(opening):  # the likelihood rises if this pooled step opens: release the one that wants it most
            pooled[opening[np.argmin(lg[:nv][opening])]] = False
        if its >= max_iter:
            break
    prof._eval(p)
    viol = _kkt(p, prof._grad, nv, pooled, a_s)[0]
    return p, False, passes, its, f"not converged: KKT violation {viol:.1e} after {its} Newton iterations, {passes} passes"


def _fitted_levels(obs: Observations, min_count: int, exclude) -> tuple:
    """The free levels and the observations fitted: in the levels' range, not excluded, of pixels with two
    or more of them.  The levels are chosen on the observations that are kept (a level whose observations
    all fall on pixels seen once carries nothing on g: as a knot it had no data and the fit started from
    NaN); dropping a pixel can move the range, so the choice is repeated until it holds."""
    keep = ~np.isin(obs.dn, exclude)
    lev = None
    for _ in range(32):
        keep &= np.bincount(obs.pixel[keep], minlength=obs.n_pixels)[obs.pixel] >= 2
        new = choose_levels(obs.dn[keep], min_count, exclude)
        in_range = keep & (obs.dn >= new.lo) & (obs.dn <= new.hi)
        if lev is not None and np.array_equal(new.knots, lev.knots) and np.array_equal(in_range, keep):
            break
        lev, keep = new, in_range
    return lev, keep


@threadpool_limits.wrap(limits=BLAS_THREADS, user_api="blas")
def fit_response(obs: Observations, exposure: np.ndarray | None = None, min_count: int = 20, exclude=(0, 255),
                 juggle_passes: int = 10, max_iter: int = MAX_ITER, z_ref: int = Z_REF,
                 gauge: str = "auto", smoothing: float = 0.0, bins: bool = False) -> ResponseFit:
    r"""Fit the inverse camera response by maximum likelihood (Kim et al., eq. 8 under eq. 7).

    Maximises :math:`L = \sum_n g(z_n)\ln\mu_n - \mu_n - \ln\Gamma(g(z_n)+1)`,
    :math:`\mu_n = r_i t_j c_n`, over a non-decreasing :math:`g` (eq. 7), the radiances
    :math:`r` and, if ``exposure`` is None, the exposure times :math:`t` (the module
    docstring gives the method).  Observations at excluded DN or outside the free levels'
    range (:func:`~.model.choose_levels`), and pixels left with fewer than two, are left
    out.  Estimated exposures leave an exponential ambiguity: the fit holds g linear over DN
    64-192 (the prior), unless the geometric slope of :class:`.model.GeometricSlope`
    replaces it (:func:`.model.choose_gauge`; as a constraint when the geometry is strong,
    else as the power :math:`\gamma = 1/\beta` applied to g, r, t).

    Parameters
    ----------
    obs : Observations
        Flat observations: ``pixel``, ``image``, integer ``dn`` (0..255) and an optional
        known factor ``c`` each (the PhotometryTK manual's reflectance; None = 1).
    exposure : numpy.ndarray, optional
        Known exposure time per image, ``(n_images,)``; None: estimated.
    min_count : int, default 20
        Observations a DN level needs to be a free level (a knot) of :math:`\ln g`.
    exclude : sequence of int, default (0, 255)
        DN left out (saturated).
    juggle_passes : int, default 10
        Passes of Kim et al.'s alternation (eqs. 10, 11, 13) that gives the start.
    max_iter : int, default MAX_ITER
        Newton iterations before the fit is reported as not converged.
    z_ref : int, default Z_REF
        DN of the normalisation :math:`g(z_{ref}) = 1` (clipped into the fitted range).
    gauge : {"auto", "geometry", "prior"}, default "auto"
        Gauge of the exponential ambiguity when exposures are estimated, as above.
    smoothing : float, default 0.0
        Weight :math:`\lambda` of the roughness penalty on :math:`\ln g` (second differences with
        Debevec-Malik hat weights; the module docstring); 0: none (Kim et al.'s plain fit).
    bins : bool, default False
        Model each DN's 8-bit quantisation in the likelihood (density times bin width, with the
        quantisation weights of :func:`.profile.quantisation_weights`) and fit the count scale that
        eq. 8 leaves free.

    Returns
    -------
    ResponseFit
        ``levels`` (DN range ``lo..hi``, ``knots``, ``counts``); ``g`` over ``lo..hi``,
        ``g(z_ref) = 1`` (``lut()``: over 0..255, NaN outside); ``g_initial``;
        ``exposure`` (geometric mean 1 when estimated); ``radiance`` (per pixel of ``obs``,
        NaN where left out); ``loglik`` (eq. 8 per iteration); ``z_ref``; ``n_juggle``;
        ``gamma`` (the gauge and why; with ``bins`` also ``count_scale`` and ``quantisation_weight``:
        the smallest weight, its DN and how many DN weigh less than 1/2); ``residuals`` (per-DN ``count``, ``bias_log``,
        ``std_log``, ``se_log_g``; ``chi2_per_dof``, ``rms_log``, ``n_obs``,
        ``n_params``); ``converged``, ``message``, ``passes``, ``newton``.

    Raises
    ------
    InputError
        Exit 2: fewer than three DN levels have ``min_count`` observations.
    """
    lev, keep = _fitted_levels(obs, min_count, exclude)
    sub, pix_ids = obs.take(keep)
    lev_idx = (sub.dn - lev.lo).astype(np.int64)
    t_free = exposure is None
    t0 = np.ones(obs.n_images) if t_free else np.asarray(exposure, np.float64)
    zr = int(np.clip(z_ref, lev.lo, lev.hi))
    g0, t_j, hist = alternation(sub, lev_idx, lev, t0, t_free, juggle_passes)
    n_juggle = len(hist)
    g0_k = g0[lev.knots - lev.lo]
    p0 = np.diff(np.log(g0_k))
    p0 = np.maximum(p0, 1e-2 * max(float(np.mean(p0)), 1e-6) if bins else 0.0)
    if t_free:
        p0 = np.concatenate([p0, np.log(t_j[1:] / t_j[0])])
    prof = Profile(sub, lev_idx, lev, None if t_free else t0, smoothing, bins)

    def record(p):
        hist.append(-prof.fun(p)[0] * prof.scale)

    info = {"exposures_known": not t_free, "gamma": 1.0}
    def solve_with_scale(p, a_s):
        """_solve, and with ``bins`` the count scale (noise level) and the quantisation weights from the shape, then
        the shape again (the first ones from the start: at the pinned scale and weights 1 the toe of a steep curve
        is badly conditioned)."""
        if bins:
            prof.log_scale, kappa = prof.best_noise(p)
            prof.set_kappa(kappa)
        p, converged, passes, its, message = _solve(prof, p, a_s, record, max_iter)
        for _ in range(MAX_SCALE_ROUNDS if bins else 0):
            new, kappa = prof.best_noise(p)
            if abs(new - prof.log_scale) < 1e-3 and np.max(np.abs(np.log(kappa / prof.kappa))) < 1e-2:
                break
            prof.log_scale = new
            prof.set_kappa(kappa)
            p, converged, more, its2, message = _solve(prof, p, a_s, record, max_iter)
            passes, its = passes + more, its + its2
        return p, converged, passes, its, message

    if not t_free:
        p, converged, passes, its, message = solve_with_scale(p0, None)
    else:
        a = gauge_prior(lev)
        p0[:prof.nv] /= max(float(a @ prof.jac @ p0[:prof.nv]), 1e-12)  # start on the prior's gauge
        p, converged, passes, its, message = solve_with_scale(p0, prof.jac.T @ a)
        info = {"exposures_known": False, "gauge": "prior", "gamma": 1.0,
                "prior": f"response linear over DN {MID_RANGE[0]}-{MID_RANGE[1]} (log-log slope 1)"}
        if gauge != "prior" and sub.factor is not None:
            geo = GeometricSlope.of(sub)
            prof._eval(p)
            beta, se = geo.slope(np.log(prof.state[3]))
            use, why = choose_gauge(beta, se, geo.spread, gauge)
            x, mu = prof.state[3], prof.state[4]
            strength = geo.spread / max(float(np.sqrt(np.mean(np.log(mu / x) ** 2))), 1e-12)
            info["geometry"] = {"beta_under_prior": beta, "se": se, "spread_log_c": geo.spread, "strength": strength,
                                "mid_slope_implied": 1.0 / beta if beta > 0 else None, "used": use, "reason": why}
            if use and strength >= GEOMETRY_STRONG:  # refit with beta = 1 as the constraint, from the powered curve
                a_geo = lev.matrix.T @ np.bincount(lev_idx, geo.weight, len(prof.cnt))
                p2, converged, passes2, its2, message = _solve(prof, p / beta, prof.jac.T @ a_geo, record, max_iter)
                p, passes, its = p2, passes + passes2, its + its2
                info.update(gauge="geometry", mode="constraint", gamma=1.0)
            elif use:  # weak geometry: the likelihood's shape under the prior, the geometry's power
                info.update(gauge="geometry", mode="power", gamma=1.0 / beta)
    info["count_scale"] = float(np.exp(prof.log_scale)) if bins else None
    if bins:  # the quantisation weights (profile.quantisation_weights): how much each DN counts
        info["quantisation_weight"] = {"min": float(prof.kappa.min()), "dn_of_min": int(lev.lo + np.argmin(prof.kappa)),
                                       "dn_below_half": int(np.sum(prof.kappa < 0.5))}
    prof._eval(p)
    g, t = prof.state[:2]
    if t_free:
        gam = info["gamma"]  # the likelihood's shape, the geometry's power (see choose_gauge)
        g, t, g0 = g**gam, (t / np.exp(np.mean(np.log(t)))) ** gam, g0**gam  # geometric mean of t -> 1
        g *= np.exp(prof.log_scale) / np.exp(np.mean(np.log(g[lev_idx])))  # back on the fit's scale: chi2 comparable
    x, kap = g[lev_idx], prof.kappa[lev_idx]
    r_sub = radiance_update(x, sub, t, kap)  # eq. 10 again: r^gamma is not the optimum when c varies
    mu = r_sub[sub.pixel] * known_factor(sub, t)
    n_params = prof.nv + (obs.n_images - 1 if t_free else 0) + sub.n_pixels
    resid = residual_analysis(x, mu, lev_idx, len(g), n_params=n_params, weight=kap)
    a = g[zr - lev.lo]
    radiance = np.full(obs.n_pixels, np.nan)
    radiance[pix_ids] = r_sub / a
    return ResponseFit(levels=lev, g=g / a, g_initial=g0 / g0[zr - lev.lo], exposure=t, radiance=radiance,
                       loglik=hist, z_ref=zr, n_juggle=n_juggle, gamma=info, residuals=resid,
                       converged=converged, message=message, passes=passes, newton=its)
