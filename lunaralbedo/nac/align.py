r"""Iterative closest point of reference points (e.g. LOLA shots) onto a DEM surface (ASP ``pc_align``, as the ASP LRO-NAC notes use it).

Pure math on NumPy arrays; all points are Moon-centred body-fixed **metres**.
The DEM is a cloud of surface points :math:`d_j` with unit normals :math:`n_j`
(from neighbouring DEM pixels).  The reference points :math:`p_i` are moved by a
rigid transform :math:`S` (rotation :math:`R`, translation :math:`t`) onto the DEM;
the transform that moves the DEM onto the reference is :math:`T = S^{-1}`.

Each iteration pairs every moved point :math:`q_i = S p_i` with its nearest DEM
point (``scipy.spatial.cKDTree``) and solves for a small update :math:`(\omega, \delta)`
(rotation vector, translation) about the pairs' centroid:

* point-to-plane (Chen & Medioni 1992): minimise
  :math:`\sum_i ((q_i + \omega \times q_i + \delta - d_i) \cdot n_i)^2`, a linear
  6x6 (or 3x3 for translation only) least-squares problem;
* point-to-point (Besl & McKay 1992): the closed-form rotation of Kabsch/Umeyama
  (SVD of the cross-covariance) and the centroid difference.

Outliers as ``pc_align``: pairs farther apart than ``max_displacement`` at the
start are dropped for good; each iteration then keeps the ``outlier_ratio``
fraction of pairs with the smallest distances (libpointmatcher's trimmed
distance filter, default 0.75 as ``pc_align --outlier-ratio``).  Iterations stop
when a step moves no point by more than ``tol_m`` or, as pairs can flip between
neighbours, the last 10 steps together move none by more than ``3 tol_m``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

METHODS = ("point-to-plane", "point-to-point")


def rotation_from_vector(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of rotation vector ``w`` (radians), Rodrigues' formula."""
    th = float(np.linalg.norm(w))
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * kx @ kx


