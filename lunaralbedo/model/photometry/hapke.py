r"""Hapke photometric functions as ISIS defines them (pure NumPy, vectorised; angles in degrees).

:func:`hapke_lroc` is ISIS ``HapkeLROC`` (``lrowacphomap``; Sato et al. 2014 parameters
:math:`w, b, c, B_{C0}, h_C, B_{S0}, h_S, \bar\theta, \phi`):

.. math::
   r = K \frac{w}{4} \frac{\mu_{0e}}{\mu_{0e}+\mu_e}
       \left[p(g)(1 + B_{S0} B_S(g)) + H(\mu_{0e}/K) H(\mu_e/K) - 1\right](1 + B_{C0} B_C(g))\, S(i, e, g)

with the double Henyey-Greenstein phase function
:math:`p = \frac{1+c}{2}\frac{1-b^2}{(1-2b\cos g+b^2)^{3/2}} + \frac{1-c}{2}\frac{1-b^2}{(1+2b\cos g+b^2)^{3/2}}`,
shadow-hiding :math:`B_S = 1/(1 + \tan(g/2)/h_S)`, coherent backscatter
:math:`B_C = \frac{1 + (1-e^{-x})/x}{2(1+x)^2}` with :math:`x = \tan(g/2)/h_C`,
the Hapke (2002) approximation :math:`H(x) = 1/(1 - w x [r_0 + \frac{1-2 r_0 x}{2}\ln\frac{1+x}{x}])`,
:math:`r_0 = (1-\sqrt{1-w})/(1+\sqrt{1-w})`, porosity factor
:math:`K = -\ln(1 - 1.209\phi^{2/3}) / (1.209\phi^{2/3})` (1 when :math:`\phi = 0`) and
Hapke's (1984) macroscopic roughness :math:`S` with effective cosines
:math:`\mu_{0e}, \mu_e` (plain :math:`\cos i, \cos e` and :math:`S = 1` when :math:`\bar\theta \le 0`).
Incidence :math:`\ge 90^\circ` gives 0.  Special cases follow ISIS: :math:`B_C = 1` at
:math:`g = 0`; :math:`B_C = 0` when :math:`h_C = 0`; :math:`B_S = 0` when :math:`h_S = 0`.
"""
from __future__ import annotations

import numpy as np

HAPKE_LROC_PARAMETERS = ("W", "B", "C", "BCO", "HC", "BSO", "HS", "THETA", "PHI")


