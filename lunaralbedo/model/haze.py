r"""Per-image additive haze solved jointly with the exposures (``FLOAT_HAZE 1``).

Scattered light and dark-level residue add an offset per image (ASP ``sfs`` floats a
haze per image for the same reason):

.. math:: I^k_{ij} = T^k A_{ij} R^k_{ij} + H_k .

Eq. 1's cost becomes :math:`Q = \sum w (I - H_k - A T^k R)^2`.  Its albedo update is eq. 3
of the PhotometryTK manual on :math:`I - H_k`.  Alternating updates of :math:`A`, :math:`T`
and :math:`H` crawl: the direction :math:`A \to A + \beta/R`, :math:`H_k \to H_k - T^k\beta`
changes Q only through the spread of :math:`R` among the images of a pixel, so every
alternating step moves along it by a small fraction.  Instead, each pass takes one
Gauss-Newton step in all :math:`\theta = (T_k, H_k)` at once *with the albedo eliminated*
(variable projection; the Schur complement of the albedo block, which is diagonal: one
unknown per pixel).  With the per-pixel sums of :mod:`lunaralbedo.engine.haze_kernels`,
the reduced normal equations are

.. math:: (S + \mu\,\mathrm{diag}\,S)\,\delta = g, \qquad \sum_k \delta T_k / T_k = 0,

the constraint (a bordered system, Lagrange multiplier) removing the scale that
:math:`A\,T` leaves free, :math:`\mu` (:data:`DAMPING`) a small Levenberg damping.  With
``EXPOSURE_MODE fixed`` only the haze moves; with ``prior`` the Gaussian prior of
:mod:`.exposure_prior` adds :math:`\sigma_n^2\lambda_k` to :math:`S_{T_kT_k}` and
:math:`\sigma_n^2\lambda_k (T^k_0 - T^k)` to :math:`g_{T_k}` and the scale is the prior's.

An image whose haze and exposure cannot be told apart (too little contrast: its
:math:`A R` nearly constant) has a nearly singular 2 x 2 block; :func:`inseparable`
names it.  Pure NumPy/SciPy, no I/O.
"""
from __future__ import annotations

import numpy as np

#: Levenberg damping of the joint step, relative to the diagonal.
DAMPING = 1e-6
#: An image's exposure and haze are inseparable when :math:`1 - \rho^2` of its 2 x 2 block is below this.
SEPARATION_MIN = 1e-3
#: Largest relative change of an exposure in one step (the step is shortened to it).
MAX_EXPOSURE_STEP = 0.25
#: The haze has settled when the error left after a joint step, estimated from the last two steps, is
#: below this fraction of the noise's standard deviation per observation (:func:`settled`).
SETTLED = 0.1


def settled(step: float, previous: float | None, rss) -> bool:
    r"""True when the joint steps can stop: the haze and the exposures held at the last step's (the photometric
    parameters go on).

    ``step``, ``previous``: the largest change of any image's haze in the last and the one before (None:
    none before); ``rss``: the pass's noise-weighted squared residuals, observations and pixels
    (:func:`standard_errors`).  The steps contract by :math:`\rho = s_n / s_{n-1}` (Gauss-Newton near
    its solution), so the error left is about :math:`\rho\,s_n = s_n^2 / s_{n-1}`; settled when that is
    at most :data:`SETTLED` :math:`\sigma_n`, :math:`\sigma_n^2 = \mathrm{rss}/(n_{obs} - n_{pix})`, and
    the steps do contract (:math:`\rho < 1/2`).
    """
    if previous is None or not previous > 0:
        return step == 0.0
    dof = float(rss[1]) - float(rss[2])
    if not dof > 0:
        return False
    noise = np.sqrt(max(float(rss[0]), 0.0) / dof)
    return step <= 0.5 * previous and step * step / previous <= SETTLED * noise


def assemble(n_images: int, parts) -> tuple[np.ndarray, "object"]:
    """The global ``g`` (``2K``) and sparse ``S`` (CSR) from per-tile ``(index, g, s)`` (local images ``index``), in order."""
    from scipy.sparse import coo_matrix

    g = np.zeros(2 * n_images)
    rows, cols, vals = [], [], []
    for index, g_loc, s_loc in parts:
        index = np.asarray(index, np.int64)
        at = np.stack([2 * index, 2 * index + 1], axis=1).reshape(-1)
        np.add.at(g, at, g_loc)
        nz = np.nonzero(s_loc)
        rows.append(at[nz[0]])
        cols.append(at[nz[1]])
        vals.append(s_loc[nz])
    r, c = (np.concatenate(x) if x else np.zeros(0, np.int64) for x in (rows, cols))
    v = np.concatenate(vals) if vals else np.zeros(0)
    return g, coo_matrix((v, (r, c)), shape=(2 * n_images,) * 2).tocsr()


