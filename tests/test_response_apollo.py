"""Camera response on the real Apollo 15/16 DRGs of PhotometryTK's settings 1 (``../shared/photk_tests``).

The observations are the solver's own response pass (``solve --response estimate``), thinned to
every 4th DEM-grid pixel (about 112 000 of the 449 000 observations) to keep the test short;
docs/response.md gives the full-data figures.  Skipped when ``../shared`` is absent.
"""
from __future__ import annotations

import numpy as np
import pytest

from lunaralbedo.engine.response_pass import response_observations
from lunaralbedo.engine.scene import build_scene
from lunaralbedo.parallel import make_executor
from lunaralbedo.response.aligned import longest_flat_run
from lunaralbedo.response.fit import fit_response
from lunaralbedo.response.smoothing import fit_regularised, heldout_error
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


def test_the_real_fit_converges_to_a_smooth_monotone_curve(apollo_fit):
    obs, fit, unpenalised = apollo_fit
    assert len(obs) > 100_000
    assert fit.converged and fit.message.startswith("KKT conditions hold"), fit.message
    steps = np.diff(fit.g)
    assert np.all(steps >= 0) and fit.g[fit.z_ref - fit.levels.lo] == pytest.approx(1.0)
    assert np.all(np.isfinite(fit.exposure)) and np.all(fit.exposure > 0)
    # Kim et al.'s fit alone pools whole runs of DN (eq. 7 active: the data want g to fall there); with the DN
    # bins an observed DN cannot have an empty bin, so no flat run is left
    assert longest_flat_run(unpenalised.g) > 20
    assert longest_flat_run(fit.g) <= 3


def test_the_real_fit_predicts_held_out_pixels_better(apollo_fit):
    """The independent check on real data: fitted on half of the pixels, each curve predicts every DN of the
    other half from that pixel's other observations; ours errs less than Kim et al.'s fit alone (measured on
    this split: mean squared DN error 476 against 573; a linear response 574)."""
    obs, fit, _ = apollo_fit
    half = np.random.default_rng(1).integers(0, 2, obs.n_pixels)[obs.pixel] == 0
    train, _ = obs.take(half)
    test, _ = obs.take(~half)
    weight = fit.smoothing["weight_per_observation"] * len(train)
    ours = heldout_error(fit_response(train, None, smoothing=weight, bins=True), test)
    kim = heldout_error(fit_response(train, None), test)
    ok = np.isfinite(ours) & np.isfinite(kim)
    assert ok.sum() > 2000  # of the ~2250 pixels of the held-out half
    assert np.mean(ours[ok]) < 0.95 * np.mean(kim[ok]), (np.mean(ours[ok]), np.mean(kim[ok]))


def test_the_real_fit_reports_its_misfit_and_why_gamma_is_the_prior(apollo_fit):
    _, fit, unpenalised = apollo_fit
    res = fit.residuals
    # the Poisson model misfits these DRGs: the fitted count scale is small (the noise of ~30 counts, 18 %
    # RMS in log exposure; synthetic stacks: thousands), and at that scale Pearson's chi2/dof is about 1;
    # in the sample the smooth curve fits a little worse than the unconstrained maximum (held out: better)
    assert 10 < fit.gamma["count_scale"] < 100 and 0.7 < res["chi2_per_dof"] < 1.4, (fit.gamma, res)
    assert res["rms_log"] < 1.1 * unpenalised.residuals["rms_log"]
    ident = fit.gamma
    assert not ident["exposures_known"] and ident["gauge"] == "prior"
    geo = ident["geometry"]
    # strong reflectance variation within pixels, but the DN follow only part of it: rejected as model error
    assert geo["spread_log_c"] > 0.05 and geo["beta_under_prior"] < 0.5 and not geo["used"]
    assert "outside the plausible" in geo["reason"]
    # 53 images at unrelated exposures: no period of a wave in g goes unseen
    assert fit.smoothing["exposure_ratios"]["min_visibility"] > 0.1
