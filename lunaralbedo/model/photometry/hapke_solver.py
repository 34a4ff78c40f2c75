r"""Hapke as the solver's reflectance: normalised to a reference geometry, as ``lrowacphomap`` does.

The solved albedo is the reflectance the surface would have at the reference geometry
:math:`(i_r, e_r, g_r)` (``Incref``, ``Emiref``, ``Pharef``), so the model reflectance of an
observation at :math:`(i, e, g)` is

.. math:: R = \frac{r_H(i, e, g; \mathbf{p})}{r_H(i_r, e_r, g_r; \mathbf{p})}

with :math:`r_H` one of ISIS's Hapke variants (:mod:`.hapke`, the one implementation) and
the parameters :math:`\mathbf{p}` constant or per ground point (parameter map).  With
:math:`I = A\,T\,R` (eq. 1's model) the albedo :math:`A = I / (T R)` is exactly the
``lrowacphomap`` correction :math:`(I/T)\,r_H(i_r,e_r,g_r)/r_H(i,e,g)`.  Hapke has no
fitted parameters in the solver (the phase behaviour is in :math:`\mathbf{p}`).
Angles in degrees; pure NumPy.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .hapke import HAPKE_LROC_PARAMETERS, hapke_hen, hapke_leg, hapke_lroc

#: ISIS algorithm name (upper case) -> (function, parameter names in call order, argument order of the angles).
VARIANTS = {
    "HAPKELROC": (hapke_lroc, HAPKE_LROC_PARAMETERS, "ieg"),
    "HAPKEHEN": (hapke_hen, ("WH", "B0", "HH", "THETA", "HG1", "HG2"), "gie"),
    "HAPKELEG": (hapke_leg, ("WH", "B0", "HH", "THETA", "BH", "CH"), "gie"),
}


@dataclass
class HapkeModel:
    """A Hapke variant, its reference geometry (degrees) and constant parameters (THETA in degrees).

    Parameters missing from ``constants`` come per ground point (``params`` argument of
    :meth:`normalised`).
    """

    variant: str
    reference: tuple[float, float, float]
    constants: dict[str, float] = field(default_factory=dict)

    def __post_init__(self):
        self.variant = self.variant.upper()
        if self.variant not in VARIANTS:
            raise ValueError(f"Hapke variant must be one of {', '.join(VARIANTS)}, got {self.variant!r}")

    @property
    def names(self) -> tuple[str, ...]:
        return VARIANTS[self.variant][1]

    def reflectance(self, i_deg, e_deg, g_deg, params: dict | None = None):
        """:math:`r_H(i, e, g)` with the constants, overridden by per-point ``params`` arrays."""
        fn, names, order = VARIANTS[self.variant]
        p = {**self.constants, **(params or {})}
        angles = {"i": i_deg, "e": e_deg, "g": g_deg}
        return fn(*(angles[c] for c in order), *(p[n] for n in names))

    def normalised(self, cos_i, cos_e, alpha_rad, params: dict | None = None):
        """:math:`R = r_H(i,e,g)/r_H(i_r,e_r,g_r)`; 0 where unlit or unseen (cos i or cos e <= 0)."""
        ci = np.asarray(cos_i, dtype=np.float64)
        ce = np.asarray(cos_e, dtype=np.float64)
        seen = (ci > 0) & (ce > 0)
        i = np.degrees(np.arccos(np.clip(ci, -1, 1)))
        e = np.degrees(np.arccos(np.clip(ce, -1, 1)))
        g = np.degrees(np.asarray(alpha_rad, dtype=np.float64))
        with np.errstate(invalid="ignore", divide="ignore"):
            r = self.reflectance(i, e, g, params) / self.reflectance(*self.reference, params)
        return np.where(seen & np.isfinite(r), r, 0.0)
