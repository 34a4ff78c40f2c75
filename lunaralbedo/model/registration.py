r"""Image-to-DEM registration: the Gauss-Newton normal equations of eq. 1 in a ground shift per image.

The cost is eq. 1 of the PhotometryTK manual with each image moved on the ground by its
shift :math:`\mathbf{s}_k = (s_e, s_n)` (metres east, north, added to the image's stated
georeference):

.. math:: Q = \sum_k \sum_{g} w_{kg}\,\bigl(I_k(\mathbf{g} - \mathbf{s}_k) - T_k A_g R_{kg}\bigr)^2

over ground pixels :math:`g` of a common grid.  The reflectance :math:`R_{kg}` comes from the
DEM's normals and the image's Sun and spacecraft, so it stays where the DEM is: a shifted
image no longer matches the shading of the terrain, and the shift is anchored by the DEM, not
by one chosen image.  The unknowns are the albedo :math:`A_g` (one per pixel), and per image
:math:`\theta_k = (T_k, s_{e,k}, s_{n,k})`.  With the residual :math:`r = I - TAR`, the
Jacobians are :math:`\partial r/\partial A_g = -T_k R_{kg}`,
:math:`\partial r/\partial \theta_k = (-A_g R_{kg},\ \partial I_k/\partial s_e,\ \partial I_k/\partial s_n)`.
The Gauss-Newton normal matrix has a diagonal albedo block :math:`D_g = \sum_k w T_k^2 R_{kg}^2`
(eq. 3's denominator); eliminating it (the Schur complement, as in bundle adjustment:
Triggs et al., "Bundle adjustment - a modern synthesis") leaves a :math:`3K \times 3K` system

.. math:: S = \mathrm{diag}_k\Bigl(\sum_g w J_\theta J_\theta^\top\Bigr) - \sum_g \frac{b_g b_g^\top}{D_g},
          \qquad b_{g,k} = w_{kg}\,(-T_k R_{kg})\,J_{\theta,kg}

whose right-hand side is :math:`\sum_g w J_\theta r - \sum_g b_g h_{A,g}/D_g`.  A pixel seen by
one image only cancels out of :math:`S`: the shifts are measured where images overlap each
other and the DEM's shading.  The albedo is then set by eq. 3 (:math:`Q` is quadratic in
:math:`A`; variable projection).  A global scale of :math:`T` against :math:`A` is free
(eq. 1); it is the one null direction of :math:`S`, fixed for the covariance by a constraint
that leaves the shifts' variances unchanged.  Standard errors: :math:`\sigma^2 S^{-1}` with
:math:`\sigma^2 = Q / (n - m)` (observations minus unknowns).

**A robust loss** (the solve's ``ROBUST_LOSS``, :mod:`.outliers`): with a few unrejected defects (hot
spots, dropout rows) the least-squares :math:`Q` is dominated by them, and the whole set of
shifts moves to where they hurt least (a common shift of a pixel was measured).  The robust
cost replaces each :math:`w r^2` by :math:`\sigma_k^2\,2\rho(\sqrt{w}\,r/\sigma_k)`
(:func:`robust_cost`), :math:`\sigma_k` image k's robust standard deviation of
:math:`\sqrt{w}\,r` (:func:`residual_scales`), held through a level; its Gauss-Newton steps are
those above with the weights :math:`w\,m` of iteratively reweighted least squares
(:func:`reweighted`), and the albedo of a pixel is eq. 3 with those weights.

Pure NumPy/SciPy; float64 sums in image order, then pixel order (``np.bincount``), so the
result does not depend on how the work was split.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import outliers
from .updates import albedo_terms


@dataclass
class ImageObs:
    """One image's observations on the registration grid (1-D, float64 or float32).

    ``pix``: flat grid index; ``value``: :math:`I_k(\\mathbf g - \\mathbf s_k)`; ``d_east``,
    ``d_north``: its derivatives in the shift (per metre); ``r``: the reflectance; ``w``: the weight;
    ``w_east``, ``w_north``: the weight's derivatives in the shift when it depends on it (or None).
    """

    pix: np.ndarray
    value: np.ndarray
    d_east: np.ndarray
    d_north: np.ndarray
    r: np.ndarray
    w: np.ndarray
    w_east: np.ndarray | None = None
    w_north: np.ndarray | None = None


def albedo(obs: list[ImageObs], exposure: np.ndarray, n_grid: int) -> np.ndarray:
    r"""Eq. 3 on the grid: :math:`A_g = \\sum_k w I T R / \\sum_k w (T R)^2` (float64; NaN where no image)."""
    num, den = np.zeros(n_grid), np.zeros(n_grid)
    for t, o in zip(exposure, obs):
        nk, dk = albedo_terms(o.value.astype(np.float64), t * o.r.astype(np.float64), o.w.astype(np.float64))
        num += np.bincount(o.pix, nk, n_grid)
        den += np.bincount(o.pix, dk, n_grid)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / den, np.nan)


def exposures(obs: list[ImageObs], a: np.ndarray, old: np.ndarray) -> np.ndarray:
    r"""Eq. 4 with the albedo fixed: :math:`T_k = \\sum w A R I / \\sum w (A R)^2` (``old`` where no observation)."""
    out = np.array(old, dtype=np.float64)
    for k, o in enumerate(obs):
        ar = np.nan_to_num(a[o.pix]) * o.r
        den = float(np.sum(o.w * ar * ar, dtype=np.float64))
        if den > 0:
            out[k] = float(np.sum(o.w * ar * o.value, dtype=np.float64)) / den
    return out


def cost(obs: list[ImageObs], exposure: np.ndarray, a: np.ndarray) -> tuple[float, int]:
    """``(Q, observations)``: eq. 1 over the observations (pixels without albedo count as A = 0) and their number."""
    q, n = 0.0, 0
    for t, o in zip(exposure, obs):
        res = o.value - t * np.nan_to_num(a[o.pix]) * o.r
        q += float(np.sum(o.w * res * res, dtype=np.float64))
        n += len(o.w)
    return q, n


def _normalised(o: ImageObs, t: float, a: np.ndarray, scale: float) -> np.ndarray:
    r""":math:`\sqrt{w}\,r/\sigma` of one image's observations."""
    return np.sqrt(o.w) * (o.value - t * np.nan_to_num(a[o.pix]) * o.r) / scale