def rigid(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """4x4 homogeneous matrix ``x -> R x + t``."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation, translation
    return m


def apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 rigid transform to ``(..., 3)`` points (metres)."""
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def _point_to_plane(q, d, n, translation_only: bool):
    c = q.mean(axis=0)
    qc = q - c
    b = np.einsum("ij,ij->i", d - q, n)
    a = n if translation_only else np.hstack([np.cross(qc, n), n])
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    if translation_only:
        return np.eye(3), x, c
    return rotation_from_vector(x[:3]), x[3:], c


def _point_to_point(q, d, translation_only: bool):
    cq, cd = q.mean(axis=0), d.mean(axis=0)
    if translation_only:
        return np.eye(3), cd - cq, cq
    h = (q - cq).T @ (d - cd)
    u, _s, vt = np.linalg.svd(h)
    sign = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    return r, cd - cq, cq


@dataclass
class IcpResult:
    """``transform`` maps the DEM (source) onto the reference; ``inliers`` marks the reference points used."""

    transform: np.ndarray
    inliers: np.ndarray
    iterations: int
    converged: bool
    history: list = field(default_factory=list)  # mean inlier distance (m) per iteration

    @property
    def inverse(self) -> np.ndarray:
        return np.linalg.inv(self.transform)


def icp(reference: np.ndarray, dem_points: np.ndarray, dem_normals: np.ndarray, method: str = "point-to-plane",
        max_displacement: float = np.inf, outlier_ratio: float = 0.75, translation_only: bool = False,
        max_iterations: int = 1000, tol_m: float = 1e-3, tree=None, on_iteration=None) -> IcpResult:
    """Find the rigid transform that moves a DEM's surface points onto reference points.

    Iterative closest point as ASP ``pc_align`` (the module docstring gives the math):
    point-to-plane (Chen & Medioni 1992) or point-to-point (Besl & McKay 1992, Kabsch
    rotation), with ``pc_align``'s outlier rules.

    Parameters
    ----------
    reference : numpy.ndarray
        ``(n, 3)`` reference points, Moon-centred body-fixed metres.
    dem_points : numpy.ndarray
        ``(m, 3)`` DEM surface points, body-fixed metres.
    dem_normals : numpy.ndarray
        ``(m, 3)`` unit outward normals at ``dem_points``.
    method : {"point-to-plane", "point-to-point"}, default "point-to-plane"
        Error metric minimised.
    max_displacement : float, default inf
        Reference points farther than this (metres) from the DEM at the start are dropped.
    outlier_ratio : float, default 0.75
        Fraction (0, 1] of the closest pairs kept at each iteration.
    translation_only : bool, default False
        Solve for a translation only.
    max_iterations : int, default 1000
        Iterations at most.
    tol_m : float, default 1e-3
        Converged when a step moves no point by more than this (metres), or the last 10
        steps together none by more than ``3 * tol_m``.
    tree : scipy.spatial.cKDTree, optional
        A tree of ``dem_points`` already built.
    on_iteration : callable, optional
        Called as ``on_iteration(iteration, mean inlier distance in metres)`` after each
        iteration.

    Returns
    -------
    IcpResult
        ``transform`` (4x4, maps the DEM onto the reference; ``inverse`` back),
        ``inliers`` (bool ``(n,)``: reference points within ``max_displacement``),
        ``iterations``, ``converged`` and ``history`` (mean inlier distance per iteration,
        metres).

    Raises
    ------
    InputError
        Exit 2: an unknown ``method``, ``outlier_ratio`` outside (0, 1], fewer than 6
        points within ``max_displacement``, or points that do not determine a rigid
        transform (degenerate geometry).
    """
    from scipy.spatial import cKDTree

    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if not 0 < outlier_ratio <= 1:
        raise InputError(f"outlier ratio must be in (0, 1], got {outlier_ratio}")
    p = np.asarray(reference, dtype=np.float64)
    tree = tree if tree is not None else cKDTree(dem_points)
    dist0, _ = tree.query(p, workers=-1)
    inliers = dist0 <= max_displacement
    if inliers.sum() < 6:
        raise InputError(f"only {int(inliers.sum())} reference points lie within --max-displacement "
                         f"{max_displacement} m of the DEM (need at least 6)")
    pin = p[inliers]
    s = np.eye(4)
    history, converged, it, past = [], False, 0, []
    for it in range(1, max_iterations + 1):
        q = apply(s, pin)
        dist, j = tree.query(q, workers=-1)
        if outlier_ratio < 1:
            keep = dist <= np.quantile(dist, outlier_ratio)
        else:
            keep = np.ones(dist.size, bool)
        history.append(float(dist[keep].mean()))
        if on_iteration is not None:
            on_iteration(it, history[-1])
        try:
            if method == "point-to-plane":
                r, t, c = _point_to_plane(q[keep], dem_points[j[keep]], dem_normals[j[keep]], translation_only)
            else:
                r, t, c = _point_to_point(q[keep], dem_points[j[keep]], translation_only)
        except np.linalg.LinAlgError as exc:
            raise InputError(f"the reference points and the DEM do not determine a rigid transform ({exc})") from None
        step = rigid(r, c + t - r @ c)  # rotate about the centroid c, then translate
        if not np.isfinite(step).all():
            raise InputError("the reference points and the DEM do not determine a rigid transform "
                             "(degenerate geometry, e.g. all points on one line); try --translation-only")
        s = step @ s
        moved = float(np.max(np.linalg.norm(apply(step, q[keep]) - q[keep], axis=1)))
        past.append(s)
        # converged: a step below tol_m, or (pairs flipping between neighbours) no net motion over 10 steps
        net = float(np.max(np.linalg.norm(apply(s, pin) - apply(past[-11], pin), axis=1))) if it > 10 else np.inf
        if moved < tol_m or net < 3 * tol_m:
            converged = True
            break
    return IcpResult(np.linalg.inv(s), inliers, it, converged, history)


def error_stats(errors: np.ndarray) -> dict:
    """What ``pc_align`` prints for absolute errors (m): 16/50/84 % percentiles, mean, std, RMSE, median, NMAD."""
    e = np.abs(np.asarray(errors, dtype=np.float64))
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"count": 0}
    med = float(np.median(e))
    p16, p50, p84 = (float(v) for v in np.percentile(e, [16, 50, 84]))
    return {"count": int(e.size), "p16": p16, "p50": p50, "p84": p84, "mean": float(e.mean()),
            "std": float(e.std()), "rmse": float(np.sqrt(np.mean(e ** 2))), "median": med,
            "nmad": float(1.4826 * np.median(np.abs(e - med)))}


def ce90_le90(points: np.ndarray, dem_points: np.ndarray, dem_normals: np.ndarray, tree) -> tuple[float, float]:
    """Horizontal CE90 and vertical LE90 (m) of points against a DEM cloud.

    Each point's residual is its offset from the tangent plane at the nearest DEM
    point, ``r = ((q - d) . n) n``; its component along the local vertical (the
    point's radial direction) and the magnitude of the rest are the vertical and
    horizontal errors.  CE90/LE90 are their 90th percentiles.
    """
    dist, j = tree.query(points, workers=-1)
    n = dem_normals[j]
    r = np.einsum("ij,ij->i", points - dem_points[j], n)[:, None] * n
    up = points / np.linalg.norm(points, axis=1, keepdims=True)
    v = np.einsum("ij,ij->i", r, up)
    h = np.linalg.norm(r - v[:, None] * up, axis=1)
    return float(np.percentile(h, 90)), float(np.percentile(np.abs(v), 90))
