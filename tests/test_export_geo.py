"""export-kml geometry: the ±180° meridian, the poles, the pyramid layout, and the
PhotometryTK settings-1 gold result (legacy uint8 + alpha tiles)."""
from __future__ import annotations

import shutil
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import rasterio
from rio_cogeo.cogeo import cog_validate

from lunaralbedo.export import export_kml
from lunaralbedo.export.tiling import merge_children
from lunaralbedo.export.pyramid import plan_pyramid
from lunaralbedo.export.sources import longitude_shifts
from test_export_common import albedo_fn, kml_vs_albedo, make_result, pixel_centres, sample_tiles

KML_NS = {"k": "http://www.opengis.net/kml/2.2"}


def _all_boxes(kml_dir):
    """Every (west, south, east, north) written in any LatLonBox / LatLonAltBox of the tree."""
    boxes = []
    for path in kml_dir.rglob("*.kml"):
        for tag in ("LatLonBox", "LatLonAltBox"):
            for box in ET.parse(path).getroot().iter(f"{{{KML_NS['k']}}}{tag}"):
                boxes.append(tuple(float(box.find(f"k:{s}", KML_NS).text) for s in ("west", "south", "east", "north")))
    return boxes


@pytest.mark.parametrize(
    "intervals, shifts",
    [
        ([(0, 4), (4, 8)], [0, 0]),
        ([(176, 180), (-180, -176)], [0, 360]),
        ([(-180, -176), (176, 180.0134)], [360, 0]),  # legacy tiles overshoot their east edge
        ([(180, 184)], [-360]),
        ([(350, 354), (354, 358)], [-360, -360]),
        ([(-180 + 4 * i, -176 + 4 * i) for i in range(90)], [0] * 90),  # the whole Moon: no cut needed
        ([(170, 174), (-100, -96), (178, 182)], [0, 360, 0]),  # cut in the widest gap (-96..170)
    ],
)
def test_longitude_shifts_make_one_continuous_range(intervals, shifts):
    assert longitude_shifts(intervals) == shifts


def test_pyramid_layout():
    pyr = plan_pyramid((0.0, -8.0, 12.0, 0.0), (400, 600), 256)
    assert (pyr.levels, pyr.root_width, pyr.root_height) == (3, 150, 100)
    assert [pyr.level_counts(k) for k in range(3)] == [(1, 1), (1, 2), (2, 3)]
    for k in range(3):
        rows, cols = pyr.level_counts(k)
        nodes = [[pyr.node(k, c, r) for c in range(cols)] for r in range(rows)]
        assert sum(n.width for n in nodes[0]) == 150 << k and sum(row[0].height for row in nodes) == 100 << k
        for r in range(rows):
            for c in range(cols):
                b = nodes[r][c].bounds
                if c + 1 < cols:
                    assert b[2] == nodes[r][c + 1].bounds[0]  # neighbours share their edge exactly
                if r + 1 < rows:
                    assert b[1] == nodes[r + 1][c].bounds[3]
        assert nodes[0][0].bounds[:1] == (0.0,) and nodes[-1][-1].bounds[1:3] == (-8.0, 12.0)
    fewer = plan_pyramid((0.0, -8.0, 12.0, 0.0), (400, 600), 256, levels=2)  # coarser than native
    assert fewer.level_shape(1) == (342, 512)


def test_tiles_across_the_antimeridian(tmp_path):
    root = make_result(tmp_path, [(172, 4), (176, 4), (-180, 4), (-176, 4)], n=100)
    summary = export_kml(root, workers=2)
    assert summary["longitude_shifted"] and summary["levels"] == 2
    worst, alpha_ok, facts, rgba = kml_vs_albedo(root)
    assert facts["bounds"] == pytest.approx((172.0, 0.0, 188.0, 4.0), abs=1e-9)
    assert (facts["width"], facts["height"]) == (400, 100)
    assert worst == 0 and alpha_ok and (rgba[3] == 255).all()  # no seam, no gap at 180
    with rasterio.open(root / "albedo_mosaic.tif") as ds:
        assert tuple(ds.bounds) == pytest.approx((172.0, 0.0, 188.0, 4.0))
        lon, lat = pixel_centres(ds.transform, ds.height, ds.width)
        np.testing.assert_allclose(ds.read(1), albedo_fn(lon, lat), atol=1e-6)
    boxes = _all_boxes(root / "kml")
    assert min(b[0] for b in boxes) == 172.0 and max(b[2] for b in boxes) == 188.0


