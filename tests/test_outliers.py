"""Outliers are rejected by default: hot spots and dropout rows of a forward-model strip, and the robust loss."""
from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.engine.solve import solve
from lunaralbedo.model import outliers
from lunaralbedo.simulate import SceneSpec, render_scene, score


def _with(settings_file, path, **keys):
    lines = [ln for ln in settings_file.read_text().splitlines() if ln.split()[:1] not in ([k] for k in keys)]
    path.write_text("\n".join(lines + [f"{k} {v}" for k, v in keys.items()]) + "\n")
    return path


@pytest.fixture(scope="module")
def dirty(tmp_path_factory):
    d = tmp_path_factory.mktemp("outlier_strip")
    render_scene(d, SceneSpec(outlier_fraction=0.01, seed=17))
    return d


def test_one_percent_outliers_with_default_settings_recover_the_truth(dirty, tmp_path):
    res = solve(dirty / "settings.txt", out=tmp_path / "out", workers=1, plots=False)
    sc = score(tmp_path / "out", dirty)
    assert sc["albedo_rel_rmse"] <= 0.022 and sc["albedo_rel_p99"] <= 0.08, sc
    assert sc["exposure_max_rel_err"] <= 0.01 and sc["coverage"] > 0.95, sc
    rep = res.report["outliers"]
    # about the 1 % planted in each image (hot spots and dropout rows), a little more at their resampled edges
    for key, im in rep["images"].items():
        assert 0.007 <= im["rejected_fraction"] <= 0.03, (key, im)
    tiles = sorted((tmp_path / "out" / "outliers").glob("*.tif"))
    assert tiles and len(tiles) == len(res.tiles)
    with rasterio.open(tiles[0]) as ds:
        frac = ds.read(1)
    assert ds.dtypes[0] == "float32" and np.nanmax(frac) == 1.0 and 0.002 < np.nanmean(frac) < 0.03


def test_the_prepare_steps_spatial_test_rejects_what_the_first_reweight_pass_did(dirty, tmp_path, monkeypatch):
    """With a static shadow mask the spatial test runs as each block is prepared (engine/robust.py): no reweight pass
    over the cache on two images a pixel.  It rejects what the first reweight pass rejected with the seed exposures
    (forced here), image by image, and the solve ends where that one did."""
    from lunaralbedo.engine import robust

    res = solve(dirty / "settings.txt", out=tmp_path / "here", workers=1, plots=False)
    rep = res.report["outliers"]
    assert rep["spatial_test"] == "prepare" and rep["reweight_passes"] == 0, rep
    monkeypatch.setattr(robust, "in_prepare", lambda settings: False)
    old = solve(dirty / "settings.txt", out=tmp_path / "pass", workers=1, plots=False)
    was = old.report["outliers"]
    assert was["spatial_test"] == "reweight pass" and was["reweight_passes"] == 1, was
    for key, im in rep["images"].items():
        assert im["observations"] == was["images"][key]["observations"], key
        assert abs(im["rejected_fraction"] - was["images"][key]["rejected_fraction"]) <= 1e-5, (key, im, was)
    new, ref = score(tmp_path / "here", dirty), score(tmp_path / "pass", dirty)
    assert abs(new["albedo_rel_rmse"] - ref["albedo_rel_rmse"]) < 2e-4, (new, ref)
    assert abs(new["exposure_max_rel_err"] - ref["exposure_max_rel_err"]) < 2e-4, (new, ref)


def test_a_shadow_mask_of_the_exposures_keeps_the_spatial_test_in_a_reweight_pass(dirty, tmp_path):
    """Shadow type 2 (lit where I/(R T) >= t) needs the exposures: the first reweight pass runs the spatial test,
    and the outliers are rejected as well."""
    res = solve(_with(dirty / "settings.txt", dirty / "ratio.txt", SHADOW_TYPE=2), out=tmp_path / "out", workers=1,
                plots=False)
    rep = res.report["outliers"]
    assert rep["spatial_test"] == "reweight pass" and rep["reweight_passes"] == 1, rep
    sc = score(tmp_path / "out", dirty)
    assert sc["albedo_rel_rmse"] <= 0.022 and sc["albedo_rel_p99"] <= 0.08, sc
    assert all(0.007 <= im["rejected_fraction"] <= 0.03 for im in rep["images"].values()), rep


