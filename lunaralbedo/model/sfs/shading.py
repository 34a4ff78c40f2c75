r"""Shading (data) term of the shape-from-shading cost, with its gradient through the DEM normals.

.. math:: D(h) = \sum_k\sum_{ij} w_{kij}\,\big(J_{kij} - R(\mathbf n_{ij}(h)\cdot\mathbf l_{kij},\;
          \mathbf n_{ij}(h)\cdot\mathbf v_{kij},\;\alpha_{kij})\big)^2,\qquad J = \frac{I}{T A}

The normals are those of :func:`lunaralbedo.model.geometry.dem_normals` (central differences of
the body-fixed points :math:`\mathbf p = (R_{moon} + h/1000)\,\mathbf u(\lambda, \phi)`, km):
:math:`\mathbf N = \tfrac12(\mathbf p_{i+1,j} - \mathbf p_{i-1,j}) \times \tfrac12(\mathbf p_{i,j+1} -
\mathbf p_{i,j-1})`, :math:`\mathbf n = s\mathbf N/|\mathbf N|` with :math:`s = \pm1` making it point
outwards; :math:`\cos i, \cos e, \alpha` as :func:`lunaralbedo.model.geometry.illumination`.  The
unit vectors to the Sun and the spacecraft :math:`\mathbf l, \mathbf v` and the phase angle
:math:`\alpha` are those of the heights the window starts from (a change of tens of metres moves
them by less than 1e-3 degrees for a spacecraft 100 km up); the normals carry the dependence on
:math:`h`.  The gradient (the adjoint of the chain :math:`h \to \mathbf p \to \mathbf N \to \mathbf n
\to (\cos i, \cos e) \to R`):

.. math::

    \mathbf g_n = \sum_k -2w(J - R)\,(R_{,i}\,\mathbf l_k + R_{,e}\,\mathbf v_k),\quad
    \mathbf g_N = s\,\frac{\mathbf g_n - (\mathbf g_n\cdot\mathbf n)\mathbf n}{|\mathbf N|},\quad
    \frac{\partial D}{\partial \mathbf a} = \mathbf b\times\mathbf g_N,\;
    \frac{\partial D}{\partial \mathbf b} = \mathbf g_N\times\mathbf a

for :math:`\mathbf N = \mathbf a\times\mathbf b`, scattered with :math:`\pm\tfrac12` to the four
neighbours and projected on :math:`\partial\mathbf p/\partial h = \mathbf u/1000`.
:math:`R_{,i} = \partial R/\partial\cos i` and :math:`R_{,e}` are forward differences of the
photometric model's own ``reflectance`` (:mod:`lunaralbedo.model.photometry`), so any registered
model works.  Only the pixels with four neighbours carry a residual.

The albedo floats with the heights (``float_albedo``, variable projection: Golub and Pereyra 1973):
each pixel's :math:`A` is scaled by the least-squares :math:`a^* = \sum_k w J R / \sum_k w R^2` of the
current heights, :math:`D = \sum w (J - a^* R)^2`; as :math:`a^*` minimises :math:`D` for the heights, its
own derivative adds nothing to the gradient.  The shading of relief that the albedo solve had taken
into the albedo can then move into the heights at once, where the images' different Sun
directions agree on it (a pixel seen by one image only gives no height information: its
residual is zero).  ``float_albedo=False`` holds the albedo (ASP ``sfs`` without ``--float-albedo``).

Shadows: an observation in a cast shadow of the current heights, or darker than SHADOW_THRESH,
has :math:`w = 0` (the engine sets it): a shadowed pixel constrains the heights only through the
other images that see it lit, the smoothness and the fidelity terms; the engine recomputes the
cast shadows from the refined heights at every outer round.
"""
from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np
from numba import njit

from ..geometry import illumination

#: Step of the (forward) differences of R in cos i and cos e.
_EPS = 1e-6