def test_tiles_reaching_the_north_pole(tmp_path):
    root = make_result(tmp_path, [(0, 90), (4, 90), (8, 90)], n=100)
    export_kml(root, tile_size=64, workers=2)
    worst, alpha_ok, facts, rgba = kml_vs_albedo(root)
    assert facts["bounds"] == pytest.approx((0.0, 86.0, 12.0, 90.0), abs=1e-9)
    assert worst == 0 and alpha_ok and (rgba[3] == 255).all()
    assert max(b[3] for b in _all_boxes(root / "kml")) == 90.0


def test_tiles_overshooting_the_south_pole_are_clipped(tmp_path):
    # legacy-style tiles: 95 px of 0.0422 deg, so the last row ends at -90.0134
    root = make_result(tmp_path, [(0, -86), (4, -86)], n=95, size=95 * 0.04224640792195306)
    summary = export_kml(root, tile_size=64, workers=2)
    worst, alpha_ok, facts, _ = kml_vs_albedo(root)
    assert facts["bounds"][1] == -90.0 and facts["bounds"][3] == -86.0
    assert worst == 0 and alpha_ok
    assert min(b[1] for b in _all_boxes(root / "kml")) == -90.0
    assert summary["bounds"][1] == -90.0
    assert cog_validate(str(root / "albedo_mosaic.tif"))[0]


@pytest.fixture()
def gold_result(photk_tests, tmp_path):
    """A RESULTS_DIR whose albedo/ is a copy of PhotometryTK's settings-1 gold albedo (uint8 + alpha)."""
    gold = photk_tests / "albedo_gold_1"
    root = tmp_path / "albedo_gold_1"
    shutil.copytree(gold / "albedo", root / "albedo")
    for p in root.rglob("*"):
        p.chmod(0o644)
    return gold, root


@pytest.mark.parametrize("levels, size", [(None, (190, 95)), (3, (192, 96))])
def test_photometrytk_gold_result(gold_result, levels, size):
    gold, root = gold_result
    summary = export_kml(root, levels=levels, workers=2)
    # bounds = union of tile_4E8S and tile_8E8S (legacy tiles overlap by a third of a pixel)
    west, north = 4.0, -8.0
    east = 8.0 + 95 * 0.04224640792195306
    south = -8.0 - 95 * 0.042233358662328274
    worst, alpha_ok, facts, rgba = kml_vs_albedo(root)
    assert facts["bounds"] == pytest.approx((west, south, east, north), abs=1e-9)
    assert (facts["width"], facts["height"]) == size
    assert worst == 0 and alpha_ok  # stretched gold values, and its alpha, exactly
    assert 0 < (rgba[3] == 0).sum() < 200  # the gold has a few no-data pixels
    with rasterio.open(root / "albedo" / "tile_4E8S.tif") as a, rasterio.open(root / "albedo" / "tile_8E8S.tif") as b:
        vals = np.concatenate([x.read(1)[x.read(2) > 0] for x in (a, b)]).astype(float)
    assert (summary["stretch"]["lo"], summary["stretch"]["hi"]) == tuple(np.percentile(vals, [2, 98]))
    valid, errors, _ = cog_validate(str(root / "albedo_mosaic.tif"))
    assert valid, errors
    with rasterio.open(root / "albedo_mosaic.tif") as ds:
        assert (ds.width, ds.height) == (190, 95)
        lon, lat = pixel_centres(ds.transform, ds.height, ds.width)
        np.testing.assert_array_equal(ds.read(1), sample_tiles(root / "albedo", lon, lat).astype(np.float32))


