r"""The weight of the roughness penalty, chosen by the data, and how much of g the exposures determine.

Kim et al.'s likelihood (eq. 8) ties DN levels together only through pixels seen in several
images.  When the log exposure ratios are (nearly) multiples of one period :math:`P`, the data
cannot tell :math:`g` from :math:`g\,e^{p(\ln g)}` with :math:`p` periodic of period :math:`P`: each
pixel's factor :math:`e^{p(\ln r_i)}` goes into its radiance.  :func:`exposure_diagnosis` measures
this; :func:`fit_regularised` adds the roughness penalty of :mod:`.fit` (second differences of
:math:`\ln g`, Debevec and Malik's hat weights) with the weight that predicts held-out pixels best.

Cross-validation (:func:`choose_smoothing`): the pixels are split into ``folds`` fixed random
groups; for each weight on a grid, the fit on the other groups predicts each DN of a held-out
pixel from that pixel's *other* observations (its radiance by eq. 10 in logs, then :math:`f = g^{-1}`
by interpolation), and the score is the mean squared DN error.  The weights are tried in
increasing order until one predicts worse than the best so far by more than one standard
error (paired over the held-out pixels); the weight chosen is the one with the least error.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from threadpoolctl import threadpool_limits

from .fit import BLAS_THREADS, ResponseFit, fit_response
from .model import Observations

#: Candidate weights per observation of the fit (0: Kim et al.'s fit unpenalised); the weight is this times N.
GRID_PER_OBS = (0.0, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1e3, 3e3, 1e4, 3e4, 1e5)
#: Pixel groups of the cross-validation.
FOLDS = 2
#: Observations the cross-validation uses at most (a fixed subset of pixels beyond).
CV_MAX_OBS = 150_000
#: Periods (in ln exposure) searched by the diagnosis.
PERIODS = np.linspace(0.05, 3.0, 600)
#: Observations the diagnosis uses at most (a fixed subset of pixels beyond: it is a mean over pixels).
DIAGNOSIS_MAX_OBS = 100_000


def exposure_diagnosis(obs: Observations, exposure: np.ndarray, periods: np.ndarray = PERIODS) -> dict:
    r"""How much of g the exposure ratios determine.

    A modulation :math:`e^{2\pi i \ln g / P}` of the curve is absorbed into a pixel's radiance when
    the phases :math:`\phi_n = 2\pi \ln(t_{j(n)} c_n) / P` of its observations agree.  The
    *visibility* of period :math:`P` is the observation-weighted mean over pixels of
    :math:`1 - |\overline{e^{i\phi}}|^2` (0: invisible, the data cannot see waves of that period;
    about 1: fully determined).  Returns the smallest visibility over ``periods`` (ln units), its
    longest period (also as an exposure ratio; P/2, P/3 ... are as invisible as P) and the fraction of periods with visibility below 0.1.
    Pixels seen once are left out; beyond ``DIAGNOSIS_MAX_OBS`` observations, every k-th pixel is used.
    """
    n_i = np.bincount(obs.pixel, minlength=obs.n_pixels)
    many = n_i[obs.pixel] >= 2
    step = max(1, -(-int(many.sum()) // DIAGNOSIS_MAX_OBS))  # a fixed subset of pixels beyond that many observations
    many &= obs.pixel % step == 0
    u = np.log(np.asarray(exposure, np.float64)[obs.image[many]])
    if obs.factor is not None:
        u = u + np.log(obs.factor[many])
    pix = np.unique(obs.pixel[many], return_inverse=True)[1]
    u_uniq, u_idx = np.unique(u, return_inverse=True)  # the images' exposures when there is no factor: few values
    m = sp.csr_matrix((np.ones(len(u)), (pix, u_idx)), shape=(int(pix.max()) + 1 if len(pix) else 0, len(u_uniq)))
    n_pix = np.asarray(m.sum(axis=1)).ravel()
    vis = np.empty(len(periods))
    chunk = max(1, 2_000_000 // max(len(u_uniq), 1))  # periods at a time: about 32 MB of phase factors
    for k0 in range(0, len(periods), chunk):  # per pixel: the sum of e^{i phase} over its observations
        per = np.asarray(periods[k0:k0 + chunk], np.float64)
        sums = m @ np.exp(2j * np.pi * u_uniq[:, None] / per[None, :])
        vis[k0:k0 + len(per)] = 1.0 - (np.abs(sums) ** 2 / n_pix[:, None]).sum(axis=0) / max(n_pix.sum(), 1)
    k = int(np.flatnonzero(vis <= vis.min() + 0.01)[-1])  # the longest of the least visible (P/2, P/3 ... tie with P)
    return {"min_visibility": float(vis[k]), "worst_period_log": float(periods[k]),
            "worst_period_ratio": float(np.exp(periods[k])), "fraction_poorly_seen": float(np.mean(vis < 0.1)),
            "log_ratios_between_images": np.round(np.diff(np.sort(np.log(exposure))), 4).tolist()}


def heldout_error(fit: ResponseFit, obs: Observations) -> np.ndarray:
    """Per pixel of ``obs`` (NaN where not scored): the mean squared DN error of predicting each of its
    observations from its other ones."""
    lev = fit.levels
    ok = (obs.dn >= lev.lo) & (obs.dn <= lev.hi)
    lg = np.log(fit.g)
    lct = np.log(np.asarray(fit.exposure, np.float64)[obs.image])
    if obs.factor is not None:
        lct = lct + np.log(obs.factor)
    u = np.where(ok, lg[np.clip(obs.dn - lev.lo, 0, len(lg) - 1)] - lct, 0.0)
    cnt = np.bincount(obs.pixel, ok.astype(float), obs.n_pixels)
    tot = np.bincount(obs.pixel, u, obs.n_pixels)
    use = ok & (cnt[obs.pixel] >= 2)
    pix = obs.pixel[use]
    log_r = (tot[pix] - u[use]) / (cnt[pix] - 1)  # eq. 10 in logs without the observation itself
    z_hat = np.interp(log_r + lct[use], lg, lev.dn.astype(np.float64))
    err2 = (obs.dn[use] - z_hat) ** 2
    per_pix = np.bincount(pix, err2, obs.n_pixels)
    n_pix = np.bincount(pix, minlength=obs.n_pixels)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n_pix > 0, per_pix / n_pix, np.nan)


def choose_smoothing(obs: Observations, exposure, grid_per_obs=GRID_PER_OBS, folds: int = FOLDS, seed: int = 0,
                     **fit_kw) -> dict:
    """Cross-validated weight (module doc): the grid, the held-out scores and the weight chosen.

    Beyond ``CV_MAX_OBS`` observations the cross-validation runs on a fixed subset of pixels (every k-th): the
    weight is per observation, so it carries over to the fit on all of them (a slight over-smoothing at most)."""
    step = max(1, -(-len(obs) // CV_MAX_OBS))
    if step > 1:
        obs = obs.take(obs.pixel % step == 0)[0]
    group = np.random.default_rng(seed).integers(0, folds, obs.n_pixels)[obs.pixel]
    splits = [(obs.take(group != f)[0], obs.take(group == f)[0]) for f in range(folds)]
    errors, excess = [], []  # per held-out pixel, per weight; excess over the best: mean and paired s.e.
    for lam in grid_per_obs:
        e = np.concatenate([heldout_error(fit_response(train, exposure, smoothing=lam * len(train), **fit_kw), test)
                            for train, test in splits])
        errors.append(e)
        ok = np.all(np.isfinite(np.array(errors)), axis=0)
        scores = [float(np.mean(x[ok])) for x in errors]
        best = int(np.argmin(scores))
        excess = [(scores[k] - scores[best], float(np.std(errors[k][ok] - errors[best][ok]) / np.sqrt(ok.sum())))
                  for k in range(len(errors))]
        if excess[-1][0] > excess[-1][1]:  # significantly worse than the best: past it
            break
    pick = int(np.argmin(scores))
    return {"weight_per_observation": float(grid_per_obs[pick]), "rule": f"{folds}-fold cross-validation over pixels: the weight with the least held-out DN error",
            "cv_observations": len(obs),
            "grid_per_observation": [float(v) for v in grid_per_obs[:len(errors)]], "heldout_dn_mse": scores,
            "excess_over_best": [d for d, _ in excess], "excess_se": [se for _, se in excess]}


@threadpool_limits.wrap(limits=BLAS_THREADS, user_api="blas")
def fit_regularised(obs: Observations, exposure=None, smoothing="auto", bins: bool = True, **fit_kw) -> ResponseFit:
    """:func:`.fit.fit_response` with the roughness weight chosen by :func:`choose_smoothing` ("auto")
    or given (a weight per observation); ``fit.smoothing`` records it and the exposure diagnosis."""
    fit_kw["bins"] = bins
    if smoothing == "auto":
        info = choose_smoothing(obs, exposure, **fit_kw)
    else:
        info = {"weight_per_observation": float(smoothing), "rule": "given"}
    info["weight"] = info["weight_per_observation"] * len(obs)
    fit = fit_response(obs, exposure, smoothing=info["weight"], **fit_kw)
    info["exposure_ratios"] = exposure_diagnosis(obs, fit.exposure)
    fit.smoothing = info
    return fit