@njit(cache=True, nogil=True)
def _cosines(n, l, v):
    r""":math:`(\mathbf n\cdot\mathbf l, \mathbf n\cdot\mathbf v)` per pixel of ``(H, W, 3)`` arrays."""
    ci, ce = np.empty(n.shape[:2]), np.empty(n.shape[:2])
    for i in range(n.shape[0]):
        for j in range(n.shape[1]):
            ci[i, j] = n[i, j, 0] * l[i, j, 0] + n[i, j, 1] * l[i, j, 1] + n[i, j, 2] * l[i, j, 2]
            ce[i, j] = n[i, j, 0] * v[i, j, 0] + n[i, j, 1] * v[i, j, 1] + n[i, j, 2] * v[i, j, 2]
    return ci, ce


def unit_up(lon_deg: np.ndarray, lat_deg: np.ndarray) -> np.ndarray:
    """Unit vectors from the Moon's centre through lon/lat (degrees), shape ``(H, W, 3)``."""
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    cl = np.cos(lat)
    return np.stack([cl * np.cos(lon), cl * np.sin(lon), np.sin(lat)], axis=-1)


def interior_normals(points: np.ndarray):
    r"""``(n, |N|/s, a, b)`` at the pixels with four neighbours: the unit outward normals of
    :func:`lunaralbedo.model.geometry.dem_normals` (the same operations) and the pieces of their derivative
    (:math:`|\mathbf N|` signed by :math:`s`, and :math:`\mathbf a, \mathbf b`)."""
    p = np.ascontiguousarray(points, dtype=np.float64)
    h, w = p.shape[0] - 2, p.shape[1] - 2
    n, a, b = np.empty((h, w, 3)), np.empty((h, w, 3)), np.empty((h, w, 3))
    snorm = np.empty((h, w))
    _normals(p, n, snorm, a, b)
    return n, snorm, a, b


@njit(cache=True, nogil=True)
def _normals(p, n, snorm, a, b):
    """:func:`interior_normals`' loop: central differences, their cross product, its sign and length."""
    for i in range(n.shape[0]):
        for j in range(n.shape[1]):
            for k in range(3):
                a[i, j, k] = 0.5 * (p[i + 2, j + 1, k] - p[i, j + 1, k])  # towards south
                b[i, j, k] = 0.5 * (p[i + 1, j + 2, k] - p[i + 1, j, k])  # towards east
            nx = a[i, j, 1] * b[i, j, 2] - a[i, j, 2] * b[i, j, 1]
            ny = a[i, j, 2] * b[i, j, 0] - a[i, j, 0] * b[i, j, 2]
            nz = a[i, j, 0] * b[i, j, 1] - a[i, j, 1] * b[i, j, 0]
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if nx * p[i + 1, j + 1, 0] + ny * p[i + 1, j + 1, 1] + nz * p[i + 1, j + 1, 2] < 0:
                norm = -norm
            snorm[i, j] = norm
            n[i, j, 0], n[i, j, 1], n[i, j, 2] = nx / norm, ny / norm, nz / norm


@njit(cache=True, nogil=True)
def _accumulate(gn, ci_coef, ce_coef, l, v):
    """``gn += ci_coef l + ce_coef v`` per pixel (the gradient over the normals of one image's residuals)."""
    for i in range(gn.shape[0]):
        for j in range(gn.shape[1]):
            for k in range(3):
                gn[i, j, k] += ci_coef[i, j] * l[i, j, k] + ce_coef[i, j] * v[i, j, k]


@njit(cache=True, nogil=True, inline="always")
def _edge_derivatives(gn, n, snorm, a, b, i, j):
    """At interior pixel ``(i, j)``: the derivatives over the two edge vectors ``a`` and ``b`` of the normal, from the
    one over the unit normal ``gn`` (module docstring): dD/da = b x g and dD/db = g x a, halved to the neighbours and
    times dp/dh = up / 1000 (km per metre)."""
    d = gn[i, j, 0] * n[i, j, 0] + gn[i, j, 1] * n[i, j, 1] + gn[i, j, 2] * n[i, j, 2]
    gx = (gn[i, j, 0] - d * n[i, j, 0]) / snorm[i, j]
    gy = (gn[i, j, 1] - d * n[i, j, 1]) / snorm[i, j]
    gz = (gn[i, j, 2] - d * n[i, j, 2]) / snorm[i, j]
    ax, ay, az, bx, by, bz = a[i, j, 0], a[i, j, 1], a[i, j, 2], b[i, j, 0], b[i, j, 1], b[i, j, 2]
    return (5e-4 * (by * gz - bz * gy), 5e-4 * (bz * gx - bx * gz), 5e-4 * (bx * gy - by * gx),
            5e-4 * (gy * az - gz * ay), 5e-4 * (gz * ax - gx * az), 5e-4 * (gx * ay - gy * ax))


