"""The reweight pass's robust loss in numba (engine/loss_kernels.py): its factors against the NumPy formulas of
model/outliers.py on small blocks, and a forward-model strip where the loss alone must remove planted outliers."""
from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from rasterio.merge import merge

from lunaralbedo.engine import loss_kernels, robust_kernels, runs
from lunaralbedo.engine.solve import solve
from lunaralbedo.model import outliers
from lunaralbedo.simulate import SceneSpec, render_scene
from resume_common import solve_stopped_at_pass


def _block(rng, bands, h, w, hole=0.03):
    """A block of ``len(bands)`` images, image i on columns ``bands[i]`` of an ``h x w`` block (holes in a few %), with
    the truth A T R + H + noise and 2 % outliers (x0.3 or x2.5); returns the runs, haze, exposures, keep and the
    planted outliers (bool per observation, in the runs' order)."""
    n = len(bands)
    albedo = rng.uniform(0.5, 1.5, h * w)
    texp, haze = rng.uniform(0.8, 1.2, n).astype(np.float32), rng.uniform(0.0, 5.0, n).astype(np.float32)
    cols = np.arange(h * w) % w
    pix, parts = [], []
    for i, (c0, c1) in enumerate(bands):
        p = np.flatnonzero((cols >= c0) & (cols < c1) & (rng.random(h * w) > hole)).astype(np.int32)
        r = rng.uniform(0.5, 1.0, len(p))
        bad = rng.random(len(p)) < 0.02
        value = (100 * albedo[p] * texp[i] * r + haze[i] + rng.normal(0, 1.0, len(p))) * np.where(bad, rng.choice([0.3, 2.5], len(p)), 1)
        base = np.where(rng.random(len(p)) < 0.01, 0.0, rng.uniform(0.5, 1.0, len(p)))
        prev = base * rng.uniform(0.6, 1.0, len(p))  # the previous pass's factors
        pix.append(p)
        parts.append(np.stack([value, base, 100 * r, prev, bad]).astype(np.float32))
    rows = np.concatenate(parts, axis=1)
    obs = {"pix": np.concatenate(pix), "index": np.arange(n, dtype=np.int32),
           "start": np.concatenate([[0], np.cumsum([len(p) for p in pix])]).astype(np.int64),
           **dict(zip(["image", "weight", "r", "prev", "bad"], rows))}
    block = runs.chunk_runs(obs, h * w, ["image", "weight", "r", "prev", "bad"], 64)
    keep = (block["weight"] > 0) & (rng.random(len(block["weight"])) > 0.03)  # the spatial test's rejections
    return block, haze, texp, keep, block["bad"] > 0


def _numpy_factors(block, haze, texp, keep, loss, k):
    """The factors by the NumPy formulas: eq. 3's albedo per pixel, each image's 1.4826 MAD of its residuals (the
    block's pooled one below MIN_SCALE_OBS), Cauchy 1/(1 + u^2/k^2) or Huber min(1, k/|u|)."""
    img, pix = runs.observation_images(block), runs.observation_pixels(block)
    w = np.where(keep, block["prev"], 0.0)
    signal, tr = block["image"] - haze[img].astype(np.float64), texp[img].astype(np.float64) * block["r"]
    albedo = np.bincount(pix, signal * tr * w) / np.maximum(np.bincount(pix, tr * tr * w), 1e-300)
    res = signal - albedo[pix] * tr
    many = keep & (np.bincount(pix, keep)[pix] >= outliers.MIN_IMAGES_FOR_LOSS)
    pooled = outliers.robust_sigma(res[many])
    m = np.ones(len(keep))
    for i in range(len(haze)):
        sel = many & (img == i)
        scale = outliers.robust_sigma(res[sel]) if sel.sum() >= outliers.MIN_SCALE_OBS else pooled
        u = np.abs(res[sel] / scale)
        m[sel] = 1 / (1 + (u / k) ** 2) if loss == "cauchy" else np.minimum(1, k / u)
    return m, many


