"""Structures that scale to 10^5 images: sparse overlap exposures and the tile x image index."""
from __future__ import annotations

from lunaralbedo.runtime import Runtime
import numpy as np
import pytest

from lunaralbedo.model import exposure_init


def _random_pairs(rng, k, per_image=4):
    pairs = {}
    for j in range(k):
        for i in rng.choice(k, per_image):
            if j < i:
                pairs[(j, int(i))] = (int(rng.integers(1, 1000)), float(rng.normal() * 50))
    return pairs


def test_sparse_overlap_exposure_equals_the_dense_least_squares():
    """Same minimiser as the stacked least-squares rows solved densely (independent formulation)."""
    rng = np.random.default_rng(3)
    k, mu = 120, 1e-6
    pairs = _random_pairs(rng, k)
    x0 = rng.normal(size=k) * 0.2
    lam = mu * np.mean([n for n, _ in pairs.values()])
    rows, rhs = [], []
    for (j, i), (n, d) in pairs.items():
        row = np.zeros(k)
        row[j], row[i] = np.sqrt(n), -np.sqrt(n)
        rows.append(row)
        rhs.append(np.sqrt(n) * d / n)
    a = np.vstack([np.array(rows), np.sqrt(lam) * np.eye(k)])
    b = np.concatenate([rhs, np.sqrt(lam) * x0])
    x = np.linalg.lstsq(a, b, rcond=None)[0]
    x += x0.mean() - x.mean()
    np.testing.assert_allclose(exposure_init.overlap_exposure(pairs, x0, mu=mu), np.exp(x), rtol=1e-7)


def test_overlap_exposure_of_a_long_strip_of_20000_images():
    """A chain of 2*10^4 images (each overlapping the next two): exposures recovered up to the free scale."""
    rng = np.random.default_rng(4)
    k = 20000
    x_true = rng.normal(size=k) * 0.3
    pairs = {}
    for j in range(k):
        for i in (j + 1, j + 2):
            if i < k:
                n = int(rng.integers(100, 5000))
                pairs[(j, i)] = (n, n * (x_true[j] - x_true[i]))
    x0 = np.zeros(k)
    t = exposure_init.overlap_exposure(pairs, x0)
    x = np.log(t)
    # mu pulls towards x0 a little; along 2*10^4 images that bends the solution by ~4e-3
    np.testing.assert_allclose(x - x.mean(), x_true - x_true.mean(), atol=1e-2)
    assert np.mean(x) == pytest.approx(0.0, abs=1e-12)


def test_tile_image_index_equals_the_all_pairs_test():
    """STRtree overlaps == the strict all-pairs rectangle test, including touching and degenerate cases."""
    from lunaralbedo.engine.scene import overlaps_per_box
    from lunaralbedo.io.rasters import intersects

    rng = np.random.default_rng(9)
    west = rng.uniform(0, 10, 400).round(1)
    south = rng.uniform(0, 10, 400).round(1)
    boxes = np.c_[west, south, west + rng.uniform(0.1, 1.5, 400).round(1), south + rng.uniform(0.1, 1.5, 400).round(1)]
    tiles = np.array([(x, y, x + 1.0, y + 1.0) for x in np.arange(0, 11.0) for y in np.arange(0, 11.0)])
    got = overlaps_per_box(boxes, tiles)
    assert len(got) == len(tiles)
    n = 0
    for t, hits in zip(tiles, got):
        want = [k for k, b in enumerate(boxes) if intersects(b, t)]
        assert hits.tolist() == want
        n += len(want)
    assert n > 1000  # the case is not trivial
    # edges that only touch do not overlap
    assert overlaps_per_box([(0, 0, 1, 1)], [(1, 0, 2, 1)])[0].size == 0


