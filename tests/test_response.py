"""Camera response recovery, aligned case (Kim et al., section 3): truth recovery, ambiguity, OpenCV, CLI."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from rasterio.transform import Affine

from lunaralbedo.cli import main
from lunaralbedo.io.rasters import MOON_CRS
from lunaralbedo.io.geotiff import write_geotiff
from lunaralbedo.response.io import read_response_csv
from lunaralbedo.response import model as R
from lunaralbedo.response.fit import fit_response
from lunaralbedo.response.smoothing import exposure_diagnosis, fit_regularised
from lunaralbedo.response.synthetic import render_stack
from response_compare import curve_error, opencv_response

TOL = 0.03  # log-RMS over DN 10-245 after one global scale (issue 16)


@pytest.fixture(scope="module")
def stack():
    return render_stack(n_images=8, shape=(120, 120), exposure_ratio=32.0, photons=3000.0, seed=1)


@pytest.fixture(scope="module")
def obs(stack):
    return R.observations_from_stack(stack["dn"], np.ones(stack["dn"].shape, bool))


@pytest.fixture(scope="module")
def fit_known(obs, stack):
    return fit_response(obs, stack["exposure"])


def test_known_exposures_recover_the_truth(fit_known, stack):
    err, cover = curve_error(fit_known.lut(), stack["curve"])
    assert cover == 1.0 and err < TOL, err
    assert fit_known.converged
    assert np.all(np.diff(fit_known.g) >= 0) and fit_known.g[fit_known.z_ref - fit_known.levels.lo] == pytest.approx(1.0)
    # the Newton step improves the likelihood over the closed-form alternation it starts from
    assert fit_known.loglik[-1] > fit_known.loglik[fit_known.n_juggle - 1]
    # the radiance agrees with the truth up to the one scale
    ratio = fit_known.radiance / stack["radiance"].ravel()
    ok = np.isfinite(ratio)
    assert ok.mean() > 0.95 and np.std(np.log(ratio[ok])) < 0.03


def test_unknown_exposures_fix_the_gamma_ambiguity_by_the_documented_prior(obs, stack):
    fit = fit_response(obs, None)
    info = fit.gamma
    assert not info["exposures_known"] and "linear" in info["prior"] and fit.converged
    assert info["gauge"] == "prior" and "geometry" not in info  # an aligned stack has no reflectance factor
    # the prior is honoured: unit log-log slope of g over the mid range
    sel = (fit.levels.dn >= 64) & (fit.levels.dn <= 192)
    assert np.polyfit(np.log(fit.levels.dn[sel]), np.log(fit.g[sel]), 1)[0] == pytest.approx(1.0, abs=1e-6)
    # the data determine g only up to g -> g^gamma: the truth is recovered after that one exponent ...
    z = np.arange(10, 246)
    g_est, g_true = fit.lut()[z].astype(float), stack["curve"].inverse(z)
    gamma = np.polyfit(np.log(g_true), np.log(g_est), 1)[0]
    assert abs(gamma - 1) > 0.1  # ... which the (film-like) truth really needs
    assert R.log_rms_error(g_est ** (1 / gamma), g_true) < TOL
    # ... and the exposures are t_true^gamma
    t = fit.exposure ** (1 / gamma)
    rel = t / stack["exposure"]
    assert np.max(np.abs(rel / np.exp(np.mean(np.log(rel))) - 1)) < 0.02


def test_closed_forms():
    y = np.linspace(-3, 6, 50)
    from scipy.special import digamma

    assert np.allclose(digamma(R.inverse_digamma(y)), y, atol=1e-10)
    # eq. 12 under (7): a decreasing pair of level means is pooled, output non-decreasing
    level = np.array([0, 0, 1, 1, 2, 2])
    log_mu = np.log([10, 10, 30, 30, 20, 20.0])
    g = R.response_closed_form(log_mu, level, 3)
    assert np.all(np.diff(g) >= 0) and g[1] == pytest.approx(g[2])
    assert np.allclose(R.response_closed_form(np.log([5.0, 5.0]), np.array([0, 1]), 2, exact=False), 5.0)


def test_active_monotonicity_constraints_are_settled_in_finite_steps(stack):
    """Where the likelihood wants g to decrease, (7) is active: the fit pools those levels and converges.

    Relabelling DN 120 <-> 135 in the stack makes the data say g(120) > g(135); the maximum
    under (7) then has a flat step between them.  (The log-increment parametrisation put such
    a step at -infinity and never settled: the Apollo DRGs, docs/response.md.)
    """
    dn = stack["dn"].astype(np.int16)
    swapped = dn.copy()
    swapped[dn == 120], swapped[dn == 135] = 135, 120
    fit = fit_response(R.observations_from_stack(swapped, np.ones(dn.shape, bool)), stack["exposure"])
    assert fit.converged and fit.message.startswith("KKT conditions hold")
    steps = np.diff(fit.g)
    assert np.all(steps >= 0)
    z = fit.levels.dn[1:]
    assert np.any(steps[(z > 120) & (z <= 135)] == 0)  # pooled: g(120..135) share values
    # away from the relabelled levels the curve is still the truth's
    far = (fit.levels.dn < 110) | (fit.levels.dn > 145)
    assert R.log_rms_error(fit.g[far], stack["curve"].inverse(fit.levels.dn[far])) < TOL


def test_choose_gauge_rules():
    from lunaralbedo.response.model import choose_gauge

    ok, why = choose_gauge(0.70, 0.006, 0.006)  # the synthetic film strip: g ~ z^1.43 in the mid range
    assert ok and "1.43" in why
    ok, why = choose_gauge(0.30, 0.002, 0.10)  # the Apollo DRGs: implies g ~ z^3.3
    assert not ok and "outside the plausible" in why
    ok, why = choose_gauge(0.9, 0.2, 0.01)
    assert not ok and "too uncertain" in why
    ok, why = choose_gauge(0.0, 0.0, 0.0)
    assert not ok and "no reflectance variation" in why
    assert choose_gauge(0.30, 0.002, 0.10, mode="geometry")[0]


def test_rare_dn_are_interpolated_not_fitted(stack):
    dn = stack["dn"].copy()
    valid = np.ones(dn.shape, bool)
    rare = (dn >= 100) & (dn <= 104)
    valid[rare] = np.random.default_rng(0).random(rare.sum()) < 0.03  # keep ~3 % of those observations
    fit = fit_response(R.observations_from_stack(dn, valid), stack["exposure"], min_count=20)
    free = np.isin(fit.levels.dn, fit.levels.knots)
    assert not free[(fit.levels.dn >= 100) & (fit.levels.dn <= 104)].any()
    assert curve_error(fit.lut(), stack["curve"])[0] < TOL
    assert np.all(np.diff(fit.g) >= 0)


def test_residual_analysis_describes_the_fit(fit_known, stack):
    res = fit_known.residuals
    assert 0.3 < res["chi2_per_dof"] < 3  # Poisson noise model roughly right at the fitted scale
    assert res["rms_log"] < 0.1 and np.nanmax(np.abs(res["bias_log"])) < 0.05
    # the uncertainty of g shrinks as 1/sqrt(observations): a quarter of the pixels doubles it
    dn = stack["dn"][:, ::2, ::2]
    quarter = fit_response(R.observations_from_stack(dn, np.ones(dn.shape, bool)), stack["exposure"])
    common, i_q, i_f = np.intersect1d(quarter.levels.dn, fit_known.levels.dn, return_indices=True)
    ratio = np.nanmedian(quarter.residuals["se_log_g"][i_q] / res["se_log_g"][i_f])
    assert 1.6 < ratio < 2.5, ratio


#: The issue's stack: 6 exposures at nearly one ratio (1.67-1.75), so the data barely see waves of that period.
NEAR_GEOMETRIC = (40, 70, 120, 200, 350, 600)


def _log_error_and_waves(lut, curve, lo=10, hi=245):
    """Log-RMS error of g over DN lo..hi after one scale, and its part that a degree-5 polynomial in DN does not explain."""
    z = np.arange(lo, hi + 1)
    d = np.log(np.asarray(lut, np.float64)[z]) - np.log(curve.inverse(z))
    assert np.all(np.isfinite(d))
    waves = d - np.polyval(np.polyfit(z, d, 5), z)
    return float(np.sqrt(np.mean((d - d.mean()) ** 2))), float(np.sqrt(np.mean(waves**2)))


def test_nearly_commensurate_exposures_smooth_fit_beats_opencv():
    """A held-out stack (seed 7; the weight grid and rule were tuned on seeds 1 and 11): the DN bins with the
    fitted count scale and the cross-validated roughness penalty keep g within 4.5 % log-RMS of the truth
    (measured 0.16 %), its waves under 1.5 %, and no worse than either OpenCV method on the same images
    (Debevec 1.87 %, Robertson 0.36 %)."""
    s = render_stack(n_images=6, exposures=NEAR_GEOMETRIC, seed=7)
    obs = R.observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool))
    fit = fit_regularised(obs, s["exposure"])
    err, waves = _log_error_and_waves(fit.lut(), s["curve"])
    assert err <= 0.045 and waves <= 0.015, (err, waves)
    for method in ("debevec", "robertson"):
        assert err <= _log_error_and_waves(opencv_response(s["dn"], s["exposure"], method), s["curve"])[0], method
    # Kim et al.'s fit alone on the same images is worse (0.43 %): the likelihood prefers waves there
    assert err < _log_error_and_waves(fit_response(obs, s["exposure"]).lut(), s["curve"])[0]
    sm = fit.smoothing
    k = sm["grid_per_observation"].index(sm["weight_per_observation"])
    assert sm["weight"] > 0 and sm["heldout_dn_mse"][k] == min(sm["heldout_dn_mse"])
    # the fitted count scale (geometric mean of g(z_n) in counts) is the photon noise of 3000 per unit exposure (~2600)
    assert 1500 < fit.gamma["count_scale"] < 4500, fit.gamma["count_scale"]
    # the diagnosis finds the near-common ratio (1.67-1.75) and how little the data see waves of that period
    d = sm["exposure_ratios"]
    assert 1.65 < d["worst_period_ratio"] < 1.76 and d["min_visibility"] < 0.1, d


def test_exposure_diagnosis_tells_commensurate_from_incommensurate_ratios():
    """Exactly geometric exposures leave waves of one ratio invisible (visibility 0); ratios 2 and 3 leave
    none that invisible (three images: some period is always seen poorly, none unseen)."""
    rng = np.random.default_rng(0)
    pix, img = np.repeat(np.arange(500), 3), np.tile(np.arange(3), 500)
    obs = R.Observations(pix, img, rng.integers(20, 230, len(pix)), 500, 3)
    geometric = exposure_diagnosis(obs, np.array([1.0, 1.5, 2.25]))
    assert geometric["min_visibility"] < 0.01 and abs(geometric["worst_period_ratio"] - 1.5) < 0.01
    other = exposure_diagnosis(obs, np.array([1.0, 2.0, 6.0]))["min_visibility"]
    assert other > 0.02 and other > 10 * geometric["min_visibility"], other


def test_at_least_as_good_as_opencv_where_photon_noise_matters():
    s = render_stack(n_images=4, exposure_ratio=10.0, shape=(200, 200), seed=1)
    ours = fit_response(R.observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool)), s["exposure"])
    e_ours = curve_error(ours.lut(), s["curve"])[0]
    e_cv = min(curve_error(opencv_response(s["dn"], s["exposure"], m), s["curve"])[0] for m in ("debevec", "robertson"))
    assert e_ours <= e_cv, (e_ours, e_cv)


def _write_stack(folder, s):
    names = []
    for k, im in enumerate(s["dn"]):
        write_geotiff(folder / f"img{k}.tif", im, Affine(0.01, 0, 10, 0, -0.01, 5), MOON_CRS)
        names.append(f"img{k}.tif")
    return names


def test_cli_writes_the_documented_outputs(tmp_path, monkeypatch):
    s = render_stack(n_images=5, shape=(60, 60), exposure_ratio=16.0, seed=4)
    monkeypatch.chdir(tmp_path)
    names = _write_stack(tmp_path, s)
    (tmp_path / "t.csv").write_text("image,exposure\n" + "".join(f"{n},{t}\n" for n, t in zip(names, s["exposure"])))
    res = CliRunner().invoke(main, ["response", *names, "--exposure-times", "t.csv", "-o", "out"])
    assert res.exit_code == 0, res.output
    out = tmp_path / "out"
    lut = read_response_csv(out / "response.csv")
    assert curve_error(lut, s["curve"])[0] < 2 * TOL
    for png in ("response.png", "loglik.png", "residuals.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
    # exposures given: nothing estimated, so no exposure.csv / exposure.png
    assert (out / "radiance.tif").exists() and not (out / "exposure.csv").exists() and not (out / "exposure.png").exists()
    res = CliRunner().invoke(main, ["response", *names, "-o", "out2", "--no-plots"])
    assert res.exit_code == 0 and "ambiguity" in res.output
    assert (tmp_path / "out2" / "exposure.csv").read_text().startswith("image,exposure\n")


def test_cli_bad_inputs_fail_cleanly(tmp_path, monkeypatch):
    s = render_stack(n_images=3, shape=(30, 30), seed=5)
    monkeypatch.chdir(tmp_path)
    names = _write_stack(tmp_path, s)
    (tmp_path / "t.csv").write_text("image,exposure\nimg0.tif,1\n")
    res = CliRunner().invoke(main, ["response", *names, "--exposure-times", "t.csv", "-o", "out"])
    assert res.exit_code == 2 and "t.csv: no exposure for image 'img1.tif'" in res.output
    assert not (tmp_path / "out").exists()
    write_geotiff(tmp_path / "small.tif", s["dn"][0][:10], Affine(0.01, 0, 10, 0, -0.01, 5), MOON_CRS)
    res = CliRunner().invoke(main, ["response", "img0.tif", "small.tif", "-o", "out"])
    assert res.exit_code == 2 and "co-registered" in res.output and "Traceback" not in res.output
    (tmp_path / "bad.csv").write_text("dn,g\n10,2\n11,1\n")
    with pytest.raises(Exception, match="non-decreasing"):
        read_response_csv(tmp_path / "bad.csv")
