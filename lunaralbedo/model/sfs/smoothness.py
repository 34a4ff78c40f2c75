r"""Smoothness term of the shape-from-shading cost: :math:`\sum_{ij}((\nabla^2 h)_{ij}/\Delta)^2`.

:math:`(\nabla^2 h)_{ij} = h_{i+1,j} + h_{i-1,j} + h_{i,j+1} + h_{i,j-1} - 4h_{ij}` (metres, the
five-point Laplacian on the pixel grid) at the pixels with four neighbours; divided by the ground
pixel size :math:`\Delta` (metres) it is the change of slope between neighbouring pixels.  ASP's
``sfs`` has the same term (``--smoothness-weight``, on the second derivatives of the heights).
Its gradient is :math:`2 L^\top L h / \Delta^2`, :math:`L^\top` applied by scattering each
pixel's value back to its five stencil pixels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def laplacian(h: np.ndarray) -> np.ndarray:
    """The five-point Laplacian of ``h`` at the interior pixels, shape ``(H-2, W-2)``."""
    return h[2:, 1:-1] + h[:-2, 1:-1] + h[1:-1, 2:] + h[1:-1, :-2] - 4.0 * h[1:-1, 1:-1]


def laplacian_adjoint(r: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """:math:`L^\\top r` for ``r`` of shape ``(H-2, W-2)``: the transpose of :func:`laplacian`."""
    g = np.zeros(shape)
    g[2:, 1:-1] += r
    g[:-2, 1:-1] += r
    g[1:-1, 2:] += r
    g[1:-1, :-2] += r
    g[1:-1, 1:-1] -= 4.0 * r
    return g


@dataclass
class Smoothness:
    """:math:`\\sum (\\nabla^2 h/\\Delta)^2` with weight ``weight`` (:math:`\\mu`, dimensionless)."""

    weight: float
    pixel_m: float
    name: str = "smoothness"

    def value_grad(self, h: np.ndarray) -> tuple[float, np.ndarray]:
        lap = laplacian(h) / self.pixel_m
        return float(np.sum(lap * lap)), laplacian_adjoint(2.0 * lap / self.pixel_m, h.shape)

    def diagonal(self, shape: tuple[int, int]) -> np.ndarray:
        r"""The diagonal of :math:`L^\top L/\Delta^2` (the Gauss-Newton matrix of the term, its weight left out)."""
        return laplacian_adjoint_squares(shape) / self.pixel_m**2


def laplacian_adjoint_squares(shape: tuple[int, int]) -> np.ndarray:
    r""":math:`\sum_q L_{qp}^2` per pixel ``p``: 16 for the centre of each stencil it is, 1 for each neighbour."""
    one = np.ones((shape[0] - 2, shape[1] - 2))
    g = np.zeros(shape)
    for sl in ((slice(2, None), slice(1, -1)), (slice(None, -2), slice(1, -1)), (slice(1, -1), slice(2, None)),
               (slice(1, -1), slice(None, -2))):
        g[sl] += one
    g[1:-1, 1:-1] += 16.0 * one
    return g