def residual_scales(obs: list[ImageObs], exposure: np.ndarray, a: np.ndarray, n_grid: int) -> np.ndarray:
    r"""Per image the robust standard deviation (:func:`.outliers.robust_sigma`) of :math:`\sqrt{w}\,r` over its
    observations of pixels another image sees too (where one image alone sees a pixel its residual is 0); 1 where
    there are none."""
    seen = np.zeros(n_grid)
    for o in obs:
        seen += np.bincount(o.pix, minlength=n_grid)
    out = np.ones(len(obs))
    for k, (t, o) in enumerate(zip(exposure, obs)):
        shared = seen[o.pix] > 1
        sig = outliers.robust_sigma(_normalised(o, t, a, 1.0)[shared]) if shared.any() else float("nan")
        out[k] = sig if np.isfinite(sig) and sig > 0 else 1.0
    return out


def reweighted(obs: list[ImageObs], exposure: np.ndarray, a: np.ndarray, scales, loss: str, k: float) -> list[ImageObs]:
    r"""The observations with their weights (and the weights' derivatives) times the IRLS factors of ``loss``
    (:func:`.outliers.loss_weights` of :math:`\sqrt{w}\,r/\sigma_k`); the same list for ``none``."""
    if loss == "none":
        return obs
    out = []
    for t, o, sc in zip(exposure, obs, scales):
        m = outliers.loss_weights(_normalised(o, t, a, sc), loss, k)
        out.append(replace(o, w=o.w * m, w_east=None if o.w_east is None else o.w_east * m,
                           w_north=None if o.w_north is None else o.w_north * m))
    return out


