"""Footprints, SIMULATION_BOX and tiles across the ±180° meridian (issue 14).

End to end: a forward-model strip centred on 180° E (some DRG files at -180..-179, the
box written ``179:-179``) is solved and exported as well as the same strip at 0° E;
ingest's footprint box and DEM grid stay continuous across 180°.
"""
from __future__ import annotations

import re

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import Affine

from lunaralbedo.cli import main
from lunaralbedo.engine.tiles import make_tiles
from lunaralbedo.ingest.dem import DemMosaic, load_dems
from lunaralbedo.ingest.run import _box, union_box
from lunaralbedo.io.rasters import MOON_CRS
from lunaralbedo.io.geotiff import write_geotiff
from lunaralbedo.model.longitude import continuous_span, overlap_shifts, union_span
from lunaralbedo.simulate import SceneSpec, render_scene, score


@pytest.mark.parametrize(
    "lon, base, span",
    [
        ([10.0, 12.0, 11.0], -180.0, (10.0, 12.0)),  # no wrap: plain min/max
        ([179.5, 179.9, -179.8, -179.6], -180.0, (179.5, 180.4)),
        ([-179.6, 179.5], -180.0, (179.5, 180.4)),
        ([359.5, 0.4, 0.1], 0.0, (359.5, 360.4)),  # a 0..360 DEM: the cut at 0/360
        ([359.5, 0.4, np.nan], -180.0, (-0.5, 0.4)),
    ],
)
def test_continuous_span_of_footprint_longitudes(lon, base, span):
    assert continuous_span(lon, base) == pytest.approx(span)


def test_union_and_overlap_across_the_antimeridian():
    assert union_span([(179.2, 179.9), (-179.9, -179.1)]) == pytest.approx((179.2, 180.9))
    assert union_span([(10.0, 12.0), (-5.0, 1.0)]) == pytest.approx((-5.0, 12.0))
    # a DRG whose file says -180..-179 meets the tile 180..181 after +360
    assert overlap_shifts((-180.0, -1.0, -179.0, 1.0), (180.0, -1.0, 181.0, 1.0)) == [360.0]
    assert overlap_shifts((179.0, -1.0, 181.0, 1.0), (-181.0, -1.0, -180.5, 1.0)) == [-360.0]
    assert overlap_shifts((10.0, -1.0, 11.0, 1.0), (10.5, -1.0, 12.0, 1.0)) == [0.0]
    assert overlap_shifts((10.0, -1.0, 11.0, 1.0), (10.5, 2.0, 12.0, 3.0)) == []  # latitudes apart


def test_tiles_across_180_are_continuous_and_named_in_minus_180_to_180():
    tiles = make_tiles((178.5, 181.5, -0.5, 0.5), 1.0, (0.01, 0.01))
    assert [t.west for t in tiles[:4]] == [178.0, 179.0, 180.0, 181.0]
    assert [t.name for t in tiles[:4]] == ["tile_178E1N", "tile_179E1N", "tile_180W1N", "tile_179W1N"]
    assert len({t.name for t in tiles}) == len(tiles) == 8


def test_ingest_footprint_across_180_gives_a_narrow_grid_with_dem_heights(tmp_path):
    """A footprint from 179.6 E to 179.7 W on a global -180..180 DEM: a 0.7-degree grid, heights continuous."""
    res = 0.25
    lon_c = np.arange(-180 + res / 2, 180, res)
    lat_c = np.arange(90 - res / 2, -90, -res)
    dem = (1000.0 * np.cos(np.radians(lon_c))[None, :] * np.cos(np.radians(lat_c))[:, None]).astype(np.float32)
    write_geotiff(tmp_path / "dem.tif", dem, Affine(res, 0, -180, 0, -res, 90), MOON_CRS)
    mosaic = DemMosaic(load_dems([tmp_path / "dem.tif"]))
    lon = np.array([179.6, 179.8, 179.95, -179.9, -179.7, -179.8, 179.7, np.nan])
    lat = np.array([0.3, 0.35, 0.3, 0.2, -0.2, -0.3, -0.25, 0.0])
    box = _box(lon, lat)
    assert box == pytest.approx((179.6, -0.3, 180.3, 0.35))
    grid = mosaic.base_grid(box)
    w, s, e, n = grid.bounds
    assert (w, e) == pytest.approx((179.5, 180.5)) and grid.shape[1] == 4  # DEM-aligned, not 360 degrees wide
    h = mosaic.onto(grid)
    lon_g, lat_g = grid.lonlat()
    # the cosine field is continuous across 180: the samples east of it come from the DEM's west edge
    expected = 1000.0 * np.cos(np.radians(lon_g)) * np.cos(np.radians(lat_g))
    assert np.isfinite(h).all()
    assert np.abs(h - expected).max() < 1.0  # metres (bilinear on a 0.25-degree grid)
    # two cubes on either side of the meridian: one continuous SIMULATION_BOX
    assert union_box([box, (-179.9, -0.5, -179.2, 0.1)]) == pytest.approx((179.6, -0.5, 180.8, 0.35))


def _run(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def _strip(root, lon_center, wrap):
    d = root / f"scene{lon_center:g}"
    render_scene(d, SceneSpec.centred(lon_center, 0.0, n_images=4, image_px=80, seed=11, wrap_lon=wrap))
    return d


def test_scene_on_180E_solves_and_exports_like_the_same_scene_on_0E(tmp_path):
    east0, am = _strip(tmp_path, 0.0, False), _strip(tmp_path, 180.0, True)
    assert "SIMULATION_BOX            179:-179:" in (am / "settings.txt").read_text()
    with rasterio.open(am / "DRG" / "SIM-IMG-003_drg.tif") as ds:
        assert ds.bounds.left == pytest.approx(-179.8)  # this DRG's file longitudes are in -180..180
    scores = {}
    for d in (east0, am):
        _run("solve", d / "settings.txt", "-o", d / "out", "--workers", "1")
        scores[d] = score(d / "out", d)
    s0, s180 = scores[east0], scores[am]
    assert s180["images_compared"] == 4 and s180["coverage"] == pytest.approx(s0["coverage"])
    assert s180["albedo_rel_rmse"] < 0.025 and s180["albedo_rel_rmse"] < 1.25 * s0["albedo_rel_rmse"], (s0, s180)
    assert s180["exposure_max_rel_err"] < 0.01, (s0, s180)
    names = sorted(p.name for p in (am / "out" / "albedo").glob("*.tif"))
    assert names == ["tile_179E0N.tif", "tile_179E1N.tif", "tile_180W0N.tif", "tile_180W1N.tif"]
    with rasterio.open(am / "out" / "albedo" / "tile_180W0N.tif") as ds:
        assert ds.bounds.left == pytest.approx(180.0) and np.isfinite(ds.read(1)).mean() > 0.3
    _run("export-kml", am / "out", "--workers", "1")
    kml = (am / "out" / "kml" / "doc.kml").read_text()
    box = {k: float(re.search(f"<{k}>([-0-9.e]+)</{k}>", kml).group(1)) for k in ("west", "east", "south", "north")}
    assert box["west"] == pytest.approx(179.01) and box["east"] == pytest.approx(180.99)  # continuous, 1.98 deg wide
    assert box["south"] == pytest.approx(-0.39) and box["north"] == pytest.approx(0.39)
    with rasterio.open(am / "out" / "albedo_mosaic.tif") as ds:
        assert ds.bounds.left == pytest.approx(179.01) and ds.bounds.right == pytest.approx(180.99)
