"""Mosaic model (REFLECTANCE_TYPE 0): :math:`R = 1`; no geometry, no fitted parameter."""
from __future__ import annotations

import numpy as np

from .base import PhotometricModel


def reflectance(cos_i, cos_e=None, alpha=None, params=()):
    """:math:`R = 1` with the shape of ``cos_i``."""
    return np.ones(np.shape(cos_i))


def reflectance_from(arrays, params=()):
    """:math:`R = 1` with the shape and dtype of the observed stack ``arrays["image"]``."""
    return np.ones_like(arrays["image"])


MODEL = PhotometricModel(
    name="mosaic",
    code=0,
    description="R = 1: a plain mosaic (no DEM, no positions)",
    layers=lambda cos_i, cos_e, alpha: {},
    reflectance_from=reflectance_from,
    reflectance=reflectance,
    needs_geometry=False,
)