def test_outlier_rejection_gives_the_same_bytes_on_two_workers(tmp_path):
    """Defaults on a strip with outliers over several tiles: the reweight pass rejects observations, so the exposures
    start again from the kept observations' overlap sums, summed per tile and reduced in tile order."""
    d = tmp_path / "scene"
    render_scene(d, SceneSpec(outlier_fraction=0.01, n_images=4, image_px=80, tile_size=0.25, seed=5))
    one = solve(d / "settings.txt", out=tmp_path / "one", workers=1, plots=False)
    solve(d / "settings.txt", out=tmp_path / "two", workers=2, plots=False)
    assert len(one.tiles) > 1 and sum(v["rejected_fraction"] > 0 for v in one.report["outliers"]["images"].values()) >= 2
    assert (tmp_path / "one" / "exposure.csv").read_bytes() == (tmp_path / "two" / "exposure.csv").read_bytes()
    for sub in ("albedo", "outliers"):
        files = sorted((tmp_path / "one" / sub).glob("*.tif"))
        assert files and all(p.read_bytes() == (tmp_path / "two" / sub / p.name).read_bytes() for p in files), sub


def test_without_rejection_the_outliers_spoil_the_albedo(dirty, tmp_path):
    off = _with(dirty / "settings.txt", dirty / "off.txt", REJECT_OUTLIERS=0, ROBUST_LOSS="none")
    res = solve(off, out=tmp_path / "out", workers=1, plots=False)
    sc = score(tmp_path / "out", dirty)
    assert sc["albedo_rel_rmse"] > 0.05 and sc["albedo_rel_p99"] > 0.2, sc  # what the default removes
    assert res.report["outliers"] is None and not (tmp_path / "out" / "outliers").exists()


def test_the_clean_strip_does_not_get_worse(tmp_path):
    d = tmp_path / "clean"
    render_scene(d, SceneSpec(seed=17))
    solve(d / "settings.txt", out=tmp_path / "on", workers=1, plots=False)
    off = _with(d / "settings.txt", d / "off.txt", REJECT_OUTLIERS=0, ROBUST_LOSS="none")
    solve(off, out=tmp_path / "off", workers=1, plots=False)
    on, plain = score(tmp_path / "on", d), score(tmp_path / "off", d)
    assert on["albedo_rel_rmse"] <= 0.0185 and on["albedo_rel_rmse"] <= plain["albedo_rel_rmse"] + 2e-4, (on, plain)
    rep = json.loads((tmp_path / "on" / "report.json").read_text())["outliers"]
    assert rep["rejected_fraction"] < 0.001, rep


def test_robust_loss_down_weights_where_three_images_overlap(tmp_path):
    d = tmp_path / "three"
    render_scene(d, SceneSpec(overlap=0.7, outlier_fraction=0.01, n_images=5, seed=19))
    res = solve(_with(d / "settings.txt", d / "huber.txt", ROBUST_LOSS="huber", ROBUST_THRESHOLD=2.0),
                out=tmp_path / "out", workers=1, plots=False)
    sc = score(tmp_path / "out", d)
    assert sc["albedo_rel_rmse"] <= 0.022 and sc["albedo_rel_p99"] <= 0.08, sc
    down = [im["downweighted_fraction"] for im in res.report["outliers"]["images"].values()]
    assert min(down) > 0.0, res.report["outliers"]


def test_nan_median_filter_is_the_median_of_the_valid_neighbours():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20, 30))
    x[rng.random(x.shape) < 0.2] = np.nan
    got = outliers.nan_median_filter(x, 5)
    for i, j in [(10, 10), (5, 17), (0, 0), (19, 29), (2, 28)]:
        win = x[max(0, i - 2):i + 3, max(0, j - 2):j + 3]
        v = np.sort(win[np.isfinite(win)])
        if len(v) * 2 < 25:
            assert np.isnan(got[i, j])
        else:
            lo, hi = v[12 - (25 - len(v))], v[12]  # the ranks from below and from above
            assert got[i, j] == pytest.approx(0.5 * (lo + hi))
            assert v[0] <= got[i, j] <= v[-1]