def robust_albedo(obs: list[ImageObs], exposure: np.ndarray, n_grid: int, scales, loss: str, k: float) -> np.ndarray:
    """The albedo of the robust cost: eq. 3, then eq. 3 again with the IRLS weights of its residuals (one IRLS step
    from least squares; :func:`albedo` for ``none``)."""
    a = albedo(obs, exposure, n_grid)
    return a if loss == "none" else albedo(reweighted(obs, exposure, a, scales, loss, k), exposure, n_grid)


def robust_cost(obs: list[ImageObs], exposure: np.ndarray, a: np.ndarray, scales, loss: str, k: float) -> tuple[float, int]:
    r"""``(Q, observations)`` of the robust cost :math:`\sum_k \sigma_k^2 \sum 2\rho(\sqrt{w}\,r/\sigma_k)`
    (:func:`.outliers.loss_rho`; :func:`cost` for ``none``)."""
    if loss == "none":
        return cost(obs, exposure, a)
    q, n = 0.0, 0
    for t, o, sc in zip(exposure, obs, scales):
        q += float(sc * sc) * float(np.sum(outliers.loss_rho(_normalised(o, t, a, sc), loss, k), dtype=np.float64))
        n += len(o.w)
    return q, n


@dataclass
class Normal:
    """The reduced normal equations: ``matrix`` (3K x 3K), ``rhs`` (3K), cost ``q``, ``n`` observations,
    ``pixels`` (grid pixels seen); unknowns ordered ``(T_k, s_east_k, s_north_k)`` image by image."""

    matrix: np.ndarray
    rhs: np.ndarray
    q: float
    n: int
    pixels: int


def normal_equations(obs: list[ImageObs], exposure: np.ndarray, a: np.ndarray, n_grid: int) -> Normal:
    """The Schur-reduced Gauss-Newton system of :math:`Q` in the images' exposures and shifts (module docstring)."""
    k_n = len(obs)
    d = np.zeros(n_grid)
    for t, o in zip(exposure, obs):
        d += np.bincount(o.pix, o.w * (t * o.r) ** 2, n_grid)
    root = np.sqrt(d)
    with np.errstate(divide="ignore"):
        inv_root = np.where(d > 0, 1.0 / np.where(d > 0, root, 1.0), 0.0)
    c = np.zeros((3 * k_n, 3 * k_n))
    h = np.zeros(3 * k_n)
    h_a = np.zeros(n_grid)
    us = []
    q, n = 0.0, 0
    for k, (t, o) in enumerate(zip(exposure, obs)):
        av = np.nan_to_num(a[o.pix])
        w = o.w.astype(np.float64)
        res = o.value - t * av * o.r
        jac = np.stack([-av * o.r, o.d_east, o.d_north]).astype(np.float64)  # (3, n_k)
        c[3 * k:3 * k + 3, 3 * k:3 * k + 3] = (jac * w) @ jac.T
        h[3 * k:3 * k + 3] = (jac * w) @ res
        if o.w_east is not None:  # Q = sum w(s) r^2: half of its derivative through the weights too
            h[3 * k + 1] += 0.5 * float(np.sum(o.w_east * res * res))
            h[3 * k + 2] += 0.5 * float(np.sum(o.w_north * res * res))
        ja = -t * o.r
        h_a += np.bincount(o.pix, w * ja * res, n_grid)
        us.append((w * ja * inv_root[o.pix]) * jac)  # b_g / sqrt(D_g)
        q += float(np.sum(w * res * res))
        n += len(o.pix)
    g = h_a * inv_root
    spread = np.zeros((3, n_grid))  # one image's b_g / sqrt(D_g) on the grid at a time
    span = [(int(o.pix.min()), int(o.pix.max())) if len(o.pix) else (1, 0) for o in obs]
    for k, (o, u) in enumerate(zip(obs, us)):
        h[3 * k:3 * k + 3] -= u @ g[o.pix]
        spread[:, o.pix] = u
        for j in range(k, k_n):  # the pairs that can share a pixel: sum_g b_gj b_gk^T / D_g
            if span[j][0] > span[k][1] or span[k][0] > span[j][1]:
                continue
            blk = us[j] @ spread[:, obs[j].pix].T
            c[3 * j:3 * j + 3, 3 * k:3 * k + 3] -= blk
            if j != k:
                c[3 * k:3 * k + 3, 3 * j:3 * j + 3] -= blk.T
        spread[:, o.pix] = 0.0
    return Normal(c, h, q, n, int(np.count_nonzero(d > 0)))


