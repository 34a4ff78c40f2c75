"""One DEM-overlap rule: where DEM files overlap, ingest and solve both average their heights (the PhotometryTK manual, section 6)."""
from __future__ import annotations

import numpy as np
import pytest
from rasterio.transform import Affine

from lunaralbedo.ingest.dem import DemMosaic, load_dems
from lunaralbedo.io.rasters import MOON_CRS, raster_info, read_dem_onto_grid
from lunaralbedo.io.geotiff import write_geotiff
from lunaralbedo.model.geometry import merge_dem_layers
from lunaralbedo.model.grid import Grid

LOW, HIGH = 100.0, 340.0  # metres: the two DEMs


@pytest.fixture
def dems(tmp_path):
    """Two 1 x 1 degree DEMs, half a degree apart in longitude: lon 10..11 at LOW, lon 10.5..11.5 at HIGH."""
    folder = tmp_path / "dem"
    for name, west, h in (("a.tif", 10.0, LOW), ("b.tif", 10.5, HIGH)):
        values = np.full((100, 100), h, np.float32)
        values[:3, :3] = -32767.0  # a no-data corner in each file
        write_geotiff(folder / name, values, Affine(0.01, 0, west, 0, -0.01, 1.0), MOON_CRS, nodata=-32767.0)
    return folder


def _regions(grid: Grid):
    """Column slices of the grid (lon 10..11.5) where only a, both, only b have heights (2 pixels from the seams)."""
    lon = grid.lonlat()[0][0]
    rows = slice(10, 90)
    return {"a": (rows, (lon > 10.02) & (lon < 10.48)), "both": (rows, (lon > 10.52) & (lon < 10.98)),
            "b": (rows, (lon > 11.02) & (lon < 11.48))}


def _check(heights, grid):
    r = _regions(grid)
    np.testing.assert_allclose(heights[r["a"][0]][:, r["a"][1]], LOW, atol=1e-3)
    np.testing.assert_allclose(heights[r["b"][0]][:, r["b"][1]], HIGH, atol=1e-3)
    np.testing.assert_allclose(heights[r["both"][0]][:, r["both"][1]], (LOW + HIGH) / 2, atol=1e-3)  # the mean
    lon = grid.lonlat()[0][0]
    assert np.isnan(heights[1, lon < 10.02]).all()  # a's no-data corner, outside b: no height
    assert np.allclose(heights[1, (lon > 10.52) & (lon < 10.53)], LOW, atol=1e-3)  # a's height where b has none


def test_ingest_averages_overlapping_dems(dems):
    """The ingest path: DemMosaic, which ingest uses for footprints, orthoprojection and DEM/dem.tif."""
    grid = Grid.from_origin(10.0, 1.0, (0.01, 0.01), (100, 150))
    _check(DemMosaic(load_dems([dems])).onto(grid), grid)
    # the order of the files does not matter
    swapped = DemMosaic(load_dems([dems / "b.tif", dems / "a.tif"])).onto(grid)
    np.testing.assert_array_equal(swapped, DemMosaic(load_dems([dems])).onto(grid))


def test_solve_averages_overlapping_dems(dems):
    """The solve path: read_dem_onto_grid, which reads the work dir's DEM tiles onto each solve tile."""
    grid = Grid.from_origin(10.0, 1.0, (0.01, 0.01), (100, 150))
    infos = [raster_info(p) for p in sorted(dems.glob("*.tif"))]
    _check(read_dem_onto_grid(infos, grid.transform, grid.shape, MOON_CRS, nodata=-32767.0), grid)


def test_the_rule_is_the_mean_of_the_dems_with_a_value():
    a = np.array([1.0, np.nan, 3.0, np.nan])
    b = np.array([5.0, 2.0, np.nan, np.nan])
    np.testing.assert_array_equal(merge_dem_layers([a, b], (4,)), [3.0, 2.0, 3.0, np.nan])
    assert np.isnan(merge_dem_layers([], (2,))).all()
    one = np.array([-0.0, 7.5, np.nan], np.float32)
    got = merge_dem_layers(iter([one]), (3,))  # one DEM: its heights, as the sum 0.0 + h gives them
    assert got.dtype == np.float64 and not np.signbit(got[0]) and got[1] == 7.5 and np.isnan(got[2])
    rng = np.random.default_rng(2)
    heights = rng.normal(0, 3000, 1000).astype(np.float32)
    heights[:3] = [-0.0, np.nan, np.float32(1e-40)]  # negative zero, no value, a subnormal
    for layers in ([heights], [heights, heights[::-1].copy()]):  # the solver asks float32: the bytes of the float64 mean
        want = merge_dem_layers(layers, (1000,)).astype(np.float32)
        got32 = merge_dem_layers(iter(layers), (1000,), np.float32)
        assert got32.dtype == np.float32 and np.array_equal(got32.view(np.uint32), want.view(np.uint32))
    # a fresh read the caller gives away (owned): the same bytes, made in place; anything else is left as it was
    want = merge_dem_layers([heights], (1000,)).astype(np.float32)
    given = heights.copy()
    owned = merge_dem_layers([given], (1000,), np.float32, owned=True)
    assert owned is given and np.array_equal(owned.view(np.uint32), want.view(np.uint32))
    kept = heights.copy()
    assert merge_dem_layers([kept], (1000,), np.float32) is not kept and np.signbit(kept[0])
    assert merge_dem_layers([heights], (1000,), np.float64, owned=True) is not heights  # another type: a new array


def test_radius_or_height_is_decided_by_the_median_of_the_finite_values():
    from lunaralbedo.model.geometry import radius_to_height

    r = 1737.4e3
    rng = np.random.default_rng(0)
    for n in range(1, 12):  # radius when more than half the finite values say so (ties: the two middle ones)
        for k in range(n + 1):
            v = np.concatenate([np.full(k, r + 100.0), np.full(n - k, 100.0), [np.nan, np.inf, -np.inf][: n % 4]])
            rng.shuffle(v)
            want = bool(np.median(v[np.isfinite(v)]) > 1e6)
            assert radius_to_height(v)[1] == want, (n, k)
    # two middle values that straddle the threshold: their mean decides
    assert radius_to_height(np.array([0.0, 2.5e6]))[1] is True
    assert radius_to_height(np.array([0.0, 1.5e6]))[1] is False