def test_spatial_test_rejects_the_deviant_image_and_keeps_a_feature_both_see():
    # pixel 0: image 0 is a hot spot (e = 0.7), image 1 sees the usual (0.01); pixel 1: both see a bright crater
    e = np.array([0.7, 0.01, 0.6, 0.62, 0.9])
    pixel = np.array([0, 0, 1, 1, 2])  # pixel 2: one image alone, far out
    tau = np.full(5, 0.15)
    assert outliers.spatial_outliers(e, pixel, tau).tolist() == [True, False, False, False, True]


def _spatial_block():
    """A block (chunk-major runs) of four images' log albedo over a texture, with hot spots, a dropout row, a bright
    feature every image sees and holes; values ``image = exp(loga)`` (T = R = 1)."""
    from lunaralbedo.engine import runs

    rng = np.random.default_rng(3)
    k, h, w = 4, 40, 50
    yy, xx = np.mgrid[:h, :w]
    texture = 0.3 * np.sin(xx / 5.0) * np.cos(yy / 7.0)
    loga = texture[None] + rng.normal(0, 0.02, (k, h, w))
    loga[:, 20:22, 30:32] += 0.8  # a small bright crater in every image: kept
    hot = rng.random((k, h, w)) < 0.01
    loga[hot] += rng.uniform(0.5, 1.1, np.count_nonzero(hot))  # hot spots of one image
    loga[2, 11, 10:40] -= 1.2  # a dropout row
    used = np.zeros((k, h, w), bool)
    for i in range(k):  # each image a band of columns (overlaps of two images), images 1-3 with holes
        used[i, :, 12 * i:12 * i + 20] = True
    used[1:] &= rng.random(used[1:].shape) > 0.03
    sel = [np.flatnonzero(used[i]) for i in range(k)]
    obs = {"pix": np.concatenate(sel).astype(np.int32), "index": np.arange(k, dtype=np.int32),
           "start": np.concatenate([[0], np.cumsum([len(x) for x in sel])]).astype(np.int64),
           "loga": np.concatenate([loga[i].ravel()[sel[i]] for i in range(k)])}
    obs["image"] = np.exp(obs["loga"].astype(np.float64))  # the kernel takes values, R, T and haze: a = I / (T R)
    return runs.chunk_runs(obs, h * w, ["loga", "image"], 64), k, h, w


def test_the_spatial_test_does_not_depend_on_the_exposures():
    """What lets the prepare step run it before any exposure is known (engine/robust.py): the same values seen with
    other exposures (I = T a) are rejected where they were, with the exposures known or all taken as 1."""
    from lunaralbedo.engine import robust_kernels, runs

    block, k, h, w = _spatial_block()
    ones, used = np.ones(len(block["image"]), np.float32), np.empty(len(block["image"]), bool)
    want = robust_kernels.spatial_test(block, w, np.zeros(k), np.ones(k), ones, ones, used)
    t = np.array([0.37, 1.9, 4.3, 0.81])
    scaled = {**block, "image": block["image"] * t[runs.observation_images(block)]}
    for texp in (t, np.ones(k)):
        got = robust_kernels.spatial_test(scaled, w, np.zeros(k), texp, ones, ones, used)
        assert used.all() and want.sum() > 20
        np.testing.assert_array_equal(got, want)