def joint_step(t, h, g, s, mode: str = "solve", t0=None, prior_weight=None, noise_var: float = 1.0):
    r"""One damped Gauss-Newton step of ``(T, H)`` (module docstring); returns the new ``(t, h)`` (float64).

    ``mode``: ``solve`` (the scale constraint), ``fixed`` (exposures kept), ``prior``
    (``t0``, ``prior_weight`` :math:`\lambda_k`, ``noise_var`` :math:`\sigma_n^2`).  Images
    without observations keep their values.
    """
    from scipy.sparse import bmat, csr_matrix, diags
    from scipy.sparse.linalg import spsolve

    t, h = np.asarray(t, np.float64), np.asarray(h, np.float64)
    k = len(t)
    g = np.asarray(g, np.float64).copy()
    s = csr_matrix(s, dtype=np.float64)
    d = s.diagonal().copy()
    if mode == "prior":
        extra = noise_var * np.asarray(prior_weight, np.float64)
        d[0::2] += extra
        g[0::2] += extra * (np.asarray(t0, np.float64) - t)
        s = s + diags(np.repeat(extra, 2) * np.tile([1.0, 0.0], k))
    keep = d > 0
    if mode == "fixed":
        keep[0::2] = False
    # unknowns without data (or fixed): identity rows, zero right-hand side
    free = diags(keep.astype(np.float64))
    a = free @ s @ free + diags(np.where(keep, DAMPING * d, 1.0))
    rhs = np.where(keep, g, 0.0)
    if mode == "solve":
        c = np.zeros(2 * k)
        c[0::2] = np.where(keep[0::2], 1.0 / t, 0.0)
        a = bmat([[a, csr_matrix(c[:, None])], [csr_matrix(c[None, :]), None]], format="csc")
        rhs = np.append(rhs, 0.0)
    delta = np.asarray(spsolve(a.tocsc(), rhs), np.float64)[: 2 * k]
    dt, dh = delta[0::2], delta[1::2]
    worst = np.max(np.abs(dt) / t) if k else 0.0
    if worst > MAX_EXPOSURE_STEP:
        dt, dh = dt * (MAX_EXPOSURE_STEP / worst), dh * (MAX_EXPOSURE_STEP / worst)
    return t + dt, h + dh


def inseparable(s) -> np.ndarray:
    r"""Indices of the images whose 2 x 2 block :math:`[[S_{TT}, S_{TH}], [S_{TH}, S_{HH}]]` has
    :math:`1 - S_{TH}^2/(S_{TT} S_{HH}) <` :data:`SEPARATION_MIN` (haze and exposure not separable)."""
    d = s.diagonal()
    off = np.asarray(s[np.arange(0, len(d), 2), np.arange(1, len(d), 2)]).ravel()
    stt, shh = d[0::2], d[1::2]
    with np.errstate(divide="ignore", invalid="ignore"):
        sep = 1.0 - off * off / (stt * shh)
    return np.flatnonzero((stt > 0) & (shh > 0) & (sep < SEPARATION_MIN))


def standard_errors(t, s, rss, mode: str = "solve", prior_weight=None) -> np.ndarray:
    r"""The standard error of each image's haze (DRG units; NaN without data): the Cramér-Rao bound of the
    linearised least-squares problem, :math:`\sigma_n^2` times the haze diagonal of the inverse of the
    reduced normal matrix ``s`` (the albedo eliminated, module docstring), bordered by the scale
    constraint in ``solve`` mode, exposures removed in ``fixed`` mode, the prior's
    :math:`\sigma_n^2\lambda_k` added in ``prior`` mode.

    ``rss``: the sum of the noise-weighted squared residuals, the observations and the pixels
    it runs over; :math:`\sigma_n^2 = \mathrm{rss} / (n_{obs} - n_{pix} - n_{free})`.  Along a chain
    of images these errors grow with the distance from its best-pinned image (docs/solver.md).
    """
    t = np.asarray(t, np.float64)
    k = len(t)
    a = np.asarray(s.toarray() if hasattr(s, "toarray") else s, np.float64).copy()
    d = np.diag(a).copy()
    keep = d > 0
    if mode == "fixed":
        keep[0::2] = False
    n_free = int(keep.sum()) - (mode == "solve")
    dof = float(rss[1]) - float(rss[2]) - n_free
    noise_var = float(rss[0]) / dof if dof > 0 else np.nan
    if mode == "prior":
        a[np.arange(0, 2 * k, 2), np.arange(0, 2 * k, 2)] += noise_var * np.asarray(prior_weight, np.float64)
    idx = np.flatnonzero(keep)
    m = a[np.ix_(idx, idx)]
    if mode == "solve":
        c = np.where(idx % 2 == 0, 1.0 / t[idx // 2], 0.0)
        m = np.block([[m, c[:, None]], [c[None, :], np.zeros((1, 1))]])
    try:
        inv = np.linalg.inv(m)[: len(idx), : len(idx)]
    except np.linalg.LinAlgError:
        return np.full(k, np.nan)
    var = np.full(2 * k, np.nan)
    var[idx] = np.diag(inv) * noise_var
    return np.sqrt(np.clip(var[1::2], 0, None))
