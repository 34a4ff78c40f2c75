r"""Maximum of the profile likelihood of seed 002 (eq. 8 under eq. 7) by trust-region Newton.

With :math:`r` at its closed form (eq. 10) the log-likelihood of eq. 8 becomes, per pixel
:math:`i` with :math:`X_i = \sum_{n\in i} x_n` and :math:`C_i = \sum_{n\in i} t_{j(n)} c_n`,

.. math:: L_p = \sum_i X_i(\ln X_i - \ln C_i - 1) + \sum_n x_n \ln(t_{j(n)}c_n) - \ln\Gamma(x_n+1)

whose gradient in :math:`x_n = g(z_n)` is eq. 9's :math:`\ln(r_i t_j c_n) - \Psi(x_n+1)`
(envelope theorem) and whose Hessian is
:math:`\delta_{i(n)i(m)}/X_i - \delta_{nm}\Psi'(x_n+1)` (concave: Cauchy-Schwarz).
Summed per DN level this is a small dense matrix (levels x levels), built with
scipy.sparse.  The unknowns handed to scipy's ``trust-exact`` are the log increments
:math:`v_m` of :math:`\ln g` between free levels (so eq. 7 holds by construction), with the
mean of :math:`\ln x_n` over the observations pinned to ``ln FIT_SCALE``.  That pin is the
one that does not bend the curve: eq. 8 pulls the scale of :math:`g` down (Stirling:
:math:`L \approx -\tfrac12\sum_n \ln x_n - \sum_n x_n\varepsilon_n^2/2` with
:math:`\varepsilon_n` the relative misfit), and that pull, :math:`-n_k/2` on
:math:`\ln g(k)`, is exactly normal to the constraint, so it only sets the multiplier.  (A pin
at one level instead pushes every other level down: a visible step in g.) and, for unknown exposure
times, :math:`u_j = \ln t_j` for :math:`j \ge 1` (:math:`u_0 = 0`: :math:`r t` is all the
data see).  The start is the seed's alternation of eqs. 10, 11 and 13 (ten passes).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.optimize import minimize
from scipy.special import digamma, polygamma

from .response import (FIT_SCALE, MID_RANGE, Z_REF, Levels, Observations, choose_levels, exposure_update, fix_gamma,
                       log_likelihood, radiance_update, residual_analysis, response_closed_form)

#: Weight (per observation) of the gamma prior when exposure times are unknown (see :func:`.response.fix_gamma`).
PRIOR_WEIGHT = 10.0
#: Largest gradient component (of -L/N) accepted as converged.
GTOL_ACCEPT = 1e-6


@dataclass
class ResponseFit:
    """Result of :func:`fit_response` (``g`` over ``levels.dn``, normalised to g(z_ref) = 1)."""

    levels: Levels
    g: np.ndarray
    g_initial: np.ndarray  # the start from the closed-form alternation (eq. 13), same normalisation
    exposure: np.ndarray
    radiance: np.ndarray  # per pixel of the observations; NaN where left out
    loglik: list[float]  # eq. 8 per pass of the alternation, then per Newton iteration
    z_ref: int
    n_juggle: int
    gamma: dict = field(default_factory=dict)
    residuals: dict = field(default_factory=dict)
    converged: bool = True
    message: str = ""

    def lut(self, n_levels: int = 256) -> np.ndarray:
        """g as a float32 look-up table over 0..n_levels-1; NaN outside the fitted range."""
        out = np.full(n_levels, np.nan, np.float32)
        out[self.levels.lo:self.levels.hi + 1] = self.g
        return out


class _Profile:
    """-L_p / N, its gradient and Hessian in the parameters ``(v, u)``; caches the last point."""

    def __init__(self, obs: Observations, lev_idx, lev: Levels, t_fixed):
        self.obs, self.lev_idx, self.lev, self.t_fixed = obs, lev_idx, lev, t_fixed
        nk, self.n_lev = len(lev.knots), lev.hi - lev.lo + 1
        self.nv = nk - 1
        n = len(obs)
        self.b = sp.csr_matrix((np.ones(n), (obs.pixel, lev_idx)), shape=(obs.n_pixels, self.n_lev))
        self.cnt = np.bincount(lev_idx, minlength=self.n_lev).astype(float)
        self.w_mean = lev.matrix.T @ self.cnt / n  # mean of ln x over the observations = w_mean @ lg_knots
        m = np.arange(nk - 1)[None, :]
        k = np.arange(nk)[:, None]
        tail = np.cumsum(self.w_mean[::-1])[::-1][1:]  # sum of w_mean over knots above increment m
        self.jac = (m < k).astype(float) - tail[None, :]  # d lg_k / d S_m, S_m = exp(v_m)
        self.scale = float(n)
        self._key = None
        self.prior = None
        if t_fixed is None:  # gamma prior: least-squares slope of ln g on ln z over the mid range = 1
            z = lev.knots.astype(float)
            sel = (z >= MID_RANGE[0]) & (z <= MID_RANGE[1])
            sel = sel if sel.sum() >= 3 else np.ones_like(sel)
            lz = np.where(sel, np.log(z), 0.0)
            lz[sel] -= lz[sel].mean()
            self.prior = lz / np.sum(lz**2)

    def unpack(self, p):
        s = np.concatenate([[0.0], np.cumsum(np.exp(p[:self.nv]))])
        lg = np.log(FIT_SCALE) + s - self.w_mean @ s
        t = self.t_fixed if self.t_fixed is not None else np.exp(np.concatenate([[0.0], p[self.nv:]]))
        return lg, t

    def _eval(self, p):
        """Value and gradient at ``p`` (kept, with what the Hessian needs)."""
        if self._key is not None and np.array_equal(p, self._key):
            return
        obs, lev = self.obs, self.lev
        lg_k, t = self.unpack(p)
        g = np.exp(lev.matrix @ lg_k)
        x = g[self.lev_idx]
        if not (np.all(np.isfinite(g)) and np.all(g > 0) and np.all(np.isfinite(t))):
            # a trial step beyond floating point (exp over/underflow): reject it (trust-region shrinks)
            self._key, self._val, self._grad = p.copy(), np.inf, np.zeros_like(p)
            return
        ct = t[obs.image] if obs.factor is None else t[obs.image] * obs.factor
        big_x = np.bincount(obs.pixel, x, obs.n_pixels)
        big_c = np.bincount(obs.pixel, ct, obs.n_pixels)
        r = big_x / big_c
        mu = r[obs.pixel] * ct
        val = log_likelihood(x, mu)
        d_lg = g * (np.bincount(self.lev_idx, np.log(mu), self.n_lev) - self.cnt * digamma(g + 1.0))
        d_k = self.lev.matrix.T @ d_lg  # to ln g over the range, then to the knots, then to v
        if self.prior is not None:  # -PRIOR_WEIGHT * N * (slope - 1)^2 added to L
            dev = self.prior @ lg_k - 1.0
            val -= PRIOR_WEIGHT * self.scale * dev**2
            d_k = d_k - 2 * PRIOR_WEIGHT * self.scale * dev * self.prior
        e = np.exp(p[:self.nv])
        grad = [(self.jac * e[None, :]).T @ d_k]
        if self.t_fixed is None:
            grad.append(np.bincount(obs.image, x - mu, obs.n_images)[1:])
        self._key, self._hess = p.copy(), None
        self._val = -val / self.scale
        self._grad = -np.concatenate(grad) / self.scale
        self.state = (g, t, r, x, mu)
        self._parts = (e, d_lg, d_k, ct, big_x, big_c)

    def _hessian(self):
        g, t, r, x, mu = self.state
        e, d_lg, d_k, ct, big_x, big_c = self._parts
        mt = self.lev.matrix.T
        h_g = (self.b.T @ sp.diags(1.0 / big_x) @ self.b).toarray() - np.diag(self.cnt * polygamma(1, g + 1.0))
        h_k = mt @ (g[:, None] * h_g * g[None, :] + np.diag(d_lg)) @ self.lev.matrix
        if self.prior is not None:
            h_k = h_k - 2 * PRIOR_WEIGHT * self.scale * np.outer(self.prior, self.prior)
        ej = self.jac * e[None, :]
        blocks = [[ej.T @ h_k @ ej + np.diag(e * (self.jac.T @ d_k))]]
        if self.t_fixed is None:
            h_uu, h_lgu = self._exposure_blocks(x, ct, big_x, big_c, g)
            cross = ej.T @ (mt @ h_lgu)  # (nv, n_img-1)
            blocks[0].append(cross)
            blocks.append([cross.T, h_uu])
        return -np.block(blocks) / self.scale

    def _exposure_blocks(self, x, ct, big_x, big_c, g):
        """Hessian block of u_j = ln t_j (j >= 1) and its cross block with ln g."""
        obs = self.obs
        q = sp.csr_matrix((ct / big_c[obs.pixel], (obs.pixel, obs.image)), shape=(obs.n_pixels, obs.n_images))
        xq = sp.diags(big_x) @ q
        h_uu = (q.T @ xq).toarray() - np.diag(np.asarray(xq.sum(axis=0)).ravel())
        n_kj = sp.csr_matrix((np.ones(len(x)), (self.lev_idx, obs.image)), shape=(self.n_lev, obs.n_images)).toarray()
        h_gu = n_kj - (self.b.T @ q).toarray()  # d2 L / dg_k du_j
        h_lgu = g[:, None] * h_gu
        return h_uu[1:, 1:], h_lgu[:, 1:]

    def fun(self, p):
        self._eval(p)
        return self._val, self._grad

    def hess(self, p):
        self._eval(p)
        if self._hess is None:
            self._hess = self._hessian()
        return self._hess


def _juggle(obs, lev_idx, lev: Levels, t, t_free: bool, passes: int):
    """The seed's alternation (10), (11), (13) from a linear g; returns (g over the range, t, log-likelihoods).

    g is kept at the fit's scale (mean of ln x over the observations = ln FIT_SCALE) so the
    likelihoods compare with the Newton ones.
    """
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
        g = np.exp(lev.matrix @ np.log(g_new[lev.knots - lev.lo]))
        g *= FIT_SCALE / np.exp(np.mean(np.log(g[lev_idx])))
    return g, t, hist


def fit_response(obs: Observations, exposure: np.ndarray | None = None, min_count: int = 20, exclude=(0, 255),
                 juggle_passes: int = 10, max_iter: int = 200, z_ref: int = Z_REF) -> ResponseFit:
    """Maximum-likelihood g, r and (if ``exposure`` is None) t of eq. 8 under eq. 7.

    Observations at excluded DN (saturation) or outside the range of the free levels
    (:func:`~.response.choose_levels`) are left out, as are pixels left with fewer than
    two observations (they carry no information on g).  With ``exposure`` None the
    exponential ambiguity is fixed by :func:`~.response.fix_gamma` (reported in ``gamma``)
    and the exposures are returned with geometric mean 1.
    """
    lev = choose_levels(obs.dn, min_count, exclude)
    keep = (obs.dn >= lev.lo) & (obs.dn <= lev.hi) & ~np.isin(obs.dn, exclude)
    keep &= np.bincount(obs.pixel[keep], minlength=obs.n_pixels)[obs.pixel] >= 2
    sub, pix_ids = obs.take(keep)
    lev_idx = (sub.dn - lev.lo).astype(np.int64)
    t_free = exposure is None
    t0 = np.ones(obs.n_images) if t_free else np.asarray(exposure, np.float64)
    zr = int(np.clip(z_ref, lev.lo, lev.hi))
    g0, t_j, hist = _juggle(sub, lev_idx, lev, t0, t_free, juggle_passes)
    n_juggle = len(hist)
    g0_k = g0[lev.knots - lev.lo]
    p0 = np.log(np.maximum(np.diff(np.log(g0_k)), 1e-6))
    if t_free:
        p0 = np.concatenate([p0, np.log(t_j[1:] / t_j[0])])
    prof = _Profile(sub, lev_idx, lev, None if t_free else t0)

    def record(xk, *_):
        hist.append(-prof.fun(xk)[0] * prof.scale)

    res = minimize(prof.fun, p0, jac=True, hess=prof.hess, method="trust-exact", callback=record,
                   options=dict(maxiter=max_iter, gtol=1e-9))
    prof._eval(res.x)
    # trust-exact stops with "bad approximation" once steps reach rounding level; the gradient says if that is the optimum
    converged = bool(res.success or np.max(np.abs(prof._grad)) < GTOL_ACCEPT)
    g, t, r_sub, x, mu = prof.state
    n_params = prof.nv + (obs.n_images - 1 if t_free else 0) + sub.n_pixels
    resid = residual_analysis(x, mu, lev_idx, len(g), n_params=n_params)
    gamma_info = {"exposures_known": not t_free, "gamma": 1.0}
    if t_free:
        b = np.exp(np.mean(np.log(t)))  # geometric mean of t -> 1
        t, r_sub = t / b, r_sub * b
        gamma, gamma_info = fix_gamma(lev.dn, g)
        g, t, r_sub, g0 = g**gamma, t**gamma, r_sub**gamma, g0**gamma
    a = g[zr - lev.lo]
    radiance = np.full(obs.n_pixels, np.nan)
    radiance[pix_ids] = r_sub / a
    return ResponseFit(levels=lev, g=g / a, g_initial=g0 / g0[zr - lev.lo], exposure=t, radiance=radiance,
                       loglik=hist, z_ref=zr, n_juggle=n_juggle, gamma=gamma_info, residuals=resid,
                       converged=converged, message=str(res.message))
