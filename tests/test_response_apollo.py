"""Camera response on the real Apollo 15/16 DRGs of PhotometryTK's settings 1 (``../shared/photk_tests``).

The observations are the solver's own response pass (``solve --response estimate``), thinned to
every 4th DEM-grid pixel (about 112 000 of the 449 000 observations) to keep the test short (16 s CPU);
docs/response.md gives the full-data figures.  Skipped when ``../shared`` is absent.
"""
from __future__ import annotations

import numpy as np
import pytest

from lunaralbedo.engine.response_pass import response_observations
from lunaralbedo.engine.scene import build_scene
from lunaralbedo.response.fit import fit_response
from lunaralbedo.parallel import make_executor
from lunaralbedo.settings import load_settings


@pytest.fixture(scope="module")
def apollo_fit(photk_tests):
    settings = load_settings(photk_tests / "photometry_settings_1.txt")
    executor = make_executor(1, None, None, None, False)
    try:
        scene = build_scene(settings, False, map_fn=lambda f, xs: executor.map(f, xs, "masks"))
        obs = response_observations(scene, executor)
    finally:
        executor.close()
    sub, _ = obs.take(obs.pixel % 4 == 0)
    return sub, fit_response(sub, None)


def test_the_real_fit_converges_to_a_monotone_curve(apollo_fit):
    obs, fit = apollo_fit
    assert len(obs) > 100_000
    assert fit.converged and fit.message.startswith("KKT conditions hold"), fit.message
    steps = np.diff(fit.g)
    assert np.all(steps >= 0) and fit.g[fit.z_ref - fit.levels.lo] == pytest.approx(1.0)
    # (7) is active on these data: many pooled (flat) steps, which the log-increment fit never settled
    assert (steps == 0).sum() > 20
    assert np.all(np.isfinite(fit.exposure)) and np.all(fit.exposure > 0)


def test_the_real_fit_reports_its_misfit_and_why_gamma_is_the_prior(apollo_fit):
    _, fit = apollo_fit
    res = fit.residuals
    # the Poisson model misfits these DRGs badly (about 18 % RMS in log exposure; synthetic fits: ~1 %)
    assert 10 < res["chi2_per_dof"] < 60 and 0.1 < res["rms_log"] < 0.3, res
    ident = fit.gamma
    assert not ident["exposures_known"] and ident["gauge"] == "prior"
    geo = ident["geometry"]
    # strong reflectance variation within pixels, but the DN follow only ~30 % of it: rejected as model error
    assert geo["spread_log_c"] > 0.05 and geo["beta_under_prior"] < 0.5 and not geo["used"]
    assert "outside the plausible" in geo["reason"]