def test_row_blocks_give_the_results_of_whole_tiles(tmp_path, monkeypatch):
    """Tiles prepared and iterated in blocks of 7 rows (bounded memory) give the whole-tile results.

    Observations, per-pixel arrays and albedo do not depend on the blocks; only sums that
    cross blocks (Q, exposure and phase sums, pair sums) are added in another order, so
    exposures and albedo agree to float64 rounding carried through float32 (1e-6).
    """
    from lunaralbedo.engine.solve import solve
    from lunaralbedo.simulate import SceneSpec, render_scene

    render_scene(tmp_path / "s", SceneSpec(n_images=4, image_px=60, seed=3, max_num_iter=2, cast_shadows=True))
    runs = {}
    for name, rows in (("whole", None), ("blocks", "7")):
        res = solve(tmp_path / "s" / "settings.txt", out=tmp_path / name, workers=1, plots=False, tolerance=0.0,
                    runtime=Runtime(block_rows=int(rows) if rows else None))
        tiles = {p.parent.name + "/" + p.name: rasterio_read(p) for p in (tmp_path / name).glob("*/tile_*.tif")}
        runs[name] = (res, tiles)
    (whole, wt), (blocks, bt) = runs["whole"], runs["blocks"]
    assert len(wt) >= 8 and wt.keys() == bt.keys()
    for key in wt:
        a, b = wt[key], bt[key]
        assert np.array_equal(np.isnan(a), np.isnan(b)), key
        if key.startswith(("DEM/", "weightsSum/")):
            assert np.array_equal(a, b, equal_nan=True), key  # per-pixel: the same bytes
        else:
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7, err_msg=key)
    np.testing.assert_allclose(whole.exposure, blocks.exposure, rtol=1e-9)
    np.testing.assert_allclose(whole.cost_history, blocks.cost_history, rtol=1e-9)


def test_blocks_bound_the_rows_held(tmp_path, monkeypatch):
    """A small memory budget splits tiles into blocks; the blocks cover every row once."""
    from lunaralbedo.engine import observations
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.settings import load_settings
    from lunaralbedo.simulate import SceneSpec, render_scene

    render_scene(tmp_path / "s", SceneSpec(n_images=6, image_px=200, seed=4, tile_size=4.0))
    scene = build_scene(load_settings(tmp_path / "s" / "settings.txt"), False, map_fn=lambda f, xs: list(map(f, xs)))
    t = max(range(len(scene.tiles)), key=lambda i: len(scene.tile_images[i]))
    tile = scene.tiles[t]
    assert observations.block_rows(scene, t) == tile.height  # the default budget holds these tiles whole
    scene.runtime = Runtime(block_mb=1)
    rows = observations.block_rows(scene, t)
    width = sum(win[3] - win[2] for _, win in observations.tile_windows(scene, t) if win is not None)
    assert 1 <= rows < tile.height
    assert rows * ((tile.width + 2) * observations.ROW_PIXEL_BYTES + width * observations.WINDOW_PIXEL_BYTES) <= 2**20
    assert (rows + 1) * ((tile.width + 2) * observations.ROW_PIXEL_BYTES + width * observations.WINDOW_PIXEL_BYTES
                         + max_width(scene, tile, t) * observations.READ_PIXEL_BYTES) > 2**20  # the most that fit
    blocks = observations.row_blocks(tile.height, rows)
    assert blocks[0][0] == 0 and blocks[-1][1] == tile.height
    assert all(b[1] == c[0] for b, c in zip(blocks, blocks[1:]))


def max_width(scene, tile, t):
    from lunaralbedo.engine.observations import tile_windows

    return max(win[3] - win[2] for _, win in tile_windows(scene, t) if win is not None)


