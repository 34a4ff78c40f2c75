r"""Lambertian model (REFLECTANCE_TYPE 1): :math:`R = \cos i` where lit, 0 elsewhere; no fitted parameter."""
from __future__ import annotations

import numpy as np

from .base import PhotometricModel


def reflectance(cos_i, cos_e=None, alpha=None, params=()):
    r""":math:`R = \max(\cos i, 0)` (float64)."""
    ci = np.asarray(cos_i, dtype=np.float64)
    return np.where(ci > 0, ci, 0.0)


def layers(cos_i, cos_e, alpha):
    """The cached layer: ``geometric`` = :math:`R` itself."""
    return {"geometric": np.where(cos_i > 0, cos_i, 0.0)}


MODEL = PhotometricModel(
    name="lambert",
    code=1,
    description="R = cos i",
    layers=layers,
    layer_names=("geometric",),
    reflectance_from=lambda arrays, params=(): arrays["geometric"],
    reflectance=reflectance,
)
