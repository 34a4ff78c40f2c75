"""Camera response on the real Apollo 15/16 DRGs of PhotometryTK's settings 1 (``../shared/photk_tests``).

The observations are the solver's own response pass (``solve --response estimate``), thinned to
every 4th DEM-grid pixel (about 112 000 of the 449 000 observations) to keep the test short;
docs/response.md gives the full-data figures.  Skipped when ``../shared`` is absent.
"""
from __future__ import annotations

import numpy as np
import pytest

from lunaralbedo.engine.observations import response_observations
from lunaralbedo.engine.scene import build_scene
from lunaralbedo.parallel import make_executor
from lunaralbedo.response.aligned import longest_flat_run
from lunaralbedo.response.fit import fit_response
from lunaralbedo.response.smoothing import fit_regularised
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
    return sub, fit_regularised(sub, None), fit_response(sub, None)


def test_the_real_fit_converges_to_a_monotone_curve(apollo_fit):
    obs, fit, unpenalised = apollo_fit
    assert len(obs) > 100_000
    assert fit.converged and fit.message.startswith("KKT conditions hold"), fit.message
    steps = np.diff(fit.g)
    assert np.all(steps >= 0) and fit.g[fit.z_ref - fit.levels.lo] == pytest.approx(1.0)
    assert np.all(np.isfinite(fit.exposure)) and np.all(fit.exposure > 0)
    # (7) is active on these data: the data want g to fall over whole runs of DN (docs/response.md); the
    # cross-validated penalty (a small weight: the held-out error rises beyond it) closes only some of them
    sm = fit.smoothing
    assert 0 < sm["weight_per_observation"] <= 10 and len(sm["grid_per_observation"]) >= 3
    k = sm["grid_per_observation"].index(sm["weight_per_observation"])
    assert sm["excess_over_best"][k] <= sm["excess_se"][k] and sm["excess_over_best"][-1] > sm["excess_se"][-1]
    assert (steps == 0).sum() < (np.diff(unpenalised.g) == 0).sum()
    assert longest_flat_run(fit.g) <= longest_flat_run(unpenalised.g)


def test_the_real_fit_reports_its_misfit_and_why_gamma_is_the_prior(apollo_fit):
    _, fit, unpenalised = apollo_fit
    res = fit.residuals
    # the Poisson model misfits these DRGs badly (about 18 % RMS in log exposure; synthetic fits: ~1 %) and the
    # penalty leaves the misfit as it was (the unpenalised maximum of eq. 8 on the same observations)
    assert res["rms_log"] <= 1.001 * unpenalised.residuals["rms_log"], (res, unpenalised.residuals)
    assert res["chi2_per_dof"] <= 1.001 * unpenalised.residuals["chi2_per_dof"]
    assert 0.1 < res["rms_log"] < 0.3
    ident = fit.gamma
    assert not ident["exposures_known"] and ident["gauge"] == "prior"
    geo = ident["geometry"]
    # strong reflectance variation within pixels, but the DN follow only ~30 % of it: rejected as model error
    assert geo["spread_log_c"] > 0.05 and geo["beta_under_prior"] < 0.5 and not geo["used"]
    assert "outside the plausible" in geo["reason"]
    # 53 images at unrelated exposures: no period of a wave in g goes unseen
    assert fit.smoothing["exposure_ratios"]["min_visibility"] > 0.1
