"""The response fit's objective (response/profile.py): the quantisation-weighted likelihood, its gradient and
Hessian against finite differences, and what the weights do on a steep film curve."""
from __future__ import annotations

import numpy as np
import pytest

from lunaralbedo.response import model as R
from lunaralbedo.response.fit import _fitted_levels
from lunaralbedo.response.profile import Profile, kappa_log_likelihood, level_log_likelihood, quantisation_weights
from lunaralbedo.response.synthetic import FilmCurve, render_stack


@pytest.fixture(scope="module")
def small():
    s = render_stack(n_images=4, shape=(24, 24), exposure_ratio=12.0, curve=FilmCurve(k=2.5), radiance_ratio=60, seed=3)
    obs = R.observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool))
    lev, keep = _fitted_levels(obs, 3, (0, 255))
    sub, _ = obs.take(keep)
    return sub, lev, (sub.dn - lev.lo).astype(np.int64)


def test_level_sums_give_the_per_observation_likelihood():
    rng = np.random.default_rng(0)
    lev = rng.integers(0, 7, 400)
    g, kap = rng.uniform(5, 50, 7), rng.uniform(0.05, 1.0, 7)
    mu = g[lev] * rng.lognormal(0, 0.2, 400)
    per_obs = kappa_log_likelihood(g[lev], mu, kap[lev])
    per_level = level_log_likelihood(g, kap, np.bincount(lev, minlength=7).astype(float),
                                     np.bincount(lev, np.log(mu), 7), np.bincount(lev, mu, 7))
    assert per_level == pytest.approx(per_obs, rel=1e-12)
    # kappa = 1 is Kim et al.'s eq. 8
    assert kappa_log_likelihood(g[lev], mu, np.ones(400)) == pytest.approx(R.log_likelihood(g[lev], mu), rel=1e-12)


@pytest.mark.parametrize("t_known", [True, False])
def test_gradient_and_hessian_match_finite_differences(small, t_known):
    sub, lev, lev_idx = small
    prof = Profile(sub, lev_idx, lev, np.exp(np.linspace(-1, 1, 4)) if t_known else None, smoothing=50.0, bins=True)
    prof.set_kappa(np.random.default_rng(1).uniform(0.2, 1.0, prof.n_lev))  # weights well away from 1
    p = np.full(prof.nv, 3.0 / prof.nv) + np.random.default_rng(2).uniform(0, 0.01, prof.nv)
    if not t_known:
        p = np.concatenate([p, [0.7, 1.4, 2.1]])
    val, grad = prof.fun(p)
    hess = prof.hess(p).copy()
    h = 1e-6
    num_g = np.array([(prof.fun(p + h * e)[0] - prof.fun(p - h * e)[0]) / (2 * h) for e in np.eye(len(p))])
    num_h = np.array([(prof.fun(p + h * e)[1] - prof.fun(p - h * e)[1]) / (2 * h) for e in np.eye(len(p))])
    assert np.allclose(grad, num_g, rtol=1e-4, atol=1e-7 * np.abs(grad).max())
    assert np.allclose(hess, num_h, rtol=1e-3, atol=1e-5 * np.abs(hess).max())


def test_quantisation_weights():
    # a bin whose uniform variance (w^2/12 in ln g) equals the photon noise's (1/g) halves the weight;
    # narrow bins weigh fully, a bin 16 photon standard deviations wide (w = 0.5 at 1000 counts) 1/22
    assert quantisation_weights(1200.0, 0.1) == pytest.approx(0.5)
    assert quantisation_weights(1000.0, 0.001) > 0.9999 and quantisation_weights(1000.0, 0.5) == pytest.approx(1 / 21.83, rel=1e-3)


def test_steep_curve_with_clipped_ends_beats_opencv():
    """A steep film curve (contrast 2.5) over a 200x radiance range: fog and saturation clip both ends, so the
    toe's and shoulder's DN bins span many photon standard deviations.  Without the quantisation weights
    (measured on these images) the fitted count scale fell to 32 (noise of 18 %, not the 3000 photons' ~2 %) and
    g erred by 2.7 %, behind OpenCV's Debevec (0.97 %).  With them the scale is the photon noise and g errs by
    0.12 % (another seed than the table of docs/response.md)."""
    from response_compare import curve_error, opencv_response

    from lunaralbedo.response.smoothing import fit_regularised

    s = render_stack(n_images=6, exposures=(40, 70, 120, 200, 350, 600), curve=FilmCurve(k=2.5), radiance_ratio=200,
                     seed=8)
    fit = fit_regularised(R.observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool)), s["exposure"])
    assert 1500 < fit.gamma["count_scale"] < 8000, fit.gamma["count_scale"]
    q = fit.gamma["quantisation_weight"]
    assert q["min"] < 0.05 and q["dn_of_min"] in (fit.levels.lo, fit.levels.hi)  # the clipped ends weigh least
    err = curve_error(fit.lut(), s["curve"])[0]
    assert err < 0.01, err
    for method in ("debevec", "robertson"):
        assert err < curve_error(opencv_response(s["dn"], s["exposure"], method), s["curve"])[0], method


def test_stirling_remainder_is_the_log_gamma_remainder():
    from scipy.special import gammaln

    from lunaralbedo.response.profile import stirling_remainder

    y = np.array([0.0, 0.3, 1.0, 9.9, 10.1, 50.0, 3e4])
    # long double reference: lnGamma(y+1) - y ln y + y, whose terms cancel for large y
    ref = np.array([float(np.longdouble(gammaln(v + 1.0)) - np.longdouble(v) * np.log(np.longdouble(v if v else 1.0))
                          + np.longdouble(v)) for v in y])
    assert np.allclose(stirling_remainder(y), ref, rtol=1e-9, atol=1e-9)


def test_one_blas_thread_inside_the_fit_only(monkeypatch):
    """The fit limits BLAS to one thread while it runs (its matrices are small; threads only spin on a shared
    machine) and leaves the process's setting as it was."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from lunaralbedo.response import fit as F

    seen = []
    solve = F._solve

    def spy(*a, **k):
        seen.append(max(i["num_threads"] for i in threadpool_info()))
        return solve(*a, **k)

    monkeypatch.setattr(F, "_solve", spy)
    s = render_stack(n_images=4, shape=(30, 30))
    with threadpool_limits(limits=2):
        before = [i["num_threads"] for i in threadpool_info()]
        F.fit_response(R.observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool)), s["exposure"])
        assert seen and max(seen) == 1
        assert [i["num_threads"] for i in threadpool_info()] == before
