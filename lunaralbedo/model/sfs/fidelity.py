r"""Fidelity term of the shape-from-shading cost: :math:`\sum_{ij}(((S h)_{ij} - h^0_{ij})/\Delta)^2`.

:math:`h^0` is the input DEM on the tile grid (metres) and :math:`S` a normalised Gaussian of
standard deviation :math:`\sigma` pixels (the input DEM's own resolution on this grid):
:math:`S h = G h / G 1`, with :math:`G` the Gaussian convolution with zeros beyond the window, so
that the window's edges are averages of the heights that exist.  Holding :math:`S h` rather
than :math:`h` to the input leaves the relief finer than the input's resolution to the shading:
ASP's ``sfs`` holds each pixel (``--initial-dem-constraint-weight``, :math:`\lambda(h - h_0)^2`),
which pulls the refined craters back towards their blurred input.  :math:`\sigma = 0` holds each
pixel (ASP's form).  Gradient :math:`2 S^\top r/\Delta^2` with :math:`S^\top r = G(r / G 1)`
(:math:`G` is symmetric).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter


@dataclass
class Fidelity:
    """:math:`\\sum((S h - h^0)/\\Delta)^2` with weight ``weight`` (:math:`\\lambda`, dimensionless)."""

    weight: float
    pixel_m: float
    h0: np.ndarray
    sigma_px: float
    name: str = "fidelity"
    _norm: np.ndarray | None = field(default=None, repr=False)

    def _g(self, a: np.ndarray) -> np.ndarray:
        return gaussian_filter(a, self.sigma_px, mode="constant", cval=0.0, truncate=3.0)

    def smooth(self, h: np.ndarray) -> np.ndarray:
        """:math:`S h` (metres)."""
        if self.sigma_px <= 0:
            return h
        if self._norm is None:
            self._norm = self._g(np.ones_like(h))
        return self._g(h) / self._norm

    def value_grad(self, h: np.ndarray) -> tuple[float, np.ndarray]:
        r = (self.smooth(h) - self.h0) / self.pixel_m
        g = 2.0 * r / self.pixel_m
        if self.sigma_px > 0:
            g = self._g(g / self._norm)
        return float(np.sum(r * r)), g

    def diagonal(self, shape: tuple[int, int]) -> np.ndarray:
        r"""The diagonal of :math:`S^\top S/\Delta^2` (the Gauss-Newton matrix of the term, its weight left out):
        :math:`\sum_q S_{qp}^2 = (G_2 (1/(G 1)^2))_p` with :math:`G_2` the convolution with the kernel squared."""
        if self.sigma_px <= 0:
            return np.full(shape, 1.0 / self.pixel_m**2)
        from scipy.ndimage import correlate

        norm = self._g(np.ones(shape))
        r = int(3.0 * self.sigma_px + 0.5)
        delta = np.zeros((2 * r + 1, 2 * r + 1))
        delta[r, r] = 1.0
        k = gaussian_filter(delta, self.sigma_px, mode="constant", cval=0.0, truncate=3.0)
        return correlate(1.0 / norm**2, k * k, mode="constant", cval=0.0) / self.pixel_m**2
