"""The fused numba kernels give the sums of the NumPy stack formulas of model/updates.py, and a
model's numba ``point`` gives what its NumPy functions give."""
from __future__ import annotations

import dataclasses
import os
import platform
from types import SimpleNamespace

import numpy as np
import pytest

from lunaralbedo.engine import kernels, runs, tilework
from lunaralbedo.engine.finalise_kernels import finalise_runs
from lunaralbedo.io.cache import MemoryCache, load_stack, mapped, save_stack
from lunaralbedo.model import shadows, updates
from lunaralbedo.model.photometry import REGISTRY, lunar_lambert

import oracles  # noqa: E402  (tests/oracles.py: the NumPy forms of the equations)


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
    r[1, 5, :] = 0  # R = 0 with weight: no albedo term, but a residual I in Q
    t = rng.uniform(0.5, 2.0, k).astype(np.float32)
    return image, r, dr, wt, t


def _compact(wt, **arrays):
    """Image-major compact observations (as engine/observations.py caches them)."""
    k = wt.shape[0]
    sel = [np.flatnonzero(wt[i] > 0) for i in range(k)]
    obs = {"pix": np.concatenate(sel).astype(np.int32), "index": np.arange(k, dtype=np.int32),
           "start": np.concatenate([[0], np.cumsum([len(s) for s in sel])]).astype(np.int64)}
    for n, a in arrays.items():
        obs[n] = np.concatenate([a[i].ravel()[sel[i]] for i in range(k)])
    return obs


def _run(pm, kind, layers, params, t, n_par, shadow=kernels.NO_SHADOW_TEST, ratio=None, thresh=0.0, alpha=None,
         haze=None, base=None, joint=True, exposure=True):
    k = len(t)
    n_cols = n_par + 1 if n_par else 0
    en, ed, jtj, jtr = np.zeros(k if exposure else 0), np.zeros(k if exposure else 0), np.zeros((n_cols, n_cols)), np.zeros(n_cols)
    alb = np.full(pm["npix"], np.nan, np.float32)
    empty = pm["image"][:0]
    n_h = k if haze is not None and joint else 0
    hg, hs, hrss = np.zeros(2 * n_h), np.zeros((2 * n_h, 2 * n_h)), np.zeros(3)
    q, n_obs, amin, amax = kernels.iterate_runs(
        kind, pm["chunks"], pm["run_start"], pm["run_pixel"], pm["run_image"], pm["image"], pm["weight"], *layers,
        np.asarray(params, np.float32), t, n_par, n_cols, shadow, empty if ratio is None else ratio, np.float32(thresh),
        empty if alpha is None else alpha, en, ed, jtj, jtr, alb, empty if haze is None else haze,
        empty if base is None else base, hg, hs, hrss)
    return dict(alb=alb, q=q, n_obs=n_obs, en=en, ed=ed, jtj=jtj, jtr=jtr, amin=amin, amax=amax, hg=hg, hs=hs, hrss=hrss)