def h_function(x, w, r0):
    """Hapke's (2002) H-function approximation (ISIS ``HGfunc``); 1 at ``x = 0``."""
    x = np.abs(np.asarray(x, dtype=np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        h = 1.0 / (1.0 - w * x * (r0 + (1.0 - 2.0 * r0 * x) * 0.5 * np.log((1.0 + x) / x)))
    return np.where(x == 0.0, 1.0, h)


def _roughness(i, e, g, theta):
    """Hapke (1984) roughness: effective ``(mu0e, mue, S)``; i, e, g, theta in radians (theta > 0)."""
    inv_pi = 1.0 / np.pi
    cost, sint = np.cos(theta), np.sin(theta)
    cott = cost / np.maximum(1e-10, sint)
    cot2t = cott * cott
    tant = sint / cost
    chi = 1.0 / np.sqrt(1.0 + np.pi * tant * tant)
    cosi, sini, cose, sine = np.cos(i), np.sin(i), np.cos(e), np.sin(e)

    def terms(cos_x, sin_x):
        cot = cos_x / np.maximum(1e-10, sin_x)
        e1 = np.exp(np.minimum(-2.0 * cott * cot * inv_pi, 23.0))
        e2 = np.exp(np.minimum(-cot2t * cot * cot * inv_pi, 23.0))
        eta = chi * (cos_x + sin_x * tant * e2 / (2.0 - e1))
        return e1, e2, eta

    e1i, e2i, etai = terms(cosi, sini)
    e1e, e2e, etae = terms(cose, sine)
    sinei = sine * sini
    with np.errstate(divide="ignore", invalid="ignore"):
        cospsi = np.where(sinei == 0.0, 1.0, (np.cos(g) - cose * cosi) / np.where(sinei == 0.0, 1.0, sinei))
    psi = np.where(cospsi <= -1.0, np.pi, np.where(cospsi > 1.0, 0.0, np.arccos(np.clip(cospsi, -1.0, 1.0))))
    half = psi * 0.5
    fpsi = np.where(half >= np.pi / 2, 0.0, np.exp(np.minimum(-2.0 * np.tan(np.where(half >= np.pi / 2, 0.0, half)), 23.0)))
    s2 = np.sin(half) ** 2
    p = psi * inv_pi
    i_first = i <= e
    ec_i = 2.0 - e1e - p * e1i  # i <= e
    ec_e = 2.0 - e1i - p * e1e  # i > e
    mu0e = np.where(i_first, chi * (cosi + sini * tant * (cospsi * e2e + s2 * e2i) / ec_i),
                    chi * (cosi + sini * tant * (e2i - s2 * e2e) / ec_e))
    mue = np.where(i_first, chi * (cose + sine * tant * (e2e - s2 * e2i) / ec_i),
                   chi * (cose + sine * tant * (cospsi * e2i + s2 * e2e) / ec_e))
    q = np.where(i_first, cosi / etai, cose / etae)
    s = (mue * cosi * chi) / (etae * etai * (1.0 - fpsi + fpsi * chi * q))
    return mu0e, mue, s


def hapke_lroc(i_deg, e_deg, g_deg, w, b, c, bc0, hc, bs0, hs, theta_deg, phi):
    """ISIS ``HapkeLROC`` reflectance (see module docstring); all arguments broadcast, angles in degrees."""
    i_deg, e_deg, g_deg = (np.asarray(a, dtype=np.float64) for a in (i_deg, e_deg, g_deg))
    w, b, c, bc0, hc, bs0, hs, theta_deg, phi = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (w, b, c, bc0, hc, bs0, hs, theta_deg, phi)))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ck = 1.209 * np.abs(phi) ** (2.0 / 3.0)
        k = np.where(phi != 0.0, -np.log(1.0 - ck) / np.where(phi != 0.0, ck, 1.0), 1.0)
        g, i, e, theta = (np.radians(a) for a in (g_deg, i_deg, e_deg, theta_deg))
        cosg = np.cos(g)
        b2 = b * b
        pg = ((1.0 + c) * 0.5 * (1.0 - b2) / (1.0 - 2.0 * b * cosg + b2) ** 1.5
              + (1.0 - c) * 0.5 * (1.0 - b2) / (1.0 + 2.0 * b * cosg + b2) ** 1.5)
        tang2 = np.tan(g * 0.5)
        bsg = np.where((hs == 0.0) | (g == np.pi), 0.0, 1.0 / (1.0 + tang2 / hs))
        x = tang2 / hc
        bcg = np.where(g == 0.0, 1.0, np.where((g == np.pi) | (hc == 0.0), 0.0,
                                               (1.0 + (1.0 - np.exp(-x)) / x) / (2.0 * (1.0 + x) ** 2)))
        sq = np.sqrt(1.0 - w)
        r0 = (1.0 - sq) / (1.0 + sq)
        rough = theta > 0.0
        mu0e, mue, s = _roughness(i, e, g, np.where(rough, theta, 0.1))
        mu0e = np.where(rough, mu0e, np.cos(i))
        mue = np.where(rough, mue, np.cos(e))
        s = np.where(rough, s, 1.0)
        mie = h_function(mu0e / k, w, r0) * h_function(mue / k, w, r0) - 1.0
        r = k * (w / 4.0) * (mu0e / (mu0e + mue)) * (pg * (1.0 + bs0 * bsg) + mie) * (1.0 + bc0 * bcg) * s
    return np.where(i_deg >= 90.0, 0.0, r)