@njit(cache=True, nogil=True)
def _adjoint(gn, n, snorm, a, b, up, gh):
    """The gradient over the heights (``gh``, metres) from the one over the unit normals ``gn`` (module docstring)."""
    gh[:] = 0.0
    for i in range(n.shape[0]):
        for j in range(n.shape[1]):
            dax, day, daz, dbx, dby, dbz = _edge_derivatives(gn, n, snorm, a, b, i, j)
            gh[i + 2, j + 1] += dax * up[i + 2, j + 1, 0] + day * up[i + 2, j + 1, 1] + daz * up[i + 2, j + 1, 2]
            gh[i, j + 1] -= dax * up[i, j + 1, 0] + day * up[i, j + 1, 1] + daz * up[i, j + 1, 2]
            gh[i + 1, j + 2] += dbx * up[i + 1, j + 2, 0] + dby * up[i + 1, j + 2, 1] + dbz * up[i + 1, j + 2, 2]
            gh[i + 1, j] -= dbx * up[i + 1, j, 0] + dby * up[i + 1, j, 1] + dbz * up[i + 1, j, 2]


@njit(cache=True, nogil=True)
def _adjoint_squares(gn, n, snorm, a, b, up, diag):
    r"""``diag`` += the squares of each height's derivative of one image's residuals, ``gn`` the derivative of each
    pixel's residual over its unit normal: :func:`_adjoint` with squares summed instead of values (the diagonal of
    the Gauss-Newton matrix :math:`J^\top J`)."""
    for i in range(n.shape[0]):
        for j in range(n.shape[1]):
            dax, day, daz, dbx, dby, dbz = _edge_derivatives(gn, n, snorm, a, b, i, j)
            v = dax * up[i + 2, j + 1, 0] + day * up[i + 2, j + 1, 1] + daz * up[i + 2, j + 1, 2]
            diag[i + 2, j + 1] += v * v
            v = dax * up[i, j + 1, 0] + day * up[i, j + 1, 1] + daz * up[i, j + 1, 2]
            diag[i, j + 1] += v * v
            v = dbx * up[i + 1, j + 2, 0] + dby * up[i + 1, j + 2, 1] + dbz * up[i + 1, j + 2, 2]
            diag[i + 1, j + 2] += v * v
            v = dbx * up[i + 1, j, 0] + dby * up[i + 1, j, 1] + dbz * up[i + 1, j, 2]
            diag[i + 1, j] += v * v


@dataclass
class Observation:
    """One image over the window: ``J = I/(T A)`` and weights ``w`` (0: not used), both ``(H-2, W-2)``;
    unit vectors to the Sun ``l`` and spacecraft ``v`` and phase ``alpha`` (radians) at the interior pixels."""

    j: np.ndarray
    w: np.ndarray
    l: np.ndarray
    v: np.ndarray
    alpha: np.ndarray


def observation(j, w, points_ref, sun_km, spacecraft_km) -> Observation:
    """An :class:`Observation` with its directions from the reference points ``(H, W, 3)`` km."""
    p = points_ref[1:-1, 1:-1]
    _, _, alpha = illumination(p, p, sun_km, spacecraft_km)  # the normal is not used for alpha
    l = np.asarray(sun_km, float) - p
    v = np.asarray(spacecraft_km, float) - p
    l /= np.linalg.norm(l, axis=-1, keepdims=True)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return Observation(np.nan_to_num(j), np.where(np.isfinite(j), w, 0.0), l, v, alpha)