@pytest.mark.parametrize("loss", ["cauchy", "huber"])
def test_the_loss_kernel_gives_the_numpy_factors(loss):
    """Below SCALE_SAMPLE residuals an image's scale is its exact MAD: the same factors to rounding.  Pixels with
    one to five images, an image with fewer than MIN_SCALE_OBS residuals where three meet (the pooled scale)."""
    rng = np.random.default_rng(11)
    bands = [(0, 20), (6, 26), (12, 32), (18, 38), (29, 31)]  # image 4: two columns (~40 px on >= 3 images)
    block, haze, texp, keep, bad = _block(rng, bands, 30, 40)
    want, many = _numpy_factors(block, haze, texp, keep, loss, 2.0)
    assert 0 < np.count_nonzero(many & (runs.observation_images(block) == 4)) < outliers.MIN_SCALE_OBS
    m, n = loss_kernels.block_loss_factors(block, haze, texp, block["r"], keep, block["prev"], loss, 2.0,
                                           np.empty(len(keep)))
    assert n == np.count_nonzero(many)
    np.testing.assert_allclose(m, want, rtol=1e-10, atol=1e-12)
    assert np.median(m[many & bad]) < 0.2 and np.median(m[many & ~bad]) > 0.7  # the planted outliers are down-weighted


def test_the_loss_kernel_takes_the_scale_from_a_sample_of_large_images():
    """Above SCALE_SAMPLE residuals an image's scale is the MAD of an evenly spaced sample: within a few % of the
    full one, so the factors are too; and fewer than MIN_SCALE_OBS residuals in the block: no factors at all."""
    rng = np.random.default_rng(12)
    block, haze, texp, keep, bad = _block(rng, [(0, 100)] * 3, 100, 100, hole=0.0)
    assert np.bincount(runs.observation_images(block)).min() > 1.2 * robust_kernels.SCALE_SAMPLE
    want, many = _numpy_factors(block, haze, texp, keep, "cauchy", 3.0)
    m, n = loss_kernels.block_loss_factors(block, haze, texp, block["r"], keep, block["prev"], "cauchy", 3.0,
                                           np.empty(len(keep)))
    assert n == np.count_nonzero(many)
    assert np.max(np.abs(m - want)) < 0.03 and np.mean(np.abs(m - want)) < 0.005
    few = keep & (runs.observation_pixels(block) < 10)  # 10 pixels of three images: 30 residuals
    m, n = loss_kernels.block_loss_factors(block, haze, texp, block["r"], few, block["prev"], "cauchy", 3.0,
                                           np.empty(len(keep)))
    assert len(m) == 0 and n == 0


def _with(d, name, **keys):
    lines = [ln for ln in (d / "settings.txt").read_text().splitlines() if ln.split()[:1] not in ([k] for k in keys)]
    (d / name).write_text("\n".join(lines + [f"{k} {v}" for k, v in keys.items()]) + "\n")
    return d / name


