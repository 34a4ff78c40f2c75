"""What a solve's passes reduce to: the initial exposures from the tiles' prepare sums, one pass's sums over the
tiles (in tile order), and the state they update (eqs. 4 and 5 of the PhotometryTK manual, the joint exposure-haze
step of :mod:`lunaralbedo.model.haze`, the exposures' prior of :mod:`lunaralbedo.model.exposure_prior`)."""
from __future__ import annotations

import numpy as np

from ..model import exposure_init, exposure_prior, haze, updates
from .scene import Scene
from .tilework import SolveState


def prepare_pairs(metas: list[dict]) -> dict:
    """The overlaps' log-ratio sums ``{(j, k): (n, sum d)}`` of the prepare step, merged in tile order."""
    pairs: dict = {}
    for meta in metas:  # fixed tile order
        exposure_init.merge_pair_sums(pairs, {(j, k): (nn, d) for j, k, nn, d in meta["pairs"]})
    return pairs


def reduce_init(scene: Scene, metas: list[dict], method: str) -> np.ndarray:
    n = len(scene.images)
    r_sum, r_cnt = np.zeros(n), np.zeros(n)
    for meta in metas:  # fixed tile order
        idx = np.asarray(meta["index"], dtype=int)
        np.add.at(r_sum, idx, meta["r_sum"])
        np.add.at(r_cnt, idx, meta["r_count"])
    t_seed = exposure_init.seed_exposure(scene.settings.tr_const, r_sum, r_cnt)
    if method == "seed":
        return t_seed
    return exposure_init.overlap_exposure(prepare_pairs(metas), np.log(t_seed))


def reduce_iteration(n_images: int, n_params: int, parts) -> updates.PassSums:
    total = updates.PassSums(n_images, n_params)
    for p in parts:  # fixed tile order: identical sums for any number of workers
        total.add(p)
    return total


def update(state: SolveState, sums: updates.PassSums, method: str, model, t_ref: np.ndarray, fixed: bool = False,
            prior: float | None = None) -> SolveState:
    """One update of exposures (eq. 4; with FLOAT_HAZE the joint step, or nothing once the haze has settled) and
    parameters (eq. 5); ``fixed``: the exposures are known (kept);
    ``prior``: the relative sigma of a Gaussian prior around ``t_ref`` (:mod:`lunaralbedo.model.exposure_prior`)."""
    h = state.haze
    held = h is not None and not sums.haze_parts  # FLOAT_HAZE, settled: the joint step's exposures and haze held
    if h is not None and sums.haze_parts:  # FLOAT_HAZE: one joint (T, H) step with the albedo eliminated (model/haze.py)
        g, mat = haze.assemble(len(state.exposure), sums.haze_parts)
        mode = "fixed" if fixed else ("prior" if prior is not None else "solve")
        t, h = haze.joint_step(state.exposure, h, g, mat, mode, t0=t_ref,
                               prior_weight=exposure_prior.prior_weight(t_ref, prior) if prior is not None else None,
                               noise_var=max(sums.q / sums.n_obs, 1e-12) if sums.n_obs else 1.0)
    elif fixed or held:
        t = state.exposure
    elif prior is not None:
        t = exposure_prior.exposure_update_prior(state.exposure, sums.exp_num, sums.exp_den, t_ref, prior, sums.q, sums.n_obs)
    else:
        t = updates.exposure_update(state.exposure, sums.exp_num, sums.exp_den)
    c = state.params
    if model.parameters and sums.n_obs:
        if method == "seed":
            c = updates.phase_update_seed(c, sums.jtj, sums.jtr)
        else:
            c = updates.phase_update_damped(c, sums.jtj, sums.jtr, (sums.alpha_min, sums.alpha_max), model.phase_curve)
    if method != "seed" and not fixed and prior is None and not held:
        # A*T leaves one global scale free: pin the geometric mean of T to the initial one.
        t = t * np.exp(np.mean(np.log(t_ref)) - np.mean(np.log(t)))
    return SolveState(np.asarray(t, dtype=np.float64), np.asarray(c, dtype=np.float64), robust=state.robust, haze=h,
                      haze_joint=state.haze_joint, exposures_known=state.exposures_known)


def haze_step_taken(ck: dict, keys: list, before: SolveState, state: SolveState, sums: updates.PassSums, last: bool,
                    fixed: bool, mode: str, t_ref, prior) -> None:
    """After a pass that took the joint exposure-haze step (``before`` -> ``state``): whether the haze has settled
    (:func:`lunaralbedo.model.haze.settled`; then it and the exposures are held from the next pass on,
    ``state.haze_joint``), the images whose haze and exposure cannot be told apart and, at the last joint step,
    each image's haze standard error (None: no data), into the checkpoint ``ck``."""
    g, mat = haze.assemble(len(keys), sums.haze_parts)
    step = float(np.max(np.abs(state.haze - before.haze), initial=0.0))
    settled = haze.settled(step, ck.get("haze_step"), sums.haze_rss)
    ck.update(haze_step=step, haze_joint=not settled, haze_joint_passes=ck.get("haze_joint_passes", 0) + 1)
    state.haze_joint = not settled
    ck["haze_inseparable"] = [keys[k] for k in haze.inseparable(mat)]
    if settled or last:
        # the noise from the residuals after the step: less the Gauss-Newton decrease g . delta
        delta = np.ravel(np.column_stack([state.exposure - before.exposure, state.haze - before.haze]))
        rss = np.array(sums.haze_rss, np.float64)
        rss[0] = max(rss[0] - max(float(g @ delta), 0.0), 0.0)
        how = "fixed" if fixed else ("prior" if mode == "prior" else "solve")
        w = exposure_prior.prior_weight(t_ref, prior) if how == "prior" else None
        sig = haze.standard_errors(state.exposure, mat, rss, how, prior_weight=w)
        ck["haze_sigma"] = [None if not np.isfinite(v) else float(v) for v in sig]
