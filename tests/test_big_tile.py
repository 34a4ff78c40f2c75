"""A tile many times bigger than its images (TILE_SIZE 16 degrees at 0.001 degree/px: 16 000 x 16 000 px, under a
strip of ~130 x 64 px) costs what the images' footprint costs, not what the tile's area would: the prepare step
reads the DEM (terrain, geometry, cast shadows) only around the images, and the albedo is that of the same scene
solved with a tile of normal size."""
from __future__ import annotations

import time

import numpy as np
import pytest
import rasterio

from lunaralbedo.engine import observations, terrain
from lunaralbedo.engine.solve import solve
from lunaralbedo.simulate import SceneSpec, render_scene

SPEC = SceneSpec(n_images=3, image_px=64, res_deg=0.001, lon0=1.1, lat0=1.1, tile_size=0.5, max_num_iter=3,
                 dem_relief_m=300.0, sun_incidence_deg=60.0, seed=3)


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    d = tmp_path_factory.mktemp("bigtile")
    render_scene(d, SPEC)
    text = (d / "settings.txt").read_text()
    assert "TILE_SIZE" in text and "CAST_SHADOWS" in text  # cast shadows on (the default): their DEM is read too
    big = d / "settings_big.txt"
    big.write_text("\n".join("TILE_SIZE 16" if line.startswith("TILE_SIZE") else line for line in text.splitlines()))
    return d


def _counting(monkeypatch, module, counts):
    real = module.read_dem_onto_grid

    def read(dems, transform, shape, *args, **kwargs):
        counts.append(int(shape[0]) * int(shape[1]))
        return real(dems, transform, shape, *args, **kwargs)

    monkeypatch.setattr(module, "read_dem_onto_grid", read)


def _solve(settings, out):
    counts: list[int] = []
    with pytest.MonkeyPatch.context() as monkeypatch:
        for module in (observations, terrain):  # every DEM read of the prepare step (terrain, geometry, cast shadows)
            _counting(monkeypatch, module, counts)
        t0 = time.perf_counter()
        solve(settings, out=out, workers=1, plots=False)
    return time.perf_counter() - t0, sum(counts)


@pytest.fixture(scope="module")
def solved(strip, tmp_path_factory):
    root = tmp_path_factory.mktemp("bigtile_out")
    normal = _solve(strip / "settings.txt", root / "normal")
    big = _solve(strip / "settings_big.txt", root / "big")
    return root, normal, big


def test_a_tile_far_bigger_than_its_images_costs_their_footprint(solved):
    tmp_path, (t_normal, px_normal), (t_big, px_big) = solved
    # the whole 16 000 x 16 000 px tile read once would be 2.6e8 px; the normal 500 x 500 px tile reads ~3e5
    assert px_big < 10 * px_normal, (px_big, px_normal)
    assert t_big < 3 * t_normal + 5.0, (t_big, t_normal)
    (normal,) = (tmp_path / "normal" / "albedo").glob("*.tif")
    (big,) = (tmp_path / "big" / "albedo").glob("*.tif")
    with rasterio.open(normal) as a, rasterio.open(big) as b:
        assert (b.width, b.height) == (16000, 16000)
        col, row = (round(v) for v in ~b.transform @ (a.transform.c, a.transform.f))  # the normal tile's corner in big
        small = a.read(1)
        part = b.read(1, window=rasterio.windows.Window(col, row, a.width, a.height))
        outside = np.count_nonzero(np.isfinite(b.read(1, window=rasterio.windows.Window(0, 0, 2048, 2048))))
    assert np.count_nonzero(np.isfinite(small)) > 5000
    np.testing.assert_array_equal(np.isfinite(part), np.isfinite(small))  # the same pixels have an albedo ...
    np.testing.assert_array_equal(part, small)  # ... the same one (the same observations, sums in the same order)
    assert outside == 0  # far from the images: no-data


def test_export_of_a_tile_far_bigger_than_its_data_reads_only_its_data(solved, monkeypatch):
    """export-kml of the 16 000 x 16 000 px tile (2.6e8 px, 1 GB as float32; a real NAC crop in one
    121 294 px tile would be 59 GB) reads only the tile's written blocks and the data's window, and
    writes the same products as the normal tile."""
    from lunaralbedo.export import api, extent, sources

    read: list[int] = []
    real = sources.read_masked

    def counting(ds, window=None, legacy=None):
        vals = real(ds, window, legacy)
        read.append(vals.size)
        return vals

    for module in (sources, extent):
        monkeypatch.setattr(module, "read_masked", counting)
    root = solved[0]
    results = {}
    for name in ("normal", "big"):
        read.clear()
        results[name] = api.export_kml(root / name, workers=1)
        results[name]["read"] = sum(read)
    assert results["big"]["read"] < 4 * results["normal"]["read"] + 2 * 256 * 256, results  # not 2.6e8
    for product in ("albedo_mosaic.tif", "error_mosaic.tif"):
        with rasterio.open(root / "normal" / product) as a, rasterio.open(root / "big" / product) as b:
            assert a.shape == b.shape and np.allclose(a.bounds, b.bounds, rtol=0, atol=1e-9)
            np.testing.assert_array_equal(a.read(1), b.read(1))
    (small,) = (root / "normal" / "albedo_sub4").glob("*.tif")
    (big,) = (root / "big" / "albedo_sub4").glob("*.tif")
    with rasterio.open(small) as a, rasterio.open(big) as b:  # both cropped to the data: the same 1/4 grid
        assert a.shape == b.shape and np.allclose(a.bounds, b.bounds, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(a.read(1), b.read(1))