def test_the_robust_loss_alone_removes_outliers_where_three_images_overlap(tmp_path):
    """No spatial test (REJECT_OUTLIERS 0), the Cauchy loss: where three or more images cover a pixel (from the DRGs'
    footprints) it must out-vote the 1 % planted hot spots and dropout rows that spoil the plain least squares; the
    same bytes on two workers."""
    d = tmp_path / "scene"
    render_scene(d, SceneSpec(n_images=6, overlap=0.8, outlier_fraction=0.01, seed=23))
    truth = json.loads((d / "truth" / "truth.json").read_text())
    with rasterio.open(d / truth["albedo"]) as t:
        ta, tt, tb = t.read(1), t.transform, t.bounds
    rows, cols = np.mgrid[:ta.shape[0], :ta.shape[1]]
    lon, lat = tt.c + tt.a * (cols + 0.5), tt.f + tt.e * (rows + 0.5)  # pixel centres, degrees
    cover = np.zeros(ta.shape, int)
    for f in sorted((d / "DRG").glob("*.tif")):
        with rasterio.open(f) as ds:
            b, margin = ds.bounds, 2 * ds.res[0]
        cover += (lon > b.left + margin) & (lon < b.right - margin) & (lat > b.bottom + margin) & (lat < b.top - margin)
    errors = {}
    for loss in ("none", "cauchy"):
        solve(_with(d, f"{loss}.txt", REJECT_OUTLIERS=0, ROBUST_LOSS=loss, ROBUST_THRESHOLD=3), out=tmp_path / loss,
              workers=1, plots=False)
        a = merge(sorted(str(f) for f in (tmp_path / loss / "albedo").glob("*.tif")), bounds=tb, res=(tt.a, -tt.e),
                  nodata=np.nan, dtype="float32")[0][0]
        ok = np.isfinite(a) & np.isfinite(ta) & (cover >= outliers.MIN_IMAGES_FOR_LOSS)
        s = np.sum(a[ok] * ta[ok]) / np.sum(a[ok] ** 2)  # A T leaves one global scale free
        errors[loss] = np.abs(s * a[ok] - ta[ok]) / ta[ok]
        assert ok.sum() > 0.5 * ok.size  # of the truth grid
    solve(d / "cauchy.txt", out=tmp_path / "two", workers=2, plots=False)  # per tile in a fixed order: the same bytes
    for sub in ("albedo", "outliers"):
        files = sorted((tmp_path / "cauchy" / sub).glob("*.tif"))
        assert len(files) > 1 and all(f.read_bytes() == (tmp_path / "two" / sub / f.name).read_bytes() for f in files)
    none, cauchy = errors["none"], errors["cauchy"]
    assert np.percentile(none, 99) > 0.2 and np.mean(none > 0.1) > 0.02, np.percentile(none, 99)  # what the loss removes
    assert np.percentile(cauchy, 99) < 0.05 and np.mean(cauchy > 0.1) < 0.01, (np.percentile(cauchy, 99), np.mean(cauchy > 0.1))


def test_resume_after_the_loss_pass_gives_the_same_bytes(tmp_path, monkeypatch):
    """Default settings where five images meet: two reweight passes (the second, the loss's, before the third
    iteration). A run stopped in its fourth iteration and resumed writes the bytes of an uninterrupted run."""
    d = tmp_path / "scene"
    render_scene(d, SceneSpec(n_images=6, overlap=0.8, outlier_fraction=0.01, image_px=80, seed=29))
    ref = solve(d / "settings.txt", out=tmp_path / "ref", workers=1, plots=False, tolerance=0.0, max_iter=5)
    assert ref.report["outliers"]["reweight_passes"] == 2
    solve_stopped_at_pass(monkeypatch, d / "settings.txt", tmp_path / "out", len(ref.tiles), 4, workers=1, plots=False,
                          tolerance=0.0, max_iter=5)
    state = json.loads((tmp_path / "out" / "checkpoint" / "state.json").read_text())
    # generation 1: the prepare step's spatial test; 2 and 3: the loss's passes before iterations 1 and 3
    assert state["iteration"] == 3 and state["robust"] == 3 and state["loss_observations"] > 0, state
    solve(d / "settings.txt", out=tmp_path / "out", workers=1, plots=False, tolerance=0.0, max_iter=5, resume=True)
    assert (tmp_path / "ref" / "exposure.csv").read_bytes() == (tmp_path / "out" / "exposure.csv").read_bytes()
    for sub in ("albedo", "outliers"):
        files = sorted((tmp_path / "ref" / sub).glob("*.tif"))
        assert files and all(p.read_bytes() == (tmp_path / "out" / sub / p.name).read_bytes() for p in files), sub


