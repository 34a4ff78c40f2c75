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
:math:`R_{,i} = \partial R/\partial\cos i` and :math:`R_{,e}` are central differences of the
photometric model's own ``reflectance`` (:mod:`lunaralbedo.model.photometry`), so any registered
model works.  Only the pixels with four neighbours carry a residual.

Shadows: an observation in a cast shadow of the current heights, or darker than SHADOW_THRESH,
has :math:`w = 0` (the engine sets it): a shadowed pixel constrains the heights only through the
other images that see it lit, the smoothness and the fidelity terms; the engine recomputes the
cast shadows from the refined heights at every outer round.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import illumination

#: Step of the central differences of R in cos i and cos e.
_EPS = 1e-5


def unit_up(lon_deg: np.ndarray, lat_deg: np.ndarray) -> np.ndarray:
    """Unit vectors from the Moon's centre through lon/lat (degrees), shape ``(H, W, 3)``."""
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    cl = np.cos(lat)
    return np.stack([cl * np.cos(lon), cl * np.sin(lon), np.sin(lat)], axis=-1)


def interior_normals(points: np.ndarray):
    """``(n, N, |N|, s, a, b)`` at the pixels with four neighbours: the unit outward normals of
    :func:`lunaralbedo.model.geometry.dem_normals` and the pieces of their derivative."""
    a = 0.5 * (points[2:, 1:-1] - points[:-2, 1:-1])  # towards south
    b = 0.5 * (points[1:-1, 2:] - points[1:-1, :-2])  # towards east
    big = np.cross(a, b)
    norm = np.sqrt(np.sum(big * big, axis=-1))
    s = np.where(np.sum(big * points[1:-1, 1:-1], axis=-1) < 0, -1.0, 1.0)
    n = big * (s / norm)[..., None]
    return n, big, norm, s, a, b


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
    name: str = "shading"

    def points(self, h: np.ndarray) -> np.ndarray:
        return (self.radius_km + h / 1000.0)[..., None] * self.up

    def residuals(self, h: np.ndarray) -> list[np.ndarray]:
        """Per observation, :math:`J - R` at the interior pixels (0 where ``w`` is 0)."""
        n = interior_normals(self.points(h))[0]
        out = []
        for o in self.observations:
            r = self.reflectance(np.sum(n * o.l, -1), np.sum(n * o.v, -1), o.alpha, self.params)
            out.append(np.where(o.w > 0, o.j - r, 0.0))
        return out

    def value_grad(self, h: np.ndarray) -> tuple[float, np.ndarray]:
        pts = self.points(h)
        n, _, norm, s, a, b = interior_normals(pts)
        gn = np.zeros_like(n)
        total = 0.0
        f = self.reflectance
        for o in self.observations:
            ci, ce = np.sum(n * o.l, -1), np.sum(n * o.v, -1)
            res = np.where(o.w > 0, o.j - f(ci, ce, o.alpha, self.params), 0.0)
            total += float(np.sum(o.w * res * res))
            r_i = (f(ci + _EPS, ce, o.alpha, self.params) - f(ci - _EPS, ce, o.alpha, self.params)) / (2 * _EPS)
            r_e = (f(ci, ce + _EPS, o.alpha, self.params) - f(ci, ce - _EPS, o.alpha, self.params)) / (2 * _EPS)
            c = -2.0 * o.w * res
            gn += (c * r_i)[..., None] * o.l + (c * r_e)[..., None] * o.v
        g_big = (gn - np.sum(gn * n, -1)[..., None] * n) * (s / norm)[..., None]
        ga, gb = 0.5 * np.cross(b, g_big), 0.5 * np.cross(g_big, a)
        gp = np.zeros_like(pts)
        gp[2:, 1:-1] += ga
        gp[:-2, 1:-1] -= ga
        gp[1:-1, 2:] += gb
        gp[1:-1, :-2] -= gb
        return total, np.sum(gp * self.up, -1) / 1000.0