def test_the_reweight_kernel_flags_what_the_numpy_test_flags():
    """The reweight pass's numba spatial test over a block's runs (engine/robust_kernels.py) rejects exactly the
    observations the NumPy form of model/outliers.py rejects (each image's raster, box means, window medians, the
    other images' mean), here with hot spots, a dropout row, a bright feature every image sees and holes."""
    from lunaralbedo.engine import robust_kernels, runs

    block, k, h, w = _spatial_block()
    ones, used = np.ones(len(block["image"]), np.float32), np.empty(len(block["image"]), bool)
    got = robust_kernels.spatial_test(block, w, np.zeros(k), np.ones(k), ones, ones, used)
    assert used.all()
    block["loga"] = np.log(block["image"])  # the kernel's logarithm is within 1 ulp of NumPy's (tests/test_vlog.py)

    img, pix = runs.observation_images(block), runs.observation_pixels(block)
    e, tau = np.full(len(pix), np.nan), np.zeros(len(pix))
    for i in range(k):  # the NumPy form: each image's raster over its bounding box
        at = np.flatnonzero(img == i)
        row, col = pix[at] // w, pix[at] % w
        raster = np.full((row.max() - row.min() + 1, col.max() - col.min() + 1), np.nan)
        raster[row - row.min(), col - col.min()] = block["loga"][at]
        e[at], tau[at] = outliers.neighbourhood_deviation(raster, row - row.min(), col - col.min())
    want = outliers.spatial_outliers(e, pix, tau)
    assert 20 < np.count_nonzero(want) < 0.05 * len(pix)
    assert not want[(pix // w >= 20) & (pix // w < 22) & (pix % w >= 30) & (pix % w < 32)].any()  # the crater stays
    np.testing.assert_array_equal(got, want)


def test_loss_weights():
    u = np.array([0.0, 1.0, 3.0, -6.0])
    assert outliers.loss_weights(u, "cauchy", 3.0) == pytest.approx([1.0, 0.9, 0.5, 0.2])
    assert outliers.loss_weights(u, "huber", 3.0) == pytest.approx([1.0, 1.0, 1.0, 0.5])
    assert outliers.loss_weights(u, "none", 3.0) == pytest.approx([1.0] * 4)


@pytest.mark.parametrize("loss", ["cauchy", "huber", "none"])
def test_loss_rho_is_the_cost_whose_irls_weights_are_loss_weights(loss):
    """IRLS minimises sum rho(u) by weights m = rho'(u) / u: the two must be one loss (finite differences)."""
    u, h = np.array([-12.0, -4.0, -0.5, 0.3, 2.0, 2.9, 3.1, 7.0, 40.0]), 1e-6
    slope = (outliers.loss_rho(u + h, loss, 3.0) - outliers.loss_rho(u - h, loss, 3.0)) / (4 * h)  # rho' (of 2 rho)
    assert slope / u == pytest.approx(outliers.loss_weights(u, loss, 3.0), rel=1e-6)
    assert outliers.loss_rho(np.array([1e-3]), loss, 3.0)[0] == pytest.approx(1e-6, rel=1e-6)  # u^2 near 0


@pytest.mark.parametrize("key,value,needle", [("ROBUST_LOSS", "tukey", "ROBUST_LOSS must be one of cauchy, huber, none"),
                                              ("ROBUST_THRESHOLD", "-1", "ROBUST_THRESHOLD must be a number > 0"),
                                              ("REJECT_OUTLIERS", "2", "REJECT_OUTLIERS must be one of 0, 1")])
def test_bad_robust_settings_exit_2_naming_the_key(tmp_path, key, value, needle):
    d = tmp_path / "scene"
    render_scene(d, SceneSpec(n_images=2, image_px=40, seed=3))
    s = _with(d / "settings.txt", d / "bad.txt", **{key: value})
    res = CliRunner().invoke(main, ["solve", str(s), "-o", str(tmp_path / "o"), "--workers", "1", "--quiet"])
    assert res.exit_code == 2 and needle in res.output and "Traceback" not in res.output, res.output


def test_standing_out_flags_defects_of_one_image_not_its_noise():
    rng = np.random.default_rng(5)
    e = rng.normal(0.0, 0.01, 5000)  # log ratios of a clean image: 1 % noise
    e[[10, 20]] = [np.log(2.0), np.log(0.3)]  # a hot spot and a dropout pixel
    e[30] = np.nan  # no model there
    bad = outliers.standing_out(e)
    assert bad[[10, 20, 30]].all() and np.count_nonzero(bad) == 3  # tau = max(0.15, 6 x 0.01): no clean one
    wide = rng.normal(0.0, 0.05, 5000)  # 5 % noise: tau 0.3, a 16 % deviation is not an outlier
    wide[0] = 0.16
    assert not outliers.standing_out(wide)[0]


@pytest.mark.parametrize("size", [7, 5])
@pytest.mark.parametrize("holes", [True, False])
@pytest.mark.parametrize("shape", [(37, 23), (4, 9)])
def test_window_deviations_are_each_value_less_its_windows_mean(size, holes, shape):
    """The spatial test's box sums (engine/window_kernels.window_deviations) against a brute-force NumPy mean of
    every window's valid values (NaN where fewer than half of the window is valid), on a random raster with holes
    and one without, a raster smaller than the window too; the counts per row and the candidates above a limit."""
    from lunaralbedo.engine import window_kernels

    hk, wk = shape
    rng = np.random.default_rng(size + 10 * holes + hk)
    x = rng.normal(-1.0, 0.3, shape)
    if holes:
        x[rng.random(shape) < 0.25] = np.nan
        x[:2, :] = np.nan  # a row with no value, as at a footprint's edge
    h, half = size // 2, (size * size + 1) // 2
    want = np.full(shape, np.nan)
    for i in range(hk):
        for j in range(wk):
            win = x[max(0, i - h):i + h + 1, max(0, j - h):j + h + 1]
            v = win[np.isfinite(win)]
            if len(v) >= half:
                want[i, j] = x[i, j] - v.mean()
    dev, rows, cand = np.empty(hk * wk), np.empty(hk, np.int64), np.empty(hk * wk, np.int64)
    work = np.empty(window_kernels.window_scratch(wk, size))
    nc = window_kernels.window_deviations(x.ravel(), hk, wk, size, holes, dev, work, rows, 0.3, cand)
    got = dev.reshape(shape)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], rtol=0, atol=1e-13)
    np.testing.assert_array_equal(rows, np.isfinite(want).sum(axis=1))
    np.testing.assert_array_equal(cand[:nc], np.flatnonzero(np.abs(np.nan_to_num(want)) > 0.3))


