r"""Solver updates of the PhotometryTK manual, section 7 (eqs. 1 and 3-7) as partial sums over a tile.

Notation: image stack index :math:`k` first, then pixels; ``I`` is the observed
value, ``R`` the reflectance, ``T`` the per-image exposure, ``w`` the product of the
blending weight and the shadow mask :math:`S w` (zero where unusable).

Pixel arrays must be finite (zero where unusable): a zero weight then removes an
observation from every sum without any masking pass.

Every quantity that couples tiles (exposure and phase-coefficient updates, the
cost :math:`Q`) is returned as float64 *sums* so a driver can add them over all
tiles in a fixed order and apply the update once.  Pixel arrays stay float32.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _f64sum(x, axis=None):
    return np.sum(x, axis=axis, dtype=np.float64)


def albedo_terms(values, tr, w):
    r"""Per-observation numerator and denominator terms of eqs. 3 and 6: :math:`(V\,TR\,Sw,\ (TR)^2 Sw)`.

    With :math:`V = I` their sums over :math:`k` give eq. 3, :math:`A = \sum V TRSw / \sum (TR)^2 Sw`;
    with the residual :math:`V = I - ATR` they give the Gauss-Newton step of eq. 6,
    :math:`\delta A = \sum V TRSw / \sum (TR)^2 Sw`.  ``tr`` is :math:`T^k R^k_{ij}`, ``w`` is
    :math:`S w`; the dtype of the inputs is kept (float32 in the solver, float64 in the
    legacy mode, which accumulates them image by image in float32).
    """
    trw = tr * w
    return values * trw, tr * trw


def cost_terms(res, w):
    r"""Per-observation terms :math:`(I - ATR)^2 S w` of the cost of eq. 1 (dtype of the inputs)."""
    return res * res * w


def exposure_update(t, num, den):
    """Apply eq. 4 from summed ``(num, den)``; images without data keep their exposure."""
    t = np.asarray(t, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / den, t)


def phase_sums(res, a, t, dr, r, w):
    r"""Normal equations of the update of the model's fitted parameters (eq. 5) over a tile.

    Columns of the Jacobian of the prediction :math:`A T R` (``dr`` holds
    :math:`\partial R/\partial p_m` from the photometric model, e.g. for eq. 2
    :math:`\partial R/\partial c_1 = -\alpha e^{-c_1\alpha} G` and :math:`\partial R/\partial c_2 = G`):

    * :math:`J_m = A T\,\partial R/\partial p_m` for each fitted parameter,
    * :math:`J_0 = A T R` -- the prediction itself, i.e. a global brightness scale (last).

    Returns ``(JtWJ, JtWr)`` of shapes ``(P+1, P+1)`` and ``(P+1,)`` (float64).  Eq. 5
    uses the diagonal entries of the first P columns.
    """
    at = np.nan_to_num(a)[None] * np.asarray(t, np.float32)[:, None, None]
    cols = [at * d for d in dr] + [at * r]
    n = len(cols)
    jtj = np.empty((n, n))
    jtr = np.empty(n)
    for m, jm in enumerate(cols):
        jmw = jm * w
        jtr[m] = _f64sum(jmw * res)
        for k in range(m, n):
            jtj[m, k] = jtj[k, m] = _f64sum(jmw * cols[k])
    return jtj, jtr


def phase_update_seed(c, jtj, jtr):
    r"""The seed's update (eq. 5): an independent Gauss-Newton step for each fitted parameter."""
    c = np.asarray(c, dtype=np.float64).copy()
    for m in range(len(c)):
        if jtj[m, m] > 0:
            c[m] += jtr[m] / jtj[m, m]
    return c


def phase_update_damped(c, jtj, jtr, alpha_range, curve, damping=0.1, max_rel_change=0.02):
    r"""Damped joint update of the fitted parameters with the global scale projected out.

    Solves the (P+1)-parameter Levenberg-Marquardt system for :math:`(\delta p, \delta s)`
    -- :math:`s` absorbs any change that a global brightness scale (free between
    :math:`A` and :math:`T`) explains equally well -- and keeps only :math:`\delta p`.
    The step is then shortened so that ``curve(alpha, params)`` (the model's
    reflectance against phase angle) changes by at most ``max_rel_change`` anywhere in
    the observed phase-angle range ``alpha_range`` (radians).  A poorly conditioned
    parameter set therefore moves slowly instead of wrecking the albedo.
    """
    c = np.asarray(c, dtype=np.float64)
    n = len(c)
    if not np.all(np.isfinite(jtj)) or jtj[n, n] <= 0:
        return c.copy()
    m = jtj + damping * np.diag(np.diag(jtj))
    try:
        step = np.linalg.solve(m, jtr)[:n]
    except np.linalg.LinAlgError:
        return c.copy()
    alphas = np.linspace(alpha_range[0], alpha_range[1], 9)
    p0 = curve(alphas, c)
    p1 = curve(alphas, c + step)
    rel = float(np.max(np.abs(p1 / p0 - 1.0))) if np.all(p0 > 0) else np.inf
    if rel > max_rel_change:
        step = step * (max_rel_change / rel)
    return c + step


