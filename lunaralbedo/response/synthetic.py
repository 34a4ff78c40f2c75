r"""Forward model of film-like 8-bit images: a known S-shaped response with toe and shoulder.

The characteristic curve is a logistic in log exposure (the H&D curve of film: toe,
straight part of slope ``contrast``, shoulder), with a fog level and a little headroom:

.. math:: z = 255\,\bigl(a + b\,\sigma(k \ln(X/X_0))\bigr),\qquad
          g(z) = f^{-1}(z) = X_0 \Bigl(\frac{y}{1-y}\Bigr)^{1/k},\; y = (z/255 - a)/b

Photon-like noise: the exposure :math:`X = r t` is observed as a Poisson count of
``photons`` per unit exposure (divided back), then mapped through :math:`f`, rounded and
clipped to 0..255.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FilmCurve:
    """S-shaped 8-bit response: fog ``a``, range ``b``, contrast ``k``, mid exposure ``x0``."""

    a: float = 0.02
    b: float = 0.97
    k: float = 1.4
    x0: float = 1.0

    def forward(self, x: np.ndarray) -> np.ndarray:
        """Continuous DN (before rounding) of exposure ``x`` (> 0)."""
        return 255.0 * (self.a + self.b / (1.0 + (np.asarray(x) / self.x0) ** -self.k))

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """The true g(z): exposure whose DN is ``z`` (NaN outside the curve's range)."""
        y = (np.asarray(z, np.float64) / 255.0 - self.a) / self.b
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where((y > 0) & (y < 1), self.x0 * (y / (1.0 - y)) ** (1.0 / self.k), np.nan)


def render_stack(n_images: int = 8, shape=(120, 120), exposure_ratio: float = 32.0, radiance_ratio: float = 40.0,
                 photons: float = 3000.0, curve: FilmCurve = FilmCurve(), seed: int = 1, exposures=None) -> dict:
    """An aligned stack of ``n_images`` exposures of one textured scene.

    Exposure times are log-spaced over ``exposure_ratio`` (geometric mean 1), radiance a
    smooth log-normal texture spanning about ``radiance_ratio``, both scaled so the middle
    exposure of the middle radiance is the curve's mid point; ``exposures`` (any units, e.g.
    milliseconds) replaces the log-spaced times by these, rescaled to geometric mean 1.  ``photons`` is the count
    per unit exposure (noise 1/sqrt(photons*X) relative).  Returns ``dn`` (uint8,
    (n, h, w)), ``exposure``, ``radiance``, ``curve``.
    """
    rng = np.random.default_rng(seed)
    h, w = shape
    if exposures is None:
        t = np.exp(np.linspace(-0.5, 0.5, n_images) * np.log(exposure_ratio))
    else:
        t = np.asarray(exposures, np.float64)
        t = t / np.exp(np.mean(np.log(t)))
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    field = np.zeros((h, w))
    for _ in range(8):
        kx, ky, ph = rng.uniform(1, 12), rng.uniform(1, 12), rng.uniform(0, 2 * np.pi)
        field += np.sin(kx * xx + ph) * np.cos(ky * yy + 2 * ph)
    field += 0.6 * rng.standard_normal((h, w))
    field = (field - field.mean()) / (np.ptp(field) or 1.0)
    r = curve.x0 * np.exp(field * np.log(radiance_ratio))
    x = r[None] * t[:, None, None]
    x = rng.poisson(photons * x) / photons
    dn = np.clip(np.round(curve.forward(np.maximum(x, 1e-9))), 0, 255).astype(np.uint8)
    return {"dn": dn, "exposure": t, "radiance": r, "curve": curve}