def test_median_and_spread_are_numpys_on_ties_sorted_and_constant_values():
    """The spread's median (engine/window_kernels.median: quickselect with a branch-free partition) is the value
    np.median gives, for odd and even counts, ties, sorted and constant values; mad_sigma is outliers.robust_sigma."""
    from lunaralbedo.engine import window_kernels

    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 4, 7, 10, 101, 1000, 8191, 8192):
        for case in range(6):
            x = rng.normal(size=n)
            x = {0: x, 1: np.round(x, 1), 2: np.sort(x), 3: np.sort(x)[::-1].copy(), 4: np.full(n, 0.25),
                 5: np.round(rng.standard_cauchy(n), 2)}[case]
            assert window_kernels.median(x.copy(), n) == np.median(x), (n, case)
            assert window_kernels.mad_sigma(x.copy(), n) == pytest.approx(outliers.robust_sigma(x), rel=1e-15, abs=1e-300)
    assert np.isnan(window_kernels.mad_sigma(np.zeros(0), 0))


def test_the_spread_sample_is_every_step_th_number_in_raster_order():
    from lunaralbedo.engine import window_kernels

    rng = np.random.default_rng(5)
    e = rng.normal(size=(300, 70))
    e[:100][rng.random((100, 70)) < 0.1] = np.nan  # rows with holes, rows without (100-199), rows with NaN at an end
    e[200:, :3] = np.nan
    rows = np.isfinite(e).sum(axis=1)
    d = np.empty(window_kernels.SCALE_SAMPLE)
    n = window_kernels.sample(e.ravel(), 300, 70, rows, d)
    v = e.ravel()[np.isfinite(e.ravel())]
    step = -(-len(v) // window_kernels.SCALE_SAMPLE)
    assert step == 3 and n == len(v[::step])
    np.testing.assert_array_equal(d[:n], v[::step])


def test_the_log_albedo_kernel_uses_what_the_float64_product_uses_and_stays_finite():
    """The reweight pass's float32 log albedo (engine/robust_kernels._log_run): the observations it uses are those
    with eq. 1's weight above 0 and T R > 0 in float64 (robust_kernels.usable), for every sign, zero, NaN and
    infinity of T and R; log a within 3e-7 of NumPy's float64 log of max(I - H, 1e-6) / (T R), and a number (the
    ratio clamped to the float32 range) even where T R is below or beyond it."""
    from lunaralbedo.engine import robust_kernels

    special = np.array([0.0, -0.0, 1.0, -1.0, 2.5, -2.5, np.nan, np.inf, -np.inf, 1e-40, 3e38], np.float32)
    for t in special:
        rng = np.random.default_rng(6)
        r = np.concatenate([special, rng.uniform(-1, 2, 200).astype(np.float32)])
        w = np.where(rng.random(len(r)) < 0.2, 0.0, 1.0).astype(np.float32)
        image = np.concatenate([np.full(len(special), 80.0), rng.uniform(-5, 300, 200)]).astype(np.float32)
        loga, used, want = np.empty(len(r), np.float32), np.empty(len(r), bool), np.empty(len(r), bool)
        n_ok = robust_kernels._log_run(image, r, w, np.float32(3.0), t, loga, used, len(r))
        robust_kernels.usable(np.array([0, len(r)]), np.array([0]), np.array([t]), r, w, want)
        with np.errstate(all="ignore"):
            x = np.float64(t) * r.astype(np.float64)
            ref = np.log(np.maximum(image.astype(np.float64) - 3.0, 1e-6) / x)
        np.testing.assert_array_equal(used, want)
        np.testing.assert_array_equal(used, (w > 0) & (x > 0))
        assert np.isfinite(loga[used]).all() and np.isnan(loga[~used]).all() and n_ok == used.sum()
        ok = used & (x > 1e-30) & (x < 1e30)
        assert np.all(np.abs(loga[ok] - ref[ok]) <= 3e-7 * np.maximum(1.0, np.abs(ref[ok])))


def test_a_far_observation_is_compared_with_the_median_deviation_of_the_other_image():
    """Image 1 has a dropout row: the window means of the rows around it are pulled beyond tau / 2, so its
    deviations there are its window medians'.  At P image 0 is 0.29 above its neighbourhood and image 1 0.10 (0.27
    from its window mean): against image 1's median deviation image 0 stands out (0.19 > tau = 0.15), against the
    mean deviation it would not.  The kernel (which takes such a median only when a far observation asks for it)
    flags what the NumPy form flags."""
    from lunaralbedo.engine import robust_kernels, runs

    rng = np.random.default_rng(8)
    k, h, w = 2, 30, 40
    loga = rng.normal(0, 0.01, (k, h, w))
    loga[1, 15, :] -= 1.2
    loga[1, 13, 20] += 0.1
    loga[0, 13, 20] += 0.3
    obs = {"pix": np.tile(np.arange(h * w, dtype=np.int32), k), "index": np.arange(k, dtype=np.int32),
           "start": np.array([0, h * w, 2 * h * w], np.int64), "image": np.exp(loga.reshape(-1))}
    block = runs.chunk_runs(obs, h * w, ["image"], 64)
    ones, used = np.ones(len(block["image"]), np.float32), np.empty(len(block["image"]), bool)
    got = robust_kernels.spatial_test(block, w, np.zeros(k), np.ones(k), ones, ones, used)

    img, pix = runs.observation_images(block), runs.observation_pixels(block)
    e, tau = np.full(len(pix), np.nan), np.zeros(len(pix))
    for i in range(k):
        at = np.flatnonzero(img == i)
        e[at], tau[at] = outliers.neighbourhood_deviation(np.log(block["image"][at]).reshape(h, w), pix[at] // w, pix[at] % w)
    want = outliers.spatial_outliers(e, pix, tau)
    at_p = np.flatnonzero(pix == 13 * w + 20)
    assert want[at_p].tolist() == [True, False] and 0.05 < e[at_p[1]] < 0.15 < e[at_p[0]] - e[at_p[1]]
    assert want[(img == 1) & (pix // w == 15)].all()  # the dropout row
    np.testing.assert_array_equal(got, want)