@pytest.mark.parametrize("chunk_px", [None, 64, 100])
def test_chunk_runs_order_is_stable_and_complete(chunk_px):
    """Chunks of consecutive pixels; in a chunk, images in tile order, each image's observations in runs of
    consecutive pixels; every observation once, with its own value."""
    image, r, dr, wt, t = _stacks()
    wt[2, 20, 14:16] = 0  # a hole inside an image's footprint: its row breaks into two runs
    obs = _compact(wt, image=image, weight=wt)
    pm = runs.chunk_runs(obs, wt[0].size, ["image", "weight"], chunk_px)
    cpx = chunk_px or runs.chunk_pixels(len(obs["pix"]), wt[0].size)
    start, pixel, img = pm["run_start"], pm["run_pixel"], pm["run_image"].astype(int)
    assert start[0] == 0 and start[-1] == len(obs["pix"]) and np.all(np.diff(start) > 0)
    pix, im = runs.observation_pixels(pm), runs.observation_images(pm)
    chunk = pix // cpx
    assert np.all(np.diff(chunk) >= 0)  # chunk-major
    assert np.all(chunk[start[:-1]] == chunk[start[1:] - 1])  # a run stays in its chunk
    bounds = start[pm["chunks"]]  # the chunks' first observations
    assert len(np.unique(chunk)) == len(pm["chunks"]) - 1 and np.all(np.diff(chunk)[bounds[1:-1] - 1] > 0)
    key = chunk.astype(np.int64) * len(t) * wt[0].size + im.astype(np.int64) * wt[0].size + pix
    assert np.all(np.diff(key) > 0)  # within a chunk: image by image in tile order, then by pixel
    for c in range(len(pm["chunks"]) - 1):  # runs are maximal: neighbours in a chunk differ in image or break the pixels
        r0, r1 = pm["chunks"][c], pm["chunks"][c + 1]
        same = img[r0 + 1:r1] == img[r0:r1 - 1]
        assert not np.any(same & (pixel[r0 + 1:r1] == pixel[r0:r1 - 1] + np.diff(start)[r0:r1 - 1]))
    np.testing.assert_array_equal(pm["image"], image[im, pix // wt.shape[2], pix % wt.shape[2]])
    np.testing.assert_array_equal(pm["weight"], wt[im, pix // wt.shape[2], pix % wt.shape[2]])
    assert runs.pixel_extent(pm) == pix.max() + 1
    if chunk_px == 64:  # the hole: image 2 has two runs on row 20 (columns 10..13 and 16..21)
        assert np.count_nonzero((img == 2) & (pixel // wt.shape[2] == 20)) >= 2


def test_chunk_runs_moves_rows_of_one_array_without_copying_them():
    """Arrays held as the rows of one array (as the prepare step holds them) are reordered in one pass, with the
    result of separate arrays; rows of another order, or separate arrays, are stacked first."""
    image, r, dr, wt, t = _stacks()
    obs = _compact(wt, image=image, weight=wt, r=r)
    names = ["image", "weight", "r"]
    rows = np.stack([obs[n] for n in names])
    held = {**obs, **dict(zip(names, rows))}
    assert runs._rows_of(held, names) is rows
    assert runs._rows_of(held, names[::-1]) is not rows and runs._rows_of(obs, names).base is None
    a, b = runs.chunk_runs(obs, wt[0].size, names), runs.chunk_runs(held, wt[0].size, names)
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("chunk_px", [None, 16, 100])
def test_fused_kernel_equals_the_numpy_formulas(chunk_px):
    image, r, dr, wt, t = _stacks()
    k, h, w = image.shape
    tr = t[:, None, None] * r
    alb = oracles.albedo(image, tr, wt)
    res = oracles.residuals(image, alb, tr, wt)
    q = oracles.cost(res, wt)
    en, ed = oracles.exposure_sums(image, alb, r, wt)
    jtj, jtr = updates.phase_sums(res, alb, t, list(dr), r, wt)

    obs = _compact(wt, image=image, weight=wt, r=r, d0=dr[0], d1=dr[1])
    pm = {**runs.chunk_runs(obs, h * w, ["image", "weight", "r", "d0", "d1"], chunk_px), "npix": h * w}
    got = _run(pm, 0, (pm["r"], pm["d0"], pm["d1"]), (), t, 2)
    # per-pixel sums run over the images in the same order as NumPy's axis-0 sum: identical bytes
    np.testing.assert_array_equal(got["alb"].reshape(h, w), alb)
    # finalise's one pass: the same albedo, and eq. 7 pixel by pixel in tile order, the NumPy sums over the
    # image axis bit for bit (its numerator over a blending sum that is 0 at some pixels, 2.5 elsewhere)
    blend = np.where(np.arange(h * w) % 7 == 0, 0.0, 2.5).astype(np.float32)
    alb2, err = np.empty(h * w, np.float32), np.empty(h * w, np.float32)
    finalise_runs(pm["chunks"], pm["run_start"], pm["run_pixel"], pm["run_image"], pm["image"], t, pm["r"],
                          pm["weight"], blend.reshape(h, w), 0, alb2, err)
    np.testing.assert_array_equal(alb2, got["alb"])
    num = updates._f64sum(updates.error_terms(image, alb[None], tr.astype(np.float32), wt), axis=0).ravel()
    assert np.count_nonzero(num) > 0.5 * h * w
    with np.errstate(divide="ignore", invalid="ignore"):
        want = np.where(blend > 0, num / blend, np.nan).astype(np.float32)
    assert np.isnan(want).sum() == np.count_nonzero(blend == 0) and np.count_nonzero(want == 0) > 0
    np.testing.assert_array_equal(err, want)
    assert got["n_obs"] == np.count_nonzero(wt)
    # whole-tile sums: other summation order, float64 -> equal to ~1e-12
    np.testing.assert_allclose(got["q"], q, rtol=1e-12)
    np.testing.assert_allclose(got["en"], en, rtol=1e-12)
    np.testing.assert_allclose(got["ed"], ed, rtol=1e-12)
    np.testing.assert_allclose(got["jtj"], jtj, rtol=1e-11)
    np.testing.assert_allclose(got["jtr"], jtr, rtol=1e-9, atol=1e-9 * np.abs(jtr).max())
    # one parameter: its column then R
    one = _run(pm, 0, (pm["r"], pm["d0"], pm["d0"]), (), t, 1)
    jtj1, jtr1 = updates.phase_sums(res, alb, t, [dr[0]], r, wt)
    np.testing.assert_allclose(one["jtj"], jtj1, rtol=1e-11)
    np.testing.assert_allclose(one["jtr"], jtr1, rtol=1e-9, atol=1e-9 * np.abs(jtr1).max())


@pytest.mark.parametrize("chunk_px", [None, 16])
def test_fused_haze_sums_equal_the_numpy_formulas(chunk_px):
    """FLOAT_HAZE 1 with robust weights: the kernel takes each image's haze off inside its sweep (albedo, Q and
    exposure sums of I - H with the effective weights) and adds the joint (T, H) step's sums with noise weights
    (the robust factor where eq. 1's weight is not 0): the dense NumPy formulas of tests/oracles.py."""
    image, r, _, wt, t = _stacks(seed=9)
    k, h, w = image.shape
    rng = np.random.default_rng(4)
    haze = rng.uniform(-3, 12, k).astype(np.float32)
    m = np.where(rng.uniform(size=image.shape) < 0.1, 0.0, rng.uniform(0.3, 1.0, image.shape)).astype(np.float32)
    eff = (wt * m).astype(np.float32)  # robust weights: some observations rejected (0), others down-weighted
    obs = _compact(wt, image=image, weight=eff, base=wt, r=r)
    pm = {**runs.chunk_runs(obs, h * w, ["image", "weight", "base", "r"], chunk_px), "npix": h * w}
    got = _run(pm, 0, (pm["r"], pm["r"], pm["r"]), (), t, 0, haze=haze, base=pm["base"])
    value = image - haze[:, None, None]
    tr = t[:, None, None] * r
    alb = oracles.albedo(value, tr, eff)
    np.testing.assert_array_equal(got["alb"].reshape(h, w), alb)
    np.testing.assert_allclose(got["q"], oracles.cost(oracles.residuals(value, alb, tr, eff), eff), rtol=1e-12)
    en, ed = oracles.exposure_sums(value, alb, r, eff)
    np.testing.assert_allclose(got["en"], en, rtol=1e-12)
    np.testing.assert_allclose(got["ed"], ed, rtol=1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        noise = np.where(eff > 0, eff / wt, 0).astype(np.float32)
    g, s, rss = oracles.haze_sums(value, t, r, noise)
    assert rss[1] < np.count_nonzero(wt) and np.count_nonzero(s[0::2, 2::2]) > 0  # rejections; images coupled
    np.testing.assert_allclose(got["hg"], g, rtol=1e-10, atol=1e-12 * np.abs(g).max())
    np.testing.assert_allclose(got["hs"], s, rtol=1e-10, atol=1e-12 * np.abs(s).max())
    np.testing.assert_array_equal(got["hs"], got["hs"].T)
    np.testing.assert_allclose(got["hrss"], rss, rtol=1e-12)
    # once the haze has settled it is held: taken off the values the same way, no joint step's sums
    held = _run(pm, 0, (pm["r"], pm["r"], pm["r"]), (), t, 0, haze=haze, base=pm["base"], joint=False)
    for name in ("alb", "q", "n_obs", "en", "ed"):
        np.testing.assert_array_equal(held[name], got[name])
    assert held["hg"].size == 0 and held["hs"].size == 0
    # FLOAT_HAZE's passes without eq. 4's sums (its exposures are the joint step's, or held): nothing else changes
    for joint in (True, False):
        lean = _run(pm, 0, (pm["r"], pm["r"], pm["r"]), (), t, 0, haze=haze, base=pm["base"], joint=joint, exposure=False)
        for name in ("alb", "q", "n_obs", "hg", "hs", "hrss"):
            np.testing.assert_array_equal(lean[name], (got if joint else held)[name])
        assert lean["en"].size == 0


def _lunar_lambert_block():
    """A block of the Lunar-Lambert model's layers (``geometric``, ``alpha``) in chunk-major runs, its exposures and
    image count."""
    image, _, _, wt, t = _stacks(seed=9)
    k, h, w = image.shape
    rng = np.random.default_rng(9)
    g = rng.uniform(0.2, 1.0, image.shape).astype(np.float32)
    alpha = rng.uniform(0.1, 1.2, image.shape).astype(np.float32)
    obs = _compact(wt, image=image, weight=wt, geometric=g, alpha=alpha)
    return {**runs.chunk_runs(obs, h * w, ["image", "weight", "geometric", "alpha"]), "npix": h * w}, t, k


def test_a_haze_pass_leaves_eq4_to_the_joint_step():
    """``iterate_block`` with FLOAT_HAZE 1 does not sum eq. 4 (the exposures come from the joint step, or are held),
    nor with the exposures known (EXPOSURE_MODE fixed): its exposure sums stay 0, its Q and haze sums are the
    kernel's with them."""
    pm, t, k = _lunar_lambert_block()
    model = REGISTRY["lunar-lambert"]
    haze = np.linspace(2.0, 9.0, k)
    for h, joint, known in ((haze, True, False), (haze, False, False), (None, True, True), (None, True, False)):
        state = tilework.SolveState(t.astype(np.float64), np.array([1.4, 0.5]), haze=h, haze_joint=joint,
                                    exposures_known=known)
        out = updates.PassSums(k, 2, index=pm["index"])
        tilework.iterate_block(pm, SimpleNamespace(shadow_type=shadows.NONE, shadow_thresh=0.0), model, state, False, out)
        ref = _run(pm, 1, (pm["geometric"], pm["alpha"], pm["alpha"]), (1.4, 0.5), t.astype(np.float32), 0,
                   haze=None if h is None else h.astype(np.float32), base=pm["weight"][:0], joint=joint)
        assert ref["en"].any() and out.q == ref["q"] and out.n_obs == ref["n_obs"]
        if h is None and not known:  # the exposures from eq. 4: summed
            np.testing.assert_array_equal(out.exp_num, ref["en"])
            continue
        assert not out.exp_num.any() and not out.exp_den.any()
        if h is not None and joint:
            np.testing.assert_array_equal(out.haze_g, ref["hg"])


def test_dynamic_shadow_test_is_dynamic_lit():
    image, r, _, wt, t = _stacks(seed=3)
    thresh = 0.7  # float32(0.7) < 0.7: NumPy compares the float32 ratios with float32(0.7), so must the kernel
    k, h, w = image.shape
    image[:, 10:20] = (np.float32(thresh) * (t[:, None, None] * r))[:, 10:20]  # ratios on the threshold
    cos_i = np.random.default_rng(0).uniform(0.05, 1.0, image.shape).astype(np.float32)
    obs = _compact(wt, image=image, weight=wt, r=r, cos_i=cos_i)
    pm = {**runs.chunk_runs(obs, h * w, ["image", "weight", "r", "cos_i"]), "npix": h * w}
    for mode, rho in ((kernels.SHADOW_ON_R, r), (kernels.SHADOW_ON_LAYER, cos_i)):
        lit = shadows.dynamic_lit(image, rho, t[:, None, None], thresh)
        assert 0 < np.count_nonzero(lit & (wt > 0)) < np.count_nonzero(wt)
        wl = np.where(lit, wt, 0).astype(np.float32)
        alb = oracles.albedo(image, t[:, None, None] * r, wl)
        got = _run(pm, 0, (pm["r"],) * 3, (), t, 0, mode, pm["cos_i"], thresh)
        np.testing.assert_array_equal(got["alb"].reshape(h, w), alb)
        assert got["n_obs"] == np.count_nonzero(wl)
        np.testing.assert_allclose(got["q"], oracles.cost(oracles.residuals(image, alb, t[:, None, None] * r, wl), wl), rtol=1e-12)


def test_a_blocks_phase_angle_range_is_the_kernels_and_stands_in_for_it_without_a_dynamic_shadow_test():
    """``alpha_range`` gives what the kernel gives over the same observations (weight > 0, NaN left out);
    ``iterate_block`` takes a block's stored range instead of asking the kernel for it, unless a dynamic
    shadow test changes the weights from pass to pass."""
    pm, t, k = _lunar_lambert_block()
    lo, hi = np.argmin(pm["alpha"]), np.argmax(pm["alpha"])
    pm["weight"][lo] = 0  # the smallest angle unused: the range is over the used observations only
    pm["alpha"][hi] = np.nan  # and a NaN angle is left out
    got = kernels.alpha_range(pm["alpha"], pm["weight"])
    used = pm["alpha"][(pm["weight"] > 0) & np.isfinite(pm["alpha"])]
    assert got == (used.min(), used.max()) and got[0] > pm["alpha"][lo]
    ran = _run(pm, 1, (pm["geometric"], pm["alpha"], pm["alpha"]), (1.4, 0.5), t, 2, alpha=pm["alpha"])
    assert (ran["amin"], ran["amax"]) == got
    assert kernels.alpha_range(pm["alpha"][:0], pm["weight"][:0]) == (np.inf, -np.inf)

    model = REGISTRY["lunar-lambert"]
    stored = {**pm, "alpha_range": np.array([0.25, 0.5], np.float32)}  # not the data's: shows which one is used
    for shadow_type, expect in ((shadows.NONE, (0.25, 0.5)), (shadows.LUNAR_LAMBERT_RATIO, got)):
        s = SimpleNamespace(shadow_type=shadow_type, shadow_thresh=0.0)
        state = tilework.SolveState(t.astype(np.float64), np.array([1.4, 0.5]))
        out = updates.PassSums(k, 2, index=pm["index"])
        tilework.iterate_block(stored, s, model, state, True, out)
        assert (out.alpha_min, out.alpha_max) == expect
        plain = updates.PassSums(k, 2, index=pm["index"])
        tilework.iterate_block(pm, s, model, state, True, plain)  # a block cached without the range (older caches)
        assert (plain.alpha_min, plain.alpha_max) == got
        for a, b in ((plain.q, out.q), (plain.jtj, out.jtj), (plain.exp_num, out.exp_num)):  # the NaN angle: NaN sums
            assert np.array_equal(a, b, equal_nan=True)


def _point_models():
    return [m for m in REGISTRY.values() if m.point is not None]


def test_the_fitted_model_has_a_kernel_also_on_a_worker(tmp_path):
    """A model sent to a Dask worker carries a copy of its numba ``point`` and its kernel branch."""
    import subprocess
    import sys

    import cloudpickle

    (tmp_path / "model.pkl").write_bytes(cloudpickle.dumps(REGISTRY["lunar-lambert"]))
    code = ("import pickle, sys; from lunaralbedo.engine import kernels; from lunaralbedo.model.photometry import lunar_lambert; "
            "m = pickle.loads(open(sys.argv[1], 'rb').read()); "
            "print(m.point is lunar_lambert.point, kernels.point_kind(m))")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "model.pkl")], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "1"]  # another dispatcher object, the same kernel branch


@pytest.mark.parametrize("model", _point_models(), ids=lambda m: m.name)
def test_fused_model_point_equals_its_numpy_functions(model):
    """The kernel with the model's ``point`` inline == the kernel fed the model's NumPy R and dR/dp."""
    image, _, _, wt, t = _stacks(seed=4)
    k, h, w = image.shape
    rng = np.random.default_rng(9)
    ci, ce = rng.uniform(0.1, 1.0, (2, *image.shape))
    alpha = rng.uniform(0.05, 1.4, image.shape)
    layers = {n: np.asarray(v, np.float32) for n, v in model.layers(ci, ce, alpha).items()}
    obs = _compact(wt, image=image, weight=wt, **layers)
    pm = {**runs.chunk_runs(obs, h * w, ["image", "weight", *layers]), "npix": h * w}
    params = np.array([1.2, 0.4][: len(model.parameters)])
    n_par = len(model.parameters)
    r = model.reflectance_from(pm, params)
    dr = model.derivatives_from(pm, params)
    assert r.dtype == np.float32 and all(d.dtype == np.float32 for d in dr)
    ls = [pm[n] for n in model.point_layers]
    kind = kernels.point_kind(model)
    assert kind  # every model with a point is inlined by the kernel
    fused = _run(pm, kind, ls + ls[:1] * (3 - len(ls)), params, t, n_par, alpha=pm.get("alpha"))
    generic = _run(pm, 0, (r, *dr, *([r] * (2 - len(dr)))), (), t, n_par, alpha=pm.get("alpha"))
    for name in ("alb", "q", "en", "ed", "jtj", "jtr", "n_obs", "amin", "amax"):
        np.testing.assert_array_equal(fused[name], generic[name], err_msg=name)


def test_lunar_lambert_point_is_eq2():
    """R = (exp(-c1 alpha) + c2) G and its derivatives, float32 in, float32 out, to float32 rounding."""
    rng = np.random.default_rng(1)
    g = rng.uniform(0.0, 1.2, 10000).astype(np.float32)
    a = rng.uniform(0.0, 1.5, 10000).astype(np.float32)
    c1, c2 = 1.37, 0.48
    e = np.exp((np.float32(-c1) * a).astype(np.float64)).astype(np.float32)  # correctly rounded float32 e^x
    r = lunar_lambert.reflectance_from({"geometric": g, "alpha": a}, (c1, c2))
    d1, d2 = lunar_lambert.derivatives_from({"geometric": g, "alpha": a}, (c1, c2))
    assert r.dtype == d1.dtype == d2.dtype == np.float32
    np.testing.assert_allclose(r, (e + np.float32(c2)) * g, rtol=3e-7)  # 1 ulp of exp (vexp vs correctly rounded), then 2 products
    np.testing.assert_allclose(d1, -a * e * g, rtol=3e-7, atol=1e-38)
    np.testing.assert_array_equal(d2, g)
    # float64 (the forward model) stays float64
    r64 = lunar_lambert.reflectance_from({"geometric": g.astype(float), "alpha": a.astype(float)}, (c1, c2))
    np.testing.assert_allclose(r64, (np.exp(-c1 * a.astype(float)) + c2) * g, rtol=1e-15)
    assert lunar_lambert.phase_factor(np.float32(0.5), c1, c2).dtype == np.float32


class _ThreeParams:
    """A model without ``point``, fitting three parameters: R = (p0 + p1 x + p2 x^2) G."""

    @staticmethod
    def model():
        def r_from(arrays, p):
            x, g = arrays["alpha"], arrays["geometric"]
            f = x.dtype.type
            return (f(p[0]) + f(p[1]) * x + f(p[2]) * x * x) * g

        def d_from(arrays, p):
            x, g = arrays["alpha"], arrays["geometric"]
            return g, x * g, x * x * g

        base = REGISTRY["lunar-lambert"]
        return dataclasses.replace(base, name="quad", reflectance_from=r_from, derivatives_from=d_from,
                                   parameters=("p0", "p1", "p2"), point=None, point_layers=())


def test_models_without_point_and_more_parameters_take_the_generic_path():
    image, _, _, wt, t = _stacks(seed=8)
    k, h, w = image.shape
    rng = np.random.default_rng(2)
    layers = {"geometric": rng.uniform(0.2, 1.0, image.shape).astype(np.float32),
              "alpha": rng.uniform(0.1, 1.2, image.shape).astype(np.float32)}
    model = _ThreeParams.model()
    params = np.array([0.9, -0.2, 0.05])
    r = model.reflectance_from(layers, params)
    dr = list(model.derivatives_from(layers, params))
    tr = t[:, None, None] * r
    alb = oracles.albedo(image, tr, wt)
    res = oracles.residuals(image, alb, tr, wt)
    jtj, jtr = updates.phase_sums(res, alb, t, dr, r, wt)
    en, ed = oracles.exposure_sums(image, alb, r, wt)

    obs = _compact(wt, image=image, weight=wt, **layers)
    pm = runs.chunk_runs(obs, h * w, ["image", "weight", *layers])
    s = SimpleNamespace(shadow_type=shadows.NONE, shadow_thresh=0.0)
    state = tilework.SolveState(t.astype(np.float64), params)
    out = updates.PassSums(k, 3, index=pm["index"])
    tilework.iterate_block(pm, s, model, state, True, out)
    np.testing.assert_allclose(out.q, oracles.cost(res, wt), rtol=1e-12)
    np.testing.assert_allclose(out.exp_num, en, rtol=1e-12)
    np.testing.assert_allclose(out.exp_den, ed, rtol=1e-12)
    np.testing.assert_allclose(out.jtj, jtj, rtol=1e-6)
    np.testing.assert_allclose(out.jtr, jtr, rtol=1e-5, atol=1e-6 * np.abs(jtr).max())
    used = layers["alpha"][wt > 0]
    assert (out.alpha_min, out.alpha_max) == (used.min(), used.max())


def test_sums_do_not_depend_on_anything_but_the_data():
    """Same inputs in fresh arrays -> identical bytes (no threads, no reassociation)."""
    image, r, dr, wt, t = _stacks(seed=5)
    obs = _compact(wt, image=image, weight=wt, r=r, d0=dr[0])
    outs = []
    for _ in range(2):
        pm = {**runs.chunk_runs({n: v.copy() for n, v in obs.items()}, wt[0].size, ["image", "weight", "r", "d0"]),
              "npix": wt[0].size}
        got = _run(pm, 0, (pm["r"], pm["d0"], pm["d0"]), (), t, 1)
        outs.append(tuple(np.asarray(v).tobytes() for v in got.values()))
    assert outs[0] == outs[1]


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="checks x86 packed instructions")
def test_the_fused_kernel_is_vectorised():
    """LLVM vectorises the kernel's loops (a conditional load or a sum carried in a register would
    make them scalar again): packed float32 products and packed float32 -> float64 conversions
    for the lanes of the 10 global sums.  A fresh, uncached compile (numba cannot show cached code)."""
    import re

    from numba import njit

    image, r, dr, wt, t = _stacks(seed=6)
    obs = _compact(wt, image=image, weight=wt, geometric=r, alpha=np.abs(dr[0]))
    pm = runs.chunk_runs(obs, wt[0].size, ["image", "weight", "geometric", "alpha"])
    fresh = njit(error_model="numpy")(kernels.iterate_runs.py_func)
    k = len(t)
    fresh(1, pm["chunks"], pm["run_start"], pm["run_pixel"], pm["run_image"], pm["image"], pm["weight"], pm["geometric"],
          pm["alpha"], pm["geometric"],
          np.array([1.4, 0.5], np.float32), t, 2, 3, kernels.NO_SHADOW_TEST, pm["image"][:0], np.float32(0), pm["alpha"],
          np.zeros(k), np.zeros(k), np.zeros((3, 3)), np.zeros(3), np.empty(0, np.float32), np.empty(0, np.float32),
          pm["weight"][:0], np.zeros(0), np.zeros((0, 0)), np.zeros(3))
    asm = fresh.inspect_asm(fresh.signatures[0])
    count = lambda ins: len(re.findall(r"\bv?" + ins + r"\b", asm))
    assert count("mulps") >= 10 and count("cvtps2pd") >= 10 and count("addpd") >= 10
    # the lanes of Q and the normal equations: 10 packed float64 additions in the loop's vector body
    # (written out inside the big function, LLVM had kept this loop scalar)
    lanes = njit(kernels._normal_lanes.py_func)
    rows = [np.linspace(0.5, 1.5, 300, dtype=np.float32)] * 7
    lanes(*rows, np.zeros(kernels.N_SUMS * kernels.LANES), 300, 2)
    packed = re.findall(r"\bvaddpd\s[^\n]*%[yz]mm", lanes.inspect_asm(lanes.signatures[0]))  # 4 or 8 lanes a time
    assert len(packed) >= kernels.N_SUMS


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="checks x86 packed instructions")
def test_the_error_terms_loop_is_vectorised():
    """Eq. 7's terms divide as the NumPy formula does (IEEE): without numba's zero-division check in the division,
    LLVM runs the loop several observations per instruction (packed float32 divisions)."""
    import re

    from numba import njit

    from lunaralbedo.engine.finalise_kernels import _error_run

    assert _error_run.targetoptions.get("error_model") == "numpy"
    fresh = njit(error_model=_error_run.targetoptions["error_model"])(_error_run.py_func)
    x = np.linspace(0.5, 1.5, 64, dtype=np.float32)
    fresh(x, x, x, np.float32(1.3), x, np.zeros(64), 64)
    assert "division by zero" not in fresh.inspect_llvm(fresh.signatures[0])
    assert re.search(r"\bvdivps\s[^\n]*%[xyz]mm", fresh.inspect_asm(fresh.signatures[0]))


@pytest.mark.parametrize("chunk_px", [None, 16])
def test_finalise_takes_the_blending_sums_of_the_windows_columns_only(chunk_px):
    """The cache keeps a block's blending sums only over the columns its images' windows span: finalise given
    those columns (and where they start) writes the albedo and error of the whole-row sums, bit for bit, with
    NaN in the columns no window reaches and 0 where a pixel has a blending weight but no observation."""
    image, r, _, wt, t = _stacks()
    k, h, w = image.shape
    wt[:, :, :4], wt[:, :, 25:] = 0, 0  # observed columns 4..24
    obs = _compact(wt, image=image, weight=wt, r=r)
    pm = runs.chunk_runs(obs, h * w, ["image", "weight", "r"], chunk_px)
    blend = np.zeros((h, w), np.float32)
    blend[:, 2:27] = np.where(np.arange(25) % 6 == 0, 0.0, 2.5)  # the windows' columns 2..26
    blend[(wt.max(axis=0) == 0) & (np.arange(h)[:, None] % 2 == 0)] = 0  # unobserved, in every other row: 0

    def finalise(sums, c0):
        alb, err = np.empty(h * w, np.float32), np.empty(h * w, np.float32)
        finalise_runs(pm["chunks"], pm["run_start"], pm["run_pixel"], pm["run_image"], pm["image"], t,
                              pm["r"], pm["weight"], np.ascontiguousarray(sums), c0, alb, err)
        return alb.reshape(h, w), err.reshape(h, w)

    alb, err = finalise(blend, 0)
    alb_cut, err_cut = finalise(blend[:, 2:27], 2)
    np.testing.assert_array_equal(alb_cut, alb)
    np.testing.assert_array_equal(err_cut, err)
    assert np.isnan(err[:, :2]).all() and np.isnan(err[:, 27:]).all()
    assert np.count_nonzero(err[:, 2:4] == 0) > 0 and np.count_nonzero(err[:, 4:25] > 0) > 0.5 * h * 21


def test_a_pixel_seen_by_more_images_than_uint16_numbers():
    """70 000 images over one pixel: the runs number their images in int32, and the kernels take them."""
    m = 70_000
    obs = {"pix": np.zeros(m, np.int32), "start": np.arange(m + 1, dtype=np.int64), "index": np.arange(m, dtype=np.int32),
           "image": np.full(m, 3.0, np.float32), "weight": np.ones(m, np.float32), "r": np.ones(m, np.float32)}
    pm = {**runs.chunk_runs(obs, 1, ["image", "weight", "r"]), "npix": 1}
    assert pm["run_image"].dtype == np.int32 and len(pm["run_start"]) == m + 1 and pm["run_image"][-1] == m - 1
    t = np.full(m, 1.5, np.float32)
    got = _run(pm, 0, (pm["r"],) * 3, (), t, 0)
    assert got["alb"][0] == 2 and got["n_obs"] == m and got["q"] == 0 and np.all(got["en"] == 6) and np.all(got["ed"] == 4)
    alb, err = np.empty(1, np.float32), np.empty(1, np.float32)
    finalise_runs(pm["chunks"], pm["run_start"], pm["run_pixel"], pm["run_image"], pm["image"], t, pm["r"],
                          pm["weight"], np.full((1, 1), 2.0, np.float32), 0, alb, err)
    assert alb[0] == 2 and err[0] == 0


def test_cached_arrays_are_read_only_file_mappings_equal_to_numpys(tmp_path):
    """load_stack maps each array of an entry (no np.memmap set-up); the values, types and shapes are np.load's,
    MemoryCache(copy=True) copies an entry it keeps into memory, and a cut-short file fails as np.load fails."""
    rng = np.random.default_rng(3)
    arrays = {"f32": rng.random(1001, dtype=np.float32), "f64": rng.random((7, 9)), "u16": np.arange(50, dtype=np.uint16),
              "i32": -np.arange(13, dtype=np.int32), "fortran": np.asfortranarray(rng.random((4, 6))),
              "empty": np.zeros(0, np.float32), "big": np.arange(70_000, dtype=np.int64)}  # a header of format 1.0 or 2.0 alike
    folder = tmp_path / "cache" / "tile"
    folder.parent.mkdir()
    save_stack(folder, arrays, {"v": 1})
    np.save(folder / "fortran.npy", arrays["fortran"])  # as NumPy writes it, in Fortran order
    got, meta = load_stack(folder)
    assert meta == {"v": 1} and sorted(got) == sorted(arrays)
    for k, a in arrays.items():
        ref = np.load(folder / f"{k}.npy", mmap_mode="r")
        assert got[k].dtype == a.dtype and got[k].shape == a.shape and np.array_equal(got[k], a) and np.array_equal(got[k], ref), k
        assert not got[k].flags.writeable, k
        assert mapped(got[k]) == (a.size > 0), k  # an empty array has nothing to map
    assert got["fortran"].flags.f_contiguous
    assert not mapped(np.array(got["f32"])) and not mapped(np.zeros(3)) and mapped(np.load(folder / "f32.npy", mmap_mode="r"))
    kept = MemoryCache(budget=10**6, copy=True).get(folder, lambda arrays, meta: arrays)
    assert all(not mapped(v) for v in kept.values()) and np.array_equal(kept["f32"], arrays["f32"])  # read into memory
    over = MemoryCache(budget=0).get(folder, lambda arrays, meta: arrays)
    assert mapped(over["f32"])  # over the budget: served mapped, as built
    raw = (folder / "f32.npy").read_bytes()
    (folder / "f32.npy").write_bytes(raw[:-8])
    with pytest.raises(ValueError):
        load_stack(folder)


def test_memory_cache_keeps_local_entries_mapped_and_copies_the_others(tmp_path, monkeypatch):
    """On a local file system a kept entry is served as mapped (its pages in the page cache, no copy);
    on a network one (or unknown) it is copied into memory; both count against the budget."""
    from lunaralbedo.io import cache as cache_mod

    assert cache_mod.filesystem_type(tmp_path) in cache_mod.LOCAL_FILESYSTEMS  # the test's own disk
    assert cache_mod.filesystem_type("/proc/self") == "proc"  # the longest mount point wins over "/"
    folder = tmp_path / "run" / "cache" / "tile"
    folder.parent.mkdir(parents=True)
    save_stack(folder, {"x": np.arange(1000, dtype=np.float32)}, {})
    local = MemoryCache(budget=10**6)
    got = local.get(folder, lambda arrays, meta: arrays)
    assert mapped(got["x"]) and local.nbytes == 4000 and local.get(folder, lambda a, m: 1 / 0) is got  # kept, mapped
    monkeypatch.setattr(cache_mod, "filesystem_type", lambda path: "nfs4")
    remote = MemoryCache(budget=10**6)
    got = remote.get(folder, lambda arrays, meta: arrays)
    assert not mapped(got["x"]) and remote.nbytes == 4000 and np.array_equal(got["x"], np.arange(1000))


def test_memory_cache_keeps_within_budget_and_never_serves_a_replaced_entry(tmp_path):
    def entry(folder, value, n=1000):
        folder.parent.mkdir(parents=True, exist_ok=True)  # the cache root exists (solve creates it)
        save_stack(folder, {"x": np.full(n, value, np.float32)}, {"v": value})

    built = []

    def build(arrays, meta):
        built.append(meta["v"])
        return {"x": np.array(arrays["x"])}

    run = tmp_path / "run" / "cache"
    cache = MemoryCache(budget=10_000)  # two entries of 4000 bytes fit, not three
    for name, v in (("a", 1), ("b", 2), ("c", 3)):
        entry(run / name, v)
    for _ in range(2):
        for name in "abc":
            cache.get(run / name, build)
    assert built == [1, 2, 3, 3] and cache.nbytes == 8000  # a, b kept; c (over budget) rebuilt, not kept
    entry(run / "a", 7)  # re-prepared (a resumed or new run): rebuilt, never the old arrays
    assert cache.get(run / "a", build)["x"][0] == 7 and built[-1] == 7
    other = tmp_path / "other" / "cache"
    entry(other / "a", 5)
    cache.get(other / "a", build)  # another run's entries make room for the new one
    cache.get(other / "a", build)
    assert built.count(5) == 1 and cache.nbytes <= cache.budget  # kept: served from memory the second time
    assert cache.get(tmp_path / "missing", build) is None


def test_a_full_memory_cache_does_not_search_for_room_again_until_an_entry_comes_or_goes(tmp_path, monkeypatch):
    """Blocks over the budget ask for room in every pass: once a search found none, the cache does not look at its
    entries again (no stat of them) until one comes or goes; an entry whose files went away goes when it is asked
    for, and the next block then finds its room."""
    import shutil

    from lunaralbedo.io import cache as cache_mod

    run = tmp_path / "run" / "cache"
    run.mkdir(parents=True)
    for name in "abcde":
        save_stack(run / name, {"x": np.full(1000, ord(name), np.float32)}, {})
    cache = MemoryCache(budget=10_000)  # two entries of 4000 bytes fit, not three
    stats = []
    real = cache_mod._stamp
    monkeypatch.setattr(cache_mod, "_stamp", lambda folder: stats.append(os.path.basename(folder)) or real(folder))
    build = lambda arrays, meta: {"x": np.array(arrays["x"])}  # noqa: E731
    for name in "abc":
        cache.get(run / name, build)
    assert cache.nbytes == 8000 and {"a", "b"} <= set(stats)  # c searched for room among a and b: none
    stats.clear()
    for name in "dc":
        assert cache.get(run / name, build)["x"][0] == ord(name)  # served, not kept
    assert sorted(stats) == ["c", "d"]  # their own stamps only: a and b not looked at again
    shutil.rmtree(run / "b")
    assert cache.get(run / "b", build) is None and cache.nbytes == 4000  # gone when asked for
    cache.get(run / "e", build)
    assert cache.nbytes == 8000 and cache.get(run / "e", lambda a, m: 1 / 0)["x"][0] == ord("e")  # e kept now


def test_a_cache_entry_does_not_bring_back_a_removed_run_folder(tmp_path):
    """A task still running after its run failed and removed OUTDIR (another Dask worker) must not recreate it."""
    run = tmp_path / "out"
    with pytest.raises(FileNotFoundError):
        save_stack(run / "checkpoint" / "cache" / "tile_0E0N", {"x": np.zeros(3, np.float32)}, {})
    assert not run.exists()
    (run / "checkpoint").mkdir(parents=True)  # the run's folder is there: its cache root may be created
    save_stack(run / "checkpoint" / "cache" / "tile_0E0N", {"x": np.zeros(3, np.float32)}, {})
    assert (run / "checkpoint" / "cache" / "tile_0E0N" / "x.npy").is_file()


def test_discarded_entries_go_at_once_and_are_deleted_in_the_background(tmp_path):
    """discard() takes entries out of the cache at once (renamed into the trash folder), deletes them on this
    process's background thread, deletes in place when the trash cannot be made, and never recreates a
    removed run folder."""
    from lunaralbedo.io.cache import _deleter, discard

    root = tmp_path / "cache"
    blocks = [root / "tile_0E0N" / f"block_{i:04d}" for i in range(3)]
    blocks[0].parent.mkdir(parents=True)
    for b in blocks:
        save_stack(b, {"x": np.arange(1000, dtype=np.float32)}, {"i": b.name})
    discard([*blocks[:2], root / "tile_0E0N" / "block_0009"], root / ".discarded")  # a missing one is skipped
    assert [p.name for p in (root / "tile_0E0N").iterdir()] == ["block_0002"]
    _deleter().submit(lambda: None).result()  # the deletions queued before it are done
    assert list((root / ".discarded").iterdir()) == []
    discard([blocks[2]], tmp_path / "gone" / ".discarded")  # no parent for the trash: deleted here and now
    assert not blocks[2].exists() and not (tmp_path / "gone").exists()


def test_an_entrys_meta_is_parsed_once_while_it_is_the_same_file(tmp_path):
    """load_meta hands out the parsed meta again while the entry's meta.json is the same file, reads an entry
    saved again (atomically, as the prepare step does) anew, and says None once the entry is gone."""
    import shutil

    from lunaralbedo.io.cache import load_meta

    folder = tmp_path / "tile_A"
    assert load_meta(folder) is None
    save_stack(folder, {"a": np.arange(3)}, {"index": [1, 2], "blocks": [[0, 5]]})
    first = load_meta(folder)
    assert first == {"index": [1, 2], "blocks": [[0, 5]]} and load_meta(folder) is first
    save_stack(folder, {"a": np.arange(3)}, {"index": [7], "blocks": [[0, 2], [2, 5]]})
    again = load_meta(folder)
    assert again == {"index": [7], "blocks": [[0, 2], [2, 5]]} and load_meta(folder) is again
    shutil.rmtree(folder)
    assert load_meta(folder) is None
