"""Hapke functions against ISIS's unit-test truth (isis/src/base/objs/Hapke/Hapke.truth) and limiting cases."""
from __future__ import annotations

import numpy as np
import pytest

from lunaralbedo.model.photometry.hapke import h_function, hapke_hen, hapke_leg, hapke_lroc

ROUGH = dict(wh=0.52, b0=1.0, hh=1.0, theta=30.0)


@pytest.mark.parametrize("func, kwargs, truth", [
    (hapke_hen, {}, (0.0965097, 0.0832883)),
    (hapke_hen, dict(ROUGH, hg1=0.213, hg2=1.0), (0.286048, 0.1342)),
    (hapke_leg, dict(ROUGH, bh=0.0, ch=0.0), (0.16145, 0.111525)),
])
def test_isis_photomet_truth(func, kwargs, truth):
    """(phase, incidence, emission) = (0, 0, 0) and (60, 45, 30); (180, 90, 90) gives 0, as ISIS prints."""
    got = [float(func(0.0, 0.0, 0.0, **kwargs)), float(func(60.0, 45.0, 30.0, **kwargs))]
    np.testing.assert_allclose(got, truth, rtol=5e-6)  # ISIS prints 6 significant digits
    assert float(func(180.0, 90.0, 90.0, **kwargs)) == 0.0


def test_hapke_lroc_smooth_limit_and_porosity():
    """theta = 0, no opposition, isotropic single scattering: r = w/4 mu0/(mu0+mu) H(mu0) H(mu) with Hapke 2002 H."""
    i, e, g = 40.0, 20.0, 50.0
    w = 0.3
    mu0, mu = np.cos(np.radians(i)), np.cos(np.radians(e))
    sq = np.sqrt(1 - w)
    r0 = (1 - sq) / (1 + sq)
    want = w / 4 * mu0 / (mu0 + mu) * h_function(mu0, w, r0) * h_function(mu, w, r0)
    got = hapke_lroc(i, e, g, w, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # b = 0, c = 0 -> p(g) = 1
    assert float(got) == pytest.approx(float(want), rel=1e-12)
    # porosity phi > 0 (K > 1) raises the reflectance; roughness darkens a grazing-light geometry
    assert hapke_lroc(i, e, g, w, 0, 0, 0, 0, 0, 0, 0, 0.3) > got
    assert hapke_lroc(80.0, 0.0, 80.0, w, 0, 0, 0, 0, 0, 0, 20.0, 0) < hapke_lroc(80.0, 0.0, 80.0, w, *[0] * 8)
    assert float(hapke_lroc(90.0, 0.0, 90.0, w, *[0] * 8)) == 0.0