def error_terms(image, a, tr, w_shadow):
    r"""Per-observation numerator terms :math:`(I/(TR) - A)^2 S w` of eq. 7 (0 where :math:`Sw = 0`)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        dev = np.where(w_shadow > 0, image / tr - a, 0.0)
    return dev * dev * w_shadow


@dataclass
class PassSums:
    """Sums one iteration needs (float64): the global ones, accumulated tile by tile, or a tile's or a block's own.

    ``index``: the global numbers of the images whose exposure sums these are, sorted (a tile's or a block's
    images); None: all ``n_images`` in order (the global sums).  ``jtj``/``jtr`` are the normal equations of
    the P fitted parameters plus the global scale.
    """

    n_images: int
    n_params: int = 0
    q: float = 0.0
    exp_num: np.ndarray = field(default=None)
    exp_den: np.ndarray = field(default=None)
    jtj: np.ndarray = field(default=None)
    jtr: np.ndarray = field(default=None)
    alpha_min: float = np.inf
    alpha_max: float = -np.inf
    n_obs: int = 0
    index: np.ndarray | None = None
    #: FLOAT_HAZE: the joint (T, H) step's gradient and reduced normal matrix over the images of ``index``,
    #: interleaved (T_k, H_k) (``engine/haze_kernels``; :mod:`.haze`); None without haze.
    haze_g: np.ndarray | None = None
    haze_s: np.ndarray | None = None
    #: The global sums' haze terms: each tile's ``(index, haze_g, haze_s)`` in tile order (:func:`.haze.assemble`).
    haze_parts: list = field(default_factory=list)
    #: FLOAT_HAZE: the noise-weighted residual sum of squares at the eliminated albedo, the observations and
    #: the pixels it sums over (the noise variance of the haze's standard errors, :func:`.haze.standard_errors`).
    haze_rss: np.ndarray | None = None

    def __post_init__(self):
        if self.index is not None:
            self.index = np.asarray(self.index)
            self.n_images = len(self.index)
        if self.exp_num is None:
            self.exp_num = np.zeros(self.n_images)
        if self.exp_den is None:
            self.exp_den = np.zeros(self.n_images)
        if self.jtj is None:
            self.jtj = np.zeros((self.n_params + 1, self.n_params + 1))
        if self.jtr is None:
            self.jtr = np.zeros(self.n_params + 1)

    def add(self, part) -> None:
        """Accumulate one tile's sums (``part.index`` maps its images to global ones).

        Call in a fixed tile order: float64 addition is then reproducible, so results
        are identical for any number of workers.  Into sums with an ``index`` (a tile's), the
        part's images must be among them.
        """
        at = part.index if self.index is None else np.searchsorted(self.index, part.index)
        if part.haze_g is not None:
            if part.haze_rss is not None:
                self.haze_rss = part.haze_rss.copy() if self.haze_rss is None else self.haze_rss + part.haze_rss
            if self.index is None:
                self.haze_parts.append((part.index, part.haze_g, part.haze_s))
            else:
                at2 = np.stack([2 * at, 2 * at + 1], axis=1).reshape(-1)
                if self.haze_g is None:
                    self.haze_g, self.haze_s = np.zeros(2 * self.n_images), np.zeros((2 * self.n_images,) * 2)
                self.haze_g[at2] += part.haze_g
                self.haze_s[np.ix_(at2, at2)] += part.haze_s
        self.q += part.q
        np.add.at(self.exp_num, at, part.exp_num)
        np.add.at(self.exp_den, at, part.exp_den)
        self.jtj += part.jtj
        self.jtr += part.jtr
        self.alpha_min = min(self.alpha_min, part.alpha_min)
        self.alpha_max = max(self.alpha_max, part.alpha_max)
        self.n_obs += part.n_obs
