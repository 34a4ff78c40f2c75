r"""LROC empirical photometric function (ISIS ``lronacpho``, algorithm ``LROC_Empirical``).

Angles: incidence :math:`i`, emission :math:`e` and phase :math:`g` in degrees;
:math:`\mu_0=\cos i`, :math:`\mu=\cos e`, and the phase term :math:`\alpha` is the
phase angle in the file's ``Units`` (degrees when ``Units = Degrees``, else radians).

* version 2014 (or no ``AlgorithmVersion``; terms ``A0..A3``):
  :math:`F = \exp(A_0 + A_1\alpha + A_2\mu + A_3\mu_0)`
* version 2019 (terms ``B0..B6``):
  :math:`F = \frac{\mu_0}{\mu+\mu_0}\exp(B_0 + B_1\alpha^2 + B_2\alpha + B_3\sqrt\alpha + B_4\mu + B_5\mu_0 + B_6\mu_0^2)`

The correction multiplies the image by :math:`F(i_r, e_r, g_r) / F(i, e, g)` with the
reference geometry of the ``NormalizationModel`` (``IncRef`` 30, ``EmaRef`` 0,
``PhaRef`` = ``IncRef`` by default).  Exactly-zero incidence/emission are nudged to
1e-11 degrees as ISIS does (no effect on the cosines).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

VERSIONS = (0, 2014, 2019)


@dataclass(frozen=True)
class LrocEmpirical:
    """Parameters of one band: ``a`` (A0..A3), ``b`` (B0..B6), version, phase units."""

    a: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    b: tuple[float, ...] = (0.0,) * 7
    version: int = 0
    degrees: bool = False
    wavelength: float = float("nan")
    tolerance: float = 1e-6
    extra: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        if self.version not in VERSIONS:
            raise ValueError(f"AlgorithmVersion {self.version} not recognised (known: 2014, 2019 or none)")

    def __call__(self, i_deg, e_deg, g_deg) -> np.ndarray:
        """:math:`F(i, e, g)` (float64), see the module docstring."""
        i = np.where(np.asarray(i_deg, dtype=np.float64) == 0.0, 1e-11, i_deg)
        e = np.where(np.asarray(e_deg, dtype=np.float64) == 0.0, 1e-11, e_deg)
        mu0, mu = np.cos(np.radians(i)), np.cos(np.radians(e))
        alpha = np.asarray(g_deg, dtype=np.float64) * (1.0 if self.degrees else np.pi / 180.0)
        if self.version == 2019:
            b = self.b
            with np.errstate(invalid="ignore", divide="ignore"):
                return mu0 / (mu + mu0) * np.exp(b[0] + b[1] * alpha * alpha + b[2] * alpha + b[3] * np.sqrt(alpha)
                                                  + b[4] * mu + b[5] * mu0 + b[6] * mu0 * mu0)
        a = self.a
        return np.exp(a[0] + a[1] * alpha + a[2] * mu + a[3] * mu0)

    def correction(self, i_deg, e_deg, g_deg, reference=(30.0, 0.0, 30.0)) -> np.ndarray:
        """Multiplicative correction :math:`F(i_r, e_r, g_r) / F(i, e, g)`."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self(*reference) / self(i_deg, e_deg, g_deg)
