"""EXPOSURE_MODE solve|fixed|prior: albedo in physical units from calibrated I/F, and exposures with a prior."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.engine.solve import solve
from lunaralbedo.io.outputs import read_exposure_csv
from lunaralbedo.model.exposure_prior import exposure_update_prior
from lunaralbedo.simulate import SceneSpec, render_scene, score, true_exposures


def _with(settings_file, path, **keys):
    """A copy of a settings file with ``keys`` replaced or added."""
    lines = [ln for ln in settings_file.read_text().splitlines() if ln.split()[:1] not in ([k] for k in keys)]
    path.write_text("\n".join(lines + [f"{k} {v}" for k, v in keys.items()]) + "\n")
    return path


def test_calibrated_lambert_strip_with_fixed_exposures_gives_the_albedo_in_physical_units(tmp_path):
    d = tmp_path / "scene"
    render_scene(d, SceneSpec(reflectance_type=1, calibrated=True, seed=12))
    assert "EXPOSURE_MODE" in (d / "settings.txt").read_text()  # the scene says its DRGs are calibrated
    solve(d / "settings.txt", out=tmp_path / "out", workers=1, plots=False)
    sc = score(tmp_path / "out", d)
    # no global scale fitted: the solved albedo is the truth's own numbers
    assert abs(sc["albedo_ratio_median"] - 1) <= 0.01 and sc["albedo_rel_rms_unscaled"] <= 0.02, sc
    assert set(read_exposure_csv(tmp_path / "out" / "exposure.csv").values()) == {1.0}


def test_fixed_exposures_from_a_file_and_a_prior_that_corrects_them(tmp_path):
    d = tmp_path / "scene"
    truth = render_scene(d, SceneSpec(reflectance_type=1, seed=13))
    t_true = true_exposures(truth)
    rng = np.random.default_rng(1)
    off = {k: t * (1 + rng.choice([-1, 1]) * 0.04) for k, t in t_true.items()}  # given exposures 4 % off
    (tmp_path / "exp.csv").write_text("key,exposure\n" + "".join(f"{k},{v}\n" for k, v in off.items()))
    fixed = _with(d / "settings.txt", d / "fixed.txt", EXPOSURE_MODE="fixed", EXPOSURE_FILE=tmp_path / "exp.csv")
    solve(fixed, out=tmp_path / "fixed", workers=1, plots=False)
    got = read_exposure_csv(tmp_path / "fixed" / "exposure.csv")
    assert all(got[k] == pytest.approx(off[k], rel=1e-8) for k in off)  # kept as given
    prior = _with(fixed, d / "prior.txt", EXPOSURE_MODE="prior", EXPOSURE_PRIOR_SIGMA=0.05)
    solve(prior, out=tmp_path / "prior", workers=1, plots=False)
    got = read_exposure_csv(tmp_path / "prior" / "exposure.csv")
    err_given = np.array([off[k] / t_true[k] - 1 for k in t_true])
    err_prior = np.array([got[k] / t_true[k] - 1 for k in t_true])
    # the data pull the relative exposures to the truth; the prior holds the overall scale (mean error of the given)
    rel = err_prior - err_prior.mean()
    assert np.abs(rel).max() < 0.005 < np.abs(err_given - err_given.mean()).max(), (err_given, err_prior)
    assert abs(err_prior.mean() - err_given.mean()) < 0.005


def test_the_prior_weighs_data_against_the_given_exposure():
    # one image, the data say 2.0 (num/den), the prior 1.0: sigma_n^2 = Q/N = 1
    t = exposure_update_prior([1.0], [2.0 * 100], [100.0], [1.0], sigma=0.1, q=10.0, n_obs=10)
    assert t[0] == pytest.approx((200 + 100 * 1.0) / (100 + 100))  # lambda = 1/(0.1*1)^2 = 100
    loose = exposure_update_prior([1.0], [2.0 * 100], [100.0], [1.0], sigma=100.0, q=10.0, n_obs=10)
    assert loose[0] == pytest.approx(2.0, rel=1e-5)


@pytest.mark.parametrize("key,value,needle", [
    ("EXPOSURE_MODE", "guess", "EXPOSURE_MODE must be one of solve, fixed, prior"),
    ("EXPOSURE_PRIOR_SIGMA", "0", "EXPOSURE_PRIOR_SIGMA must be a number > 0"),
    ("EXPOSURE_FILE", "nothere.csv", "EXPOSURE_FILE"),
])
def test_bad_exposure_settings_exit_2_naming_the_key(tmp_path, key, value, needle):
    d = tmp_path / "scene"
    render_scene(d, SceneSpec(n_images=2, image_px=40, seed=3))
    keys = {key: value} if key != "EXPOSURE_FILE" else {"EXPOSURE_MODE": "fixed", key: value}
    s = _with(d / "settings.txt", d / "bad.txt", **keys)
    res = CliRunner().invoke(main, ["solve", str(s), "-o", str(tmp_path / "o"), "--workers", "1", "--quiet"])
    assert res.exit_code == 2 and needle in res.output and "Traceback" not in res.output, res.output
    assert not (tmp_path / "o").exists()