def gauge_fixed(normal: Normal, exposure: np.ndarray) -> np.ndarray:
    """``S`` plus a constraint on the free scale of the exposures (the direction :math:`\\delta T \\propto T`)."""
    v = np.zeros(len(normal.rhs))
    v[0::3] = exposure
    v /= np.linalg.norm(v)
    scale = max(float(np.trace(normal.matrix)) / len(v), 1e-300)
    return normal.matrix + scale * np.outer(v, v)


def step(normal: Normal, exposure: np.ndarray, damping: float) -> np.ndarray:
    """The Levenberg-Marquardt step ``(dT, ds_east, ds_north)`` per image, shape ``(K, 3)``: the solution of
    :math:`(S + \\lambda\\,\\mathrm{diag}\\,S)\\,\\delta = -h` with the gauge fixed (:func:`gauge_fixed`)."""
    m = gauge_fixed(normal, exposure)
    diag = np.diag(m).copy()
    diag[diag <= 0] = 1.0
    m = m + damping * np.diag(diag)
    try:
        delta = np.linalg.solve(m, -normal.rhs)
    except np.linalg.LinAlgError:
        delta = np.linalg.lstsq(m, -normal.rhs, rcond=None)[0]
    return delta.reshape(-1, 3)


def standard_errors(normal: Normal, exposure: np.ndarray) -> np.ndarray:
    """Standard errors of ``(s_east, s_north)`` per image (metres), shape ``(K, 2)``: the diagonal of
    :math:`\\sigma^2 S^{-1}` with :math:`\\sigma^2 = Q/(n - m)`, m = the grid pixels seen plus 3 per image
    less the free scale; NaN where the shift is not determined (no overlap)."""
    m = gauge_fixed(normal, exposure)
    dof = normal.n - normal.pixels - len(normal.rhs) + 1
    sigma2 = normal.q / dof if dof > 0 else np.nan
    try:
        cov = np.linalg.inv(m)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(m)
    var = np.diag(cov).reshape(-1, 3)[:, 1:] * sigma2
    with np.errstate(invalid="ignore"):
        return np.where(var > 0, np.sqrt(np.abs(var)), np.nan)


def spline_noise_factor(frac: np.ndarray, order: int = 3, derivative: bool = False) -> np.ndarray:
    r"""Variance of white unit noise after interpolation by the spline of ``order`` at fractional pixel positions.

    An interpolating spline through pixels :math:`p_j` gives :math:`\sum_j L(x - j)\,p_j` (L its cardinal
    function); with independent pixel noise of variance :math:`\sigma^2` the value at :math:`x` has variance
    :math:`\sigma^2 v(\phi)`, :math:`v(\phi) = \sum_j L(\phi - j)^2`, :math:`\phi` the fractional part of
    :math:`x`: 1 on a pixel, 0.756 half way between two for the cubic spline (Unser, "Splines: a perfect
    fit for signal and image processing").  A cost that compares sampled values is lower between pixels by
    that factor; weighting each sample by :math:`1/v` (per axis, the product for an image) removes the pull.
    """
    from scipy import ndimage

    phis = np.linspace(0.0, 1.0, 65)
    impulse = np.zeros(64)
    impulse[32] = 1.0
    coef = ndimage.spline_filter1d(impulse, order=order, mode="mirror")
    at = np.arange(8, 56)[None, :] + phis[:, None]
    weights = ndimage.map_coordinates(coef, at.reshape(1, -1), order=order, prefilter=False, mode="mirror")
    table = np.sum(weights.reshape(at.shape) ** 2, axis=1)
    if derivative:
        table = np.gradient(table, phis)
    return np.interp(np.mod(frac, 1.0), phis, table)