def test_photometrytk_gold_sub4(gold_result):
    gold, root = gold_result
    export_kml(root, levels=1, workers=1, sub4_resampling="nearest")
    for name in ("tile_4E8S.tif", "tile_8E8S.tif"):
        with rasterio.open(root / "albedo_sub4" / name) as ours, rasterio.open(gold / "albedo_sub4" / name) as ref:
            assert (ours.width, ours.height, ours.count, ours.dtypes[0]) == (23, 23, 2, "uint8")
            assert tuple(ours.bounds) == pytest.approx(tuple(ref.bounds), abs=1e-12)
            np.testing.assert_array_equal(ours.read(), ref.read())  # PhotometryTK's sub4, pixel for pixel
    export_kml(root, levels=1, workers=1)  # default: average of the valid pixels
    with rasterio.open(root / "albedo_sub4" / "tile_4E8S.tif") as ours, rasterio.open(root / "albedo" / "tile_4E8S.tif") as full:
        assert (ours.width, ours.height) == (23, 23)
        assert abs(ours.read(1).astype(float).mean() - full.read(1).astype(float).mean()) < 1.0


def test_coarser_levels_are_count_weighted_means_of_the_finest_level():
    # uneven edges (13 x 7 root, 16-px tiles) and holes: every level must equal the
    # mean of the valid finest-level pixels below each of its pixels
    t = 16
    pyr = plan_pyramid((0.0, 0.0, 10.0, 6.0), (56, 104), tile_size=t, levels=4)
    assert (pyr.root_width, pyr.root_height) == (13, 7)
    assert [pyr.level_counts(k) for k in range(4)] == [(1, 1), (1, 2), (2, 4), (4, 7)]
    rng = np.random.default_rng(1)
    finest = rng.random(pyr.level_shape(3))
    finest[rng.random(finest.shape) < 0.3] = np.nan
    finest[:16, :32] = np.nan  # two whole tiles without data
    results = {}
    for level in range(3, -1, -1):
        rows, cols = pyr.level_counts(level)
        for r in range(rows):
            for c in range(cols):
                node = pyr.node(level, c, r)
                if level == 3:
                    vals = finest[r * t:r * t + node.height, c * t:c * t + node.width].astype(np.float32)
                    results[node.key] = (vals, np.isfinite(vals).astype(np.float32))
                else:
                    kids = [pyr.node(*k) for k in pyr.children(node)]
                    results[node.key] = merge_children(node, kids, [results[k.key] for k in kids])
        f = 1 << (3 - level)
        h, w = pyr.level_shape(level)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            want = np.nanmean(finest.reshape(h, f, w, f).transpose(0, 2, 1, 3).reshape(h, w, -1), axis=2)
        got = np.full((h, w), np.nan)
        for r in range(rows):
            for c in range(cols):
                vals, _ = results[(level, c, r)]
                got[r * t:r * t + vals.shape[0], c * t:c * t + vals.shape[1]] = vals
        np.testing.assert_allclose(got, want, rtol=1e-5)


@pytest.mark.parametrize(
    "corners, n, size",
    [
        ([(0, 0), (4, 0), (0, -4)], 50, 4.0),  # L-shape with a missing tile
        ([(176, 4), (-180, 4)], 40, 4.0),  # across ±180° (shifted tile)
        ([(0, -86)], 95, 95 * 0.04224640792195306),  # overshooting the south pole
    ],
)
def test_exact_copy_equals_gdal_nearest(tmp_path, corners, n, size):
    from rasterio.enums import Resampling

    from lunaralbedo.export.sources import find_sources, native_grid, pixel_offset, read_region
    from lunaralbedo.model.grid import Grid

    make_result(tmp_path, corners, n=n, size=size)
    sources = find_sources(tmp_path / "albedo")
    grid = native_grid(sources)
    w, s, e, nn = grid.bounds
    dx, dy = (e - w) / grid.width, (nn - s) / grid.height
    grids = [grid] + [  # aligned sub-grids, some reaching past the data
        Grid.from_bounds((w + c * dx, nn - (r + h) * dy, w + (c + wd) * dx, nn - r * dy), h, wd)
        for r, c, h, wd in [(0, 0, 7, 9), (3, 5, 40, 33), (grid.height - 10, grid.width - 12, 10, 12), (10, 30, 30, 30)]
    ]
    for g in grids:
        fast = read_region(sources, g, Resampling.nearest)
        slow = read_region(sources, g, Resampling.nearest, exact_copy=False)
        np.testing.assert_array_equal(fast, slow)
    aligned = [pixel_offset(src, grid.transform) is not None for src in sources]
    assert aligned == [size == 4.0] * len(sources)  # the legacy-sized tile goes through GDAL's warper