def test_the_kept_overlaps_are_the_prepare_steps_less_the_pairs_of_the_rejected():
    """The overlap sums for the exposures' new start: the prepare step's (model/exposure_init.pair_sums over every
    image's pixels with a value and R above 0) plus the negated pairs the rejected observations took part in
    (engine/pair_kernels.py, walked from the rejected observations only) equal pair_sums over the kept pixels."""
    from lunaralbedo.engine import robust
    from lunaralbedo.model import exposure_init

    rng = np.random.default_rng(5)
    block, _, _, keep, _ = _block(rng, [(0, 40), (25, 70), (30, 55), (60, 96)], 48, 96)
    block["image"][rng.random(len(keep)) < 0.01] = -0.5  # a few values the prepare step does not use
    index = np.array([3, 0, 7, 5], np.int32)  # global ids, not in order
    block["index"] = index
    flag = ~keep & (block["weight"] > 0)  # the spatial test's rejections
    img, pix = runs.observation_images(block), runs.observation_pixels(block)
    r = block["r"].astype(np.float32)
    prepared = (block["image"] > 0) & (r > 0)

    def sums(use):
        order = np.lexsort((pix, img))[use[np.lexsort((pix, img))]]  # image-major, pixels ascending
        start = np.searchsorted(img[order], np.arange(len(index) + 1))
        return exposure_init.pair_sums(pix[order], start, block["image"][order], r[order], index)

    got = exposure_init.merge_pair_sums(dict(sums(prepared)), robust._removed_pairs(block, r, flag))
    want = sums(prepared & ~flag)
    assert flag.sum() > 50 and len(want) >= 4 and set(want) <= set(got)
    for key, (n, d) in got.items():
        wn, wd = want.get(key, (0, 0.0))
        assert n == wn and d == pytest.approx(wd, rel=1e-6, abs=1e-7 * max(n, 1)), key  # float32 logs (numba, NumPy)


def test_the_outliers_layer_from_the_runs_is_the_numpy_formula():
    """finalise's ``outliers/`` rows (engine/finalise_kernels.lost_fraction_runs, from the runs) have the bits of
    model/outliers.lost_fraction (NumPy bincounts over each observation's pixel): rejected, down-weighted, unweighted
    observations and pixels no observation reaches."""
    from lunaralbedo.engine.finalise_kernels import lost_fraction_runs
    from lunaralbedo.model import outliers

    rng = np.random.default_rng(8)
    block, _, _, keep, _ = _block(rng, [(0, 40), (25, 70), (30, 55), (60, 96)], 48, 96)
    base = block["weight"]
    eff = (base * np.where(keep, rng.uniform(0.2, 1.0, len(base)), 0.0) ** (rng.random(len(base)) < 0.3)).astype(np.float32)
    n_pix = 48 * 96
    got = np.full(n_pix, np.nan, np.float32)
    lost_fraction_runs(block["run_start"], block["run_pixel"], base, eff, np.empty(n_pix), np.empty(n_pix), got)
    want = outliers.lost_fraction(base, eff, runs.observation_pixels(block), n_pix)
    assert np.isnan(want).sum() > 10 and (want > 0).sum() > 100 and (want == 0).sum() > 100
    np.testing.assert_array_equal(got, want)


def test_the_weights_store_gives_back_what_a_pass_wrote(tmp_path):
    """engine/robust_store.py: a block whose weights changed in a few places is stored as those places (a few
    bytes), one where many changed whole; both read back as the same float32 values, an unchanged block as the
    cached weights themselves; a block of another length is refused (a cache of another preparation)."""
    from lunaralbedo.engine import robust_store

    rng = np.random.default_rng(3)
    cached = rng.uniform(0.1, 1.0, 10_000).astype(np.float32)
    few, many = cached.copy(), cached * rng.uniform(0.2, 1.0, len(cached)).astype(np.float32)
    few[rng.choice(len(few), 300, replace=False)] = 0.0
    for name, w in (("block_0000", few), ("block_0001", many), ("block_0002", cached.copy())):
        robust_store.save(tmp_path / name, 1, cached, w)
        got = robust_store.load(tmp_path / name, cached, 1)
        np.testing.assert_array_equal(got, w)
        assert got.dtype == np.float32
    stored = {p.name: p.stat().st_size for p in (tmp_path / "robust_1").iterdir()}
    assert set(stored) == {"block_0000.changed.npy", "block_0000.value.npy", "block_0001.npy",
                           "block_0002.changed.npy", "block_0002.value.npy"}
    assert stored["block_0000.changed.npy"] + stored["block_0000.value.npy"] < 0.15 * stored["block_0001.npy"]
    assert robust_store.load(tmp_path / "block_0002", cached, 1) is cached
    for name in ("block_0000", "block_0001"):
        with pytest.raises(FileNotFoundError, match="another preparation"):
            robust_store.load(tmp_path / name, cached[:-1], 1)