def rasterio_read(path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read(1)


def test_reading_and_reducing_ahead_caches_the_same_bytes(tmp_path, monkeypatch):
    """A prepare step that reads and reduces image windows and reorders each block on helper threads (a one-worker run
    with a CPU to spare) caches the bytes of the plain loop: blocks, initialisation sums, DEM and weight-sum tiles;
    also when the blocks are too big to be held beside the next one (reduced in the task's thread)."""
    import filecmp

    from lunaralbedo.engine import prepare
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.settings import load_settings
    from lunaralbedo.simulate import SceneSpec, render_scene

    render_scene(tmp_path / "s", SceneSpec(n_images=5, image_px=80, seed=5, cast_shadows=True))
    scene = build_scene(load_settings(tmp_path / "s" / "settings.txt"), False, map_fn=lambda f, xs: list(map(f, xs)))
    scene.runtime = Runtime(block_rows=9)
    runs = {"plain": (0, prepare.AHEAD_BYTES), "ahead": (2, prepare.AHEAD_BYTES), "ahead, big blocks": (3, 0)}
    for name, (helpers, ahead_bytes) in runs.items():
        monkeypatch.setattr(prepare, "AHEAD_BYTES", ahead_bytes)
        for t in range(len(scene.tiles)):
            prepare.prepare_tile(t, scene=scene, cache_root=tmp_path / name, helpers=helpers)
    files = sorted(p.relative_to(tmp_path / "plain") for p in (tmp_path / "plain").rglob("*") if p.is_file())
    assert sum(p.name == "weight.npy" for p in files) > 2 * len(scene.tiles)  # tiles of several blocks
    assert sum(p.name == "DEM.tif" for p in files) == len(scene.tiles)
    for name in ("ahead", "ahead, big blocks"):
        assert files == sorted(p.relative_to(tmp_path / name) for p in (tmp_path / name).rglob("*") if p.is_file())
        for p in files:
            assert filecmp.cmp(tmp_path / "plain" / p, tmp_path / name / p, shallow=False), f"{name}: {p}"


def test_windows_cut_to_the_drgs_pixels_cache_what_padded_windows_do(tmp_path, monkeypatch):
    """Windows cut to a DRG's own pixels (DRGs on the tile grid, as ingest writes them) give the observations,
    initialisation sums, DEM and weight-sum tiles of the windows padded by a pixel, which the reader filled with
    empty pixels; only the per-pixel sums' columns may be fewer."""
    import json

    from lunaralbedo.engine import observations, prepare
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.settings import load_settings
    from lunaralbedo.simulate import SceneSpec, render_scene

    render_scene(tmp_path / "s", SceneSpec(n_images=5, image_px=80, seed=7, cast_shadows=True))
    scene = build_scene(load_settings(tmp_path / "s" / "settings.txt"), False, map_fn=lambda f, xs: list(map(f, xs)))
    area = {}
    for name in ("cut", "padded"):
        if name == "padded":
            monkeypatch.setattr(observations, "pixels_on_grid", lambda *a: None)
        area[name] = sum((w[1] - w[0]) * (w[3] - w[2]) for t in range(len(scene.tiles))
                         for _, w in observations.tile_windows(scene, t) if w is not None)
        for t in range(len(scene.tiles)):
            prepare.prepare_tile(t, scene=scene, cache_root=tmp_path / name)
    assert area["cut"] < area["padded"]
    cut = sorted(p.relative_to(tmp_path / "cut") for p in (tmp_path / "cut").rglob("*") if p.is_file())
    padded = sorted(p.relative_to(tmp_path / "padded") for p in (tmp_path / "padded").rglob("*") if p.is_file())
    assert cut == padded and sum(p.name == "image.npy" for p in cut) >= len(scene.tiles)
    for p in cut:
        a, b = tmp_path / "cut" / p, tmp_path / "padded" / p
        if p.suffix == ".tif":
            assert np.array_equal(rasterio_read(a), rasterio_read(b), equal_nan=True), p
        elif p.name == "meta.json":
            ma, mb = json.loads(a.read_text()), json.loads(b.read_text())
            assert {k: v for k, v in ma.items() if k != "cols"} == {k: v for k, v in mb.items() if k != "cols"}, p
        elif not p.name.startswith("tile_"):
            assert a.read_bytes() == b.read_bytes(), p
        else:  # the same sums in the tile's columns, 0 outside the windows'
            full = []
            for root in (tmp_path / "cut", tmp_path / "padded"):
                sums = np.load(root / p)
                c0 = json.loads((root / p.parent / "meta.json").read_text()).get("cols", [0])[0]
                grid = np.zeros((sums.shape[0], scene.tiles[0].width), sums.dtype)
                grid[:, c0:c0 + sums.shape[1]] = sums
                full.append(grid)
            assert np.array_equal(*full), p
