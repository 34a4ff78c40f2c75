"""The fused numba kernels give the sums of the NumPy stack formulas of model/updates.py."""
from __future__ import annotations

import numpy as np

from lunaralbedo.engine import kernels
from lunaralbedo.model import updates


def _stacks(seed=2, k=5, h=40, w=30):
    rng = np.random.default_rng(seed)
    image = rng.uniform(10, 200, (k, h, w)).astype(np.float32)
    r = rng.uniform(0.2, 1.0, (k, h, w)).astype(np.float32)
    dr = rng.normal(size=(2, k, h, w)).astype(np.float32)
    wt = rng.uniform(0.0, 1.0, (k, h, w)).astype(np.float32)
    for i in range(k):  # each image covers a band of columns, as a strip does
        wt[i, :, : 5 * i] = 0
        wt[i, :, 5 * i + 12:] = 0
    wt[:, :3] = 0  # rows without any observation: albedo NaN
    t = rng.uniform(0.5, 2.0, k).astype(np.float32)
    return image, r, dr, wt, t


def _compact(wt, *arrays):
    k = wt.shape[0]
    sel = [np.flatnonzero(wt[i] > 0) for i in range(k)]
    start = np.concatenate([[0], np.cumsum([len(s) for s in sel])]).astype(np.int64)
    pix = np.concatenate(sel).astype(np.int32)
    flat = [np.concatenate([a[i].ravel()[sel[i]] for i in range(k)]) for a in arrays]
    return pix, start, flat


def test_kernels_equal_the_numpy_formulas():
    image, r, dr, wt, t = _stacks()
    k, h, w = image.shape
    tr = t[:, None, None] * r
    alb = updates.albedo(image, tr, wt)
    res = updates.residuals(image, alb, tr, wt)
    q = updates.cost(res, wt)
    en, ed = updates.exposure_sums(image, alb, r, wt)
    jtj, jtr = updates.phase_sums(res, alb, t, list(dr), r, wt)
    err = updates.error_map(image, alb, tr, wt, wt)

    pix, start, (ci, cr, cw, cd1, cd2) = _compact(wt, image, r, wt, dr[0], dr[1])
    t_obs = np.repeat(t, np.diff(start))
    c_alb = kernels.albedo(pix, ci, t_obs * cr, cw, h * w)
    # per-pixel sums run over the images in the same order as NumPy's axis-0 sum: identical bytes
    np.testing.assert_array_equal(c_alb.reshape(h, w), alb)
    c_jtj, c_jtr, c_en, c_ed = np.zeros((3, 3)), np.zeros(3), np.zeros(k), np.zeros(k)
    c_q, n_obs = kernels.iteration_sums(pix, start, ci, cr, cw, t_obs, c_alb, np.stack([cd1, cd2]), c_jtj, c_jtr, c_en, c_ed)
    assert n_obs == np.count_nonzero(wt)
    # whole-tile sums: other summation order, float64 -> equal to ~1e-12
    np.testing.assert_allclose(c_q, q, rtol=1e-12)
    np.testing.assert_allclose(c_en, en, rtol=1e-12)
    np.testing.assert_allclose(c_ed, ed, rtol=1e-12)
    np.testing.assert_allclose(c_jtj, jtj, rtol=1e-11)
    np.testing.assert_allclose(c_jtr, jtr, rtol=1e-9, atol=1e-9 * np.abs(jtr).max())
    num = kernels.error_numerator(pix, ci, t_obs * cr, cw, c_alb, h * w).reshape(h, w)
    den = wt.sum(axis=0, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        c_err = np.where(den > 0, num / den, np.nan).astype(np.float32)
    np.testing.assert_array_equal(c_err, err)


def test_sums_do_not_depend_on_anything_but_the_data():
    """Same inputs in a fresh array -> identical bytes (no threads, no reassociation)."""
    image, r, dr, wt, t = _stacks(seed=5)
    pix, start, (ci, cr, cw, cd1) = _compact(wt, image, r, wt, dr[0])
    t_obs = np.repeat(t, np.diff(start))
    outs = []
    for _ in range(2):
        alb = kernels.albedo(pix.copy(), ci.copy(), t_obs * cr, cw.copy(), wt[0].size)
        jtj, jtr, en, ed = np.zeros((2, 2)), np.zeros(2), np.zeros(len(t)), np.zeros(len(t))
        q, _ = kernels.iteration_sums(pix, start, ci, cr, cw, t_obs, alb, cd1[None], jtj, jtr, en, ed)
        outs.append((alb.tobytes(), q, jtj.tobytes(), jtr.tobytes(), en.tobytes(), ed.tobytes()))
    assert outs[0] == outs[1]


def test_three_parameters_take_the_numpy_normal_equations():
    image, r, _, wt, t = _stacks(seed=8)
    dr = np.random.default_rng(1).normal(size=(3, *image.shape)).astype(np.float32)
    tr = t[:, None, None] * r
    alb = updates.albedo(image, tr, wt)
    jtj, jtr = updates.phase_sums(updates.residuals(image, alb, tr, wt), alb, t, list(dr), r, wt)
    pix, start, (ci, cr, cw, d0, d1, d2) = _compact(wt, image, r, wt, *dr)
    t_obs = np.repeat(t, np.diff(start))
    c_alb = kernels.albedo(pix, ci, t_obs * cr, cw, wt[0].size)
    c_jtj, c_jtr = np.zeros((4, 4)), np.zeros(4)
    kernels.iteration_sums(pix, start, ci, cr, cw, t_obs, c_alb, np.stack([d0, d1, d2]), c_jtj, c_jtr, np.zeros(len(t)), np.zeros(len(t)))
    np.testing.assert_allclose(c_jtj, jtj, rtol=1e-6)
    np.testing.assert_allclose(c_jtr, jtr, rtol=1e-5, atol=1e-6 * np.abs(jtr).max())
