r"""The one forward model of every synthetic scene: what a camera records of a known Moon.

Every scene of :mod:`lunaralbedo.simulate` (the solver's DRG strip, the ISIS mission)
renders its pixels through these functions:

* the Sun and the local frame at a ground point (:func:`local_frame`, :func:`sun_position`:
  one Sun geometry, azimuth clockwise from north and elevation above the local horizon);
* the recorded exposure :math:`A\,T\,R` of eq. 1 of the PhotometryTK manual (:func:`exposure_signal`), with
  :math:`R` from the photometric registry (:mod:`lunaralbedo.model.photometry`);
* the recording: 8-bit DN with additive Gaussian noise, optionally through the S-shaped
  film curve of Kim et al. (:func:`to_dn`, the DRG contract), or a float Level-1 cube value
  with multiplicative Gaussian noise (:func:`to_radiance`, the ISIS contract).

Units: positions in km in the Moon body-fixed frame (1737.4 km sphere), angles in degrees.
Pure NumPy, no I/O.
"""
from __future__ import annotations

import numpy as np

#: Distance of the synthetic Sun from the Moon's centre, km (1 AU).
SUN_DISTANCE_KM = 1.496e8


def local_frame(point) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors ``(east, north, up)`` at body-fixed ``point`` (km; not on a pole)."""
    up = point / np.linalg.norm(point)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    return east, np.cross(up, east), up


def sun_position(point, azimuth_deg: float, elevation_deg: float, distance_km: float = SUN_DISTANCE_KM) -> np.ndarray:
    """Body-fixed Sun position (km) seen from ``point`` at ``azimuth_deg`` (clockwise from north), ``elevation_deg``.

    The incidence angle on flat ground at ``point`` is ``90 - elevation_deg``.
    """
    east, north, up = local_frame(point)
    saz, sel = np.radians(azimuth_deg), np.radians(elevation_deg)
    return distance_km * (np.cos(sel) * (np.cos(saz) * north + np.sin(saz) * east) + np.sin(sel) * up)


def exposure_signal(albedo, exposure, reflectance):
    r"""The model of eq. 1 of the PhotometryTK manual: :math:`A\,T\,R` (albedo, exposure time, reflectance; broadcasts)."""
    return albedo * exposure * reflectance


def to_dn(signal, gain: float, noise_dn: float, rng, film=None) -> np.ndarray:
    r"""8-bit DN of a DRG: :math:`\mathrm{round}(f(\mathrm{gain}\cdot A T R) + n)` clipped to 0..255 (uint8).

    ``f`` is the identity, or the film curve ``film`` (a :class:`~lunaralbedo.response.synthetic.FilmCurve`,
    Kim et al.: DN = f(A T R)); ``n`` is Gaussian with ``noise_dn`` DN of spread.
    """
    dn = gain * signal if film is None else film.forward(np.maximum(signal, 1e-9))
    return np.clip(np.round(dn + rng.normal(0, noise_dn, dn.shape)), 0, 255).astype(np.uint8)


def to_radiance(signal, noise_relative: float, rng) -> np.ndarray:
    """A float Level-1 cube value: ``signal`` with multiplicative Gaussian noise of relative spread ``noise_relative``."""
    return signal * (1.0 + noise_relative * rng.standard_normal(signal.shape))
