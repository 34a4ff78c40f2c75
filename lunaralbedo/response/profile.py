r"""The objective of the response fit: Kim et al.'s profile likelihood (eq. 8 with r at eq. 10), its gradient and Hessian.

With :math:`r` at its closed form the log-likelihood becomes, per pixel :math:`i` with
:math:`X_i = \sum_{n\in i} \kappa_n x_n` and :math:`C_i = \sum_{n\in i} \kappa_n t_{j(n)} c_n`,

.. math:: L_p = \sum_i X_i(\ln X_i - \ln C_i - 1)
          + \sum_n \kappa_n x_n \ln(\kappa_n t_{j(n)}c_n) - \ln\Gamma(\kappa_n x_n+1) + \ln\kappa_n

whose gradient in :math:`x_n = g(z_n)` is eq. 9's :math:`\kappa_n(\ln(\kappa_n r_i t_j c_n) - \Psi(\kappa_n x_n+1))`
(envelope theorem) and whose Hessian is :math:`\kappa_n\kappa_m\delta_{i(n)i(m)}/X_i - \delta_{nm}\kappa_n^2\Psi'(\kappa_n x_n+1)`
(concave: Cauchy-Schwarz).  Summed per DN level this is a small dense matrix (levels x levels), built with
scipy.sparse.  :math:`\kappa = 1` is Kim et al.'s eq. 8.

:math:`\kappa_z \le 1` is the *quantisation weight* of DN level :math:`z` (:func:`quantisation_weights`): a DN
records any exposure in its bin, so given :math:`\mu` the probability of :math:`z` is the bin's width
:math:`\Delta_z` times the noise density convolved with the bin's uniform distribution (exact), which
moment matching makes a density of variance :math:`\mu + \Delta_z^2/12` counts (Sheppard's correction).
As a Poisson law of :math:`\kappa x` that is :math:`\kappa_z = 1/(1 + g(z)\,w_z^2/12)`, with :math:`w_z` the
bin's width in :math:`\ln g` and :math:`g` in counts; the :math:`\ln\kappa_n` term is its Jacobian.  In the
straight part of a film curve :math:`\kappa \approx 1`; in the toe and shoulder, where one DN spans
many photon standard deviations, :math:`\kappa` falls and those DN weigh what they are worth.  The fit
(:mod:`.fit`) holds :math:`\kappa` fixed during a Newton solve and updates it with the count scale.

The unknowns are the increments :math:`S_m \ge 0` of :math:`\ln g` between free levels (eq. 7 is
:math:`S \ge 0`), with the mean of :math:`\ln x_n` over the observations pinned to ``ln FIT_SCALE``
(eq. 8's pull on the scale, :math:`-n_k/2` on :math:`\ln g(k)` by Stirling, is normal to that pin, so it
does not bend the curve) and, for unknown exposure times, :math:`u_j = \ln t_j` for :math:`j \ge 1`.
Optional terms: the roughness penalty :math:`\tfrac{\lambda}{2}\lVert W D_2 \ln g\rVert^2`
(:func:`.model.roughness_weights`) and the DN bins' :math:`\sum_n \ln w_{z_n}` (:func:`.model.bin_widths`).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import minimize_scalar
from scipy.special import digamma, gammaln, polygamma

from .model import FIT_SCALE, Levels, Observations, bin_widths, roughness_weights, second_differences


def quantisation_weights(g_counts: np.ndarray, width_log: np.ndarray) -> np.ndarray:
    r""":math:`\kappa_z = 1/(1 + g_z w_z^2/12)`: Poisson weight of a DN whose bin is :math:`w_z` wide in :math:`\ln g`.

    ``g_counts`` is :math:`g(z)` in counts (the fit's scale), ``width_log`` the bin width in :math:`\ln g`
    (the module docstring: the noise variance :math:`\mu` plus the bin's uniform variance :math:`(g w)^2/12`).
    """
    return 1.0 / (1.0 + np.asarray(g_counts) * np.asarray(width_log) ** 2 / 12.0)


def stirling_remainder(y: np.ndarray) -> np.ndarray:
    r""":math:`\ln\Gamma(y+1) - y\ln y + y` without the cancellation of its terms for large :math:`y` (Stirling's
    series above 10, to ~1e-13; directly below, where the terms are small)."""
    y = np.asarray(y, np.float64)
    big = y > 10.0
    yb = np.where(big, y, 10.0)
    series = 0.5 * np.log(2 * np.pi * yb) + 1 / (12 * yb) - 1 / (360 * yb**3) + 1 / (1260 * yb**5)
    ys = np.where(big, 1.0, y)
    direct = gammaln(ys + 1.0) - np.where(ys > 0, ys * np.log(np.where(ys > 0, ys, 1.0)), 0.0) + ys
    return np.where(big, series, direct)


def kappa_log_likelihood(x: np.ndarray, mu: np.ndarray, kap: np.ndarray) -> float:
    r""":math:`\sum_n \kappa x\ln(\kappa\mu) - \kappa\mu - \ln\Gamma(\kappa x+1) + \ln\kappa` (eq. 8 when :math:`\kappa = 1`)."""
    kx = kap * x
    return float(np.sum(kx * np.log(kap * mu) - kap * mu - gammaln(kx + 1.0) + np.log(kap)))


def level_log_likelihood(g, kappa, cnt, sum_log_mu, sum_mu) -> float:
    """:func:`kappa_log_likelihood` from per-level sums (g, kappa per level; count, sum of ln mu, sum of mu over the
    level's observations): every term but ln mu depends on the level only, so this costs O(levels) (for the
    count scale's 1-D search; less precise than the per-observation sum, whose terms cancel one by one)."""
    kg = kappa * g
    have = cnt > 0
    lk = np.log(kappa)
    return float(np.sum(np.where(have, kg * (sum_log_mu + cnt * lk) - kappa * sum_mu
                                 - cnt * (gammaln(kg + 1.0) - lk), 0.0)))


class Profile:
    """-L_p / N (plus the optional terms), its gradient and Hessian in the parameters ``(S, u)``; caches the last point."""

    def __init__(self, obs: Observations, lev_idx, lev: Levels, t_fixed, smoothing: float = 0.0, bins: bool = False):
        self.obs, self.lev_idx, self.lev, self.t_fixed = obs, lev_idx, lev, t_fixed
        nk, self.n_lev = len(lev.knots), lev.hi - lev.lo + 1
        self.nv = nk - 1
        n = len(obs)
        self.b = sp.csr_matrix((np.ones(n), (obs.pixel, lev_idx)), shape=(obs.n_pixels, self.n_lev))
        self.bt = self.b.T.tocsr()
        self.cnt = np.bincount(lev_idx, minlength=self.n_lev).astype(float)
        self.w_mean = lev.matrix.T @ self.cnt / n  # mean of ln x over the observations = w_mean @ lg_knots
        m = np.arange(nk - 1)[None, :]
        k = np.arange(nk)[:, None]
        tail = np.cumsum(self.w_mean[::-1])[::-1][1:]  # sum of w_mean over knots above increment m
        self.jac = (m < k).astype(float) - tail[None, :]  # d lg_k / d S_m
        self.tail = tail
        identity = self.n_lev == nk  # every level a knot: the interpolation is the identity
        self.m_sp = None if identity else sp.csr_matrix(lev.matrix)
        self.bw_sp = sp.csr_matrix(bin_widths(self.n_lev))
        self.scale = float(n)
        d2 = second_differences(self.n_lev) @ lev.matrix @ self.jac
        d2 *= roughness_weights(lev.dn[1:-1])[:, None]
        self.pen = smoothing * (d2.T @ d2)
        self.width = bin_widths(self.n_lev) @ lev.matrix @ self.jac  # bin widths in ln g, linear in S
        self.bins = self.width if bins else None
        self.log_scale = np.log(FIT_SCALE)
        self.kappa = np.ones(self.n_lev)
        self._key = None
        n_kj = sp.csr_matrix((np.ones(n), (lev_idx, obs.image)), shape=(self.n_lev, obs.n_images))
        self._n_kj = n_kj.toarray()

    def set_kappa(self, kappa: np.ndarray) -> None:
        self.kappa, self._key = np.asarray(kappa, np.float64), None

    def unpack(self, p):
        s = np.concatenate([[0.0], np.cumsum(p[:self.nv])])
        lg = self.log_scale + s - self.w_mean @ s
        t = self.t_fixed if self.t_fixed is not None else np.exp(np.concatenate([[0.0], p[self.nv:]]))
        return lg, t

    def _reject(self, p):
        """A trial step beyond floating point, or an observed DN with an empty bin: value +inf (trust region shrinks)."""
        self._key, self._val, self._grad = p.copy(), np.inf, np.zeros_like(p)

    def _eval(self, p):
        """Value and gradient at ``p`` (kept, with what the Hessian needs)."""
        if self._key is not None and np.array_equal(p, self._key):
            return
        obs, lev = self.obs, self.lev
        lg_k, t = self.unpack(p)
        g = np.exp(lev.matrix @ lg_k)
        if not (np.all(np.isfinite(g)) and np.all(g > 0) and np.all(np.isfinite(t))):
            return self._reject(p)
        x, kap = g[self.lev_idx], self.kappa[self.lev_idx]
        ct = t[obs.image] if obs.factor is None else t[obs.image] * obs.factor
        big_x = np.bincount(obs.pixel, kap * x, obs.n_pixels)
        big_c = np.bincount(obs.pixel, kap * ct, obs.n_pixels)
        r = big_x / big_c
        mu = r[obs.pixel] * ct
        # kappa x ln(kappa mu) - kappa mu - lnGamma(kappa x + 1) + ln kappa, written as the small per-observation
        # kappa (x ln(mu/x) - (mu - x)) plus per level -stirling_remainder(kappa g) + ln kappa: summing terms of
        # ~x ln mu first would cancel them and lose the precision the trust region's decrease ratio needs
        lmu = np.log(mu)
        dev = kap * (x * (lmu - np.log(g)[self.lev_idx]) - (mu - x))
        kg = self.kappa * g
        val = float(np.sum(dev)) + float(self.cnt @ (np.log(self.kappa) - stirling_remainder(kg)))
        slm = np.bincount(self.lev_idx, lmu, self.n_lev)
        sm = np.bincount(self.lev_idx, mu, self.n_lev)
        d_lg = kg * (slm + self.cnt * (np.log(self.kappa) - digamma(kg + 1.0)))
        grad = [self.jac.T @ (self.lev.matrix.T @ d_lg)]  # to ln g over the range, then to the knots, then to S
        if self.t_fixed is None:
            grad.append(np.bincount(obs.image, kap * (x - mu), obs.n_images)[1:])
        self._key, self._hess = p.copy(), None
        ps = self.pen @ p[:self.nv]
        if self.bins is not None:
            w = self.bins @ p[:self.nv]
            have = self.cnt > 0
            if np.any(w[have] <= 0):
                return self._reject(p)
            wh = np.where(have, w, 1.0)
            val += float(self.cnt[have] @ np.log(w[have]))
            grad[0] = grad[0] + self.bins.T @ np.where(have, self.cnt / wh, 0.0)
            self._bin_h = np.where(have, self.cnt / wh**2, 0.0)
        self._val = (-val + 0.5 * float(p[:self.nv] @ ps)) / self.scale
        self._grad = -np.concatenate(grad) / self.scale
        self._grad[:self.nv] += ps / self.scale
        self.state = (g, t, r, x, mu)
        self._parts = (d_lg, ct, big_x, big_c)
        self._sums = (slm, sm)

    def _right_jac(self, a: np.ndarray) -> np.ndarray:
        """``a @ jac`` in O(size of a): jac is "ones below the diagonal" minus the rank one ``1 tail^T``."""
        c = np.cumsum(a, axis=1)  # sum over knots k <= m; the sum over k > m is the total minus it
        total = c[:, -1:]
        return total * (1.0 - self.tail[None, :]) - c[:, :-1]

    def _to_knots(self, h: np.ndarray) -> np.ndarray:
        """``M^T h M`` for the levels' interpolation M (sparse; the identity when every level is a knot)."""
        if self.m_sp is None:
            return h
        return (self.m_sp.T @ (self.m_sp.T @ h).T).T

    def _hessian(self):
        g, t, r, x, mu = self.state
        d_lg, ct, big_x, big_c = self._parts
        kap = self.kappa
        h_g = kap[:, None] * (self.bt @ sp.diags(1.0 / big_x) @ self.b).toarray() * kap[None, :]
        h_g -= np.diag(self.cnt * kap**2 * polygamma(1, kap * g + 1.0))
        h_lg = g[:, None] * h_g * g[None, :] + np.diag(d_lg)  # in ln g over the levels
        if self.bins is not None:  # the bins' term, in ln g over the levels too (banded)
            h_lg -= (self.bw_sp.T @ sp.diags(self._bin_h) @ self.bw_sp).toarray()
        h_k = self._to_knots(h_lg)
        blocks = [[self._right_jac(self._right_jac(h_k).T) - self.pen]]  # jac^T h_k jac (h_k symmetric)
        if self.t_fixed is None:
            h_uu, h_lgu = self._exposure_blocks(ct, big_x, big_c, g)
            cross = self._right_jac((h_lgu if self.m_sp is None else self.m_sp.T @ h_lgu).T).T  # (nv, n_img-1)
            blocks[0].append(cross)
            blocks.append([cross.T, h_uu])
        return -np.block(blocks) / self.scale

    def _exposure_blocks(self, ct, big_x, big_c, g):
        """Hessian block of u_j = ln t_j (j >= 1) and its cross block with ln g."""
        obs = self.obs
        kct = self.kappa[self.lev_idx] * ct
        q = sp.csr_matrix((kct / big_c[obs.pixel], (obs.pixel, obs.image)), shape=(obs.n_pixels, obs.n_images))
        xq = sp.diags(big_x) @ q
        h_uu = (q.T @ xq).toarray() - np.diag(np.asarray(xq.sum(axis=0)).ravel())
        h_gu = self.kappa[:, None] * (self._n_kj - (self.bt @ q).toarray())  # d2 L / dg_k du_j
        return h_uu[1:, 1:], (g[:, None] * h_gu)[:, 1:]

    def fun(self, p):
        self._eval(p)
        return self._val, self._grad

    def hess(self, p):
        self._eval(p)
        if self._hess is None:
            self._hess = self._hessian()
        return self._hess

    def best_noise(self, p) -> tuple[float, np.ndarray]:
        """The count scale ln s maximising the DN's likelihood with the shape fixed, and the quantisation weights
        at that scale (the likelihood is eq. 8 with the weights, plus ``N ln s``, the bins' Jacobian)."""
        self._eval(p)
        g, n = self.state[0], len(self.obs)
        slm, sm = self._sums
        s0 = np.exp(self.log_scale)
        gt, slmt, smt = g / s0, slm - self.cnt * self.log_scale, sm / s0  # at scale 1
        w = np.abs(self.width @ p[:self.nv])

        def neg(ls):
            sc = np.exp(ls)
            kap = quantisation_weights(sc * gt, w)
            return -(level_log_likelihood(sc * gt, kap, self.cnt, slmt + self.cnt * ls, sc * smt) + n * ls)

        ls = float(minimize_scalar(neg, bounds=(0.0, 20.0), method="bounded", options={"xatol": 1e-4}).x)
        return ls, quantisation_weights(np.exp(ls) * gt, w)