@dataclass
class Shading:
    """The data term :math:`D(h)` over ``observations`` with the model's ``reflectance(ci, ce, alpha, params)``."""

    weight: float
    up: np.ndarray  # (H, W, 3) unit vectors
    radius_km: float
    observations: list
    reflectance: object
    params: tuple
    float_albedo: bool = True
    name: str = "shading"

    def points(self, h: np.ndarray) -> np.ndarray:
        return (self.radius_km + h / 1000.0)[..., None] * self.up

    def albedo_scale(self, refl: list[np.ndarray]) -> np.ndarray | float:
        """1 (the albedo held), or with ``float_albedo`` the least-squares :math:`a^*` of each pixel (1 where no
        image sees it)."""
        if not self.float_albedo:
            return 1.0
        num = sum(o.w * o.j * r for o, r in zip(self.observations, refl))
        den = sum(o.w * r * r for o, r in zip(self.observations, refl))
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)

    def _shade(self, h: np.ndarray):
        """At heights ``h``: the interior normals with their edge vectors (:func:`interior_normals`), each image's
        ``(cos i, cos e)`` and reflectance, and the albedo's scale (:meth:`albedo_scale`)."""
        normals = interior_normals(self.points(h))
        cosines = [_cosines(normals[0], o.l, o.v) for o in self.observations]
        refl = [self.reflectance(ci, ce, o.alpha, self.params) for (ci, ce), o in zip(cosines, self.observations)]
        return normals, cosines, refl, self.albedo_scale(refl)

    def value_grad(self, h: np.ndarray) -> tuple[float, np.ndarray]:
        f = self.reflectance
        (n, snorm, a, b), cosines, refl, scale = self._shade(h)
        gn = np.zeros_like(n)
        total = 0.0
        for o, (ci, ce), r in zip(self.observations, cosines, refl):
            res = np.where(o.w > 0, o.j - scale * r, 0.0)
            total += float(np.sum(o.w * res * res))
            c = (-2.0 / _EPS) * o.w * res * scale  # the albedo's scale held: its derivative adds nothing at the optimum
            r_i = f(ci + _EPS, ce, o.alpha, self.params) - r  # times 1/eps in c
            r_e = f(ci, ce + _EPS, o.alpha, self.params) - r
            _accumulate(gn, c * r_i, c * r_e, o.l, o.v)
        gh = np.empty(h.shape)
        _adjoint(gn, n, snorm, a, b, self.up, gh)
        return total, gh

    def gauss_newton_diagonal(self, h: np.ndarray) -> tuple[np.ndarray, float, int, int]:
        r"""``(diag, misfit, n, dof)``: the diagonal of :math:`J^\top J` over the heights (per metre squared), with
        :math:`J` the residuals' derivatives :math:`-a^* \sqrt{w}\,\partial R/\partial h` (the floating albedo's own
        derivative left out, as in the gradient), the data term's value, its number of observations, and the
        residuals' degrees of freedom: ``n`` less one per observed pixel when the albedo floats (each such pixel's
        :math:`a^*` is fitted to its own observations: one image per pixel leaves no residual at all)."""
        f = self.reflectance
        (n, snorm, a, b), cosines, refl, scale = self._shade(h)
        diag, total, count = np.zeros(h.shape), 0.0, 0
        for o, (ci, ce), r in zip(self.observations, cosines, refl):
            res = np.where(o.w > 0, o.j - scale * r, 0.0)
            total += float(np.sum(o.w * res * res))
            count += int(np.count_nonzero(o.w))
            c = np.sqrt(o.w) * scale / _EPS
            gn = np.zeros_like(n)
            _accumulate(gn, c * (f(ci + _EPS, ce, o.alpha, self.params) - r), c * (f(ci, ce + _EPS, o.alpha, self.params) - r),
                        o.l, o.v)
            _adjoint_squares(gn, n, snorm, a, b, self.up, diag)
        seen = int(np.count_nonzero(sum(o.w > 0 for o in self.observations))) if self.float_albedo else 0
        return diag, total, count, count - seen