def _hapke_photomet(phase_deg, incidence_deg, emission_deg, wh, b0, hh, theta_deg, pg):
    r"""ISIS ``Hapke`` (photomet) with phase function values ``pg``:

    :math:`r = \frac{w}{4}\frac{\mu_{0e}}{\mu_{0e}+\mu_e}[(1+B(g))p(g) - 1 + H(\mu_{0e})H(\mu_e)]\,S`,
    :math:`B = B_0/(1+\tan(g/2)/h)` (0 when :math:`h = 0`), :math:`H(u) = (1+2u)/(1+2u\sqrt{1-w})`
    (Hapke 1981), roughness as in :func:`hapke_lroc`; 0 at incidence :math:`\ge 90^\circ`.
    """
    g, i, e = (np.asarray(a, dtype=np.float64) for a in (phase_deg, incidence_deg, emission_deg))
    wh, b0, hh, theta_deg = (np.asarray(a, dtype=np.float64) for a in (wh, b0, hh, theta_deg))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        gamma = np.sqrt(1.0 - wh)
        tang2 = np.tan(np.radians(g) / 2.0)
        bg = np.where(hh == 0.0, 0.0, b0 / (1.0 + tang2 / np.where(hh == 0.0, 1.0, hh)))
        rough = theta_deg > 0.0
        mu0e, mue, s = _roughness(np.radians(i), np.radians(e), np.radians(g),
                                  np.radians(np.where(rough, theta_deg, 1.0)))
        mu0e = np.where(rough, mu0e, np.cos(np.radians(i)))
        mue = np.where(rough, mue, np.cos(np.radians(e)))
        s = np.where(rough, s, 1.0)

        def h(u):
            return (1.0 + 2.0 * u) / (1.0 + 2.0 * u * gamma)

        r = wh / 4.0 * mu0e / (mu0e + mue) * ((1.0 + bg) * pg - 1.0 + h(mu0e) * h(mue)) * s
    return np.where(i >= 90.0, 0.0, r)


def hapke_hen(phase_deg, incidence_deg, emission_deg, wh=0.5, b0=0.0, hh=0.0, theta=0.0, hg1=0.0, hg2=0.0):
    r"""ISIS ``HapkeHen``: two-term Henyey-Greenstein
    :math:`p = (1-c_2)\frac{1-b^2}{(1+b^2+2b\cos g)^{3/2}} + c_2\frac{1-b^2}{(1+b^2-2b\cos g)^{3/2}}`
    (``Hg1`` = b, ``Hg2`` = c2); defaults are ISIS's.  Note ISIS's argument order: phase, incidence, emission.
    """
    cosg = np.cos(np.radians(np.asarray(phase_deg, dtype=np.float64)))
    b2 = hg1 * hg1
    pg = (1.0 - hg2) * (1.0 - b2) / (1.0 + b2 + 2.0 * hg1 * cosg) ** 1.5 + hg2 * (1.0 - b2) / (1.0 + b2 - 2.0 * hg1 * cosg) ** 1.5
    return _hapke_photomet(phase_deg, incidence_deg, emission_deg, wh, b0, hh, theta, pg)


def hapke_leg(phase_deg, incidence_deg, emission_deg, wh=0.5, b0=0.0, hh=0.0, theta=0.0, bh=0.0, ch=0.0):
    r"""ISIS ``HapkeLeg``: Legendre phase function :math:`p = 1 + b_h\cos g + c_h(1.5\cos^2 g - 0.5)`."""
    cosg = np.cos(np.radians(np.asarray(phase_deg, dtype=np.float64)))
    pg = 1.0 + bh * cosg + ch * (1.5 * cosg * cosg - 0.5)
    return _hapke_photomet(phase_deg, incidence_deg, emission_deg, wh, b0, hh, theta, pg)
