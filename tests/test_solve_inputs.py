"""Input variants of the solve: ISIS3 cube DRGs, overlapping DEM tiles, shadow types 0-3."""
from __future__ import annotations

import shutil

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from lunaralbedo.engine.solve import solve
from lunaralbedo.io.rasters import MOON_CRS, raster_info, read_dem_onto_grid
from lunaralbedo.io.geotiff import write_geotiff
from lunaralbedo.model import shadows
from lunaralbedo.simulate import SceneSpec, render_scene, score


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    render_scene(d, SceneSpec(n_images=4, image_px=80, seed=5))
    return d


def test_isis3_cube_drgs_solve_like_geotiffs(scene, tmp_path):
    """GDAL reads ISIS3 cubes: the same DRGs as .cub give the same albedo."""
    cubes = tmp_path / "scene"
    shutil.copytree(scene, cubes)
    for tif in sorted((cubes / "DRG").glob("*.tif")):
        with rasterio.open(tif) as src:
            prof = dict(driver="ISIS3", width=src.width, height=src.height, count=2, dtype="uint8",
                        transform=src.transform, crs=src.crs)
            with rasterio.open(tif.with_suffix(".cub"), "w", **prof) as dst:
                dst.write(src.read())
        tif.unlink()
    assert raster_info(next((cubes / "DRG").glob("*.cub"))).has_alpha
    solve(scene / "settings.txt", out=tmp_path / "a", workers=1, plots=False)
    solve(cubes / "settings.txt", out=tmp_path / "b", workers=1, plots=False)
    # the cubes are presented in metres (SimpleCylindrical): reprojected back onto the degree grid,
    # the same pixels up to floating-point rounding of the grid and the data edges
    for p in sorted((tmp_path / "a" / "albedo").glob("*.tif")):
        with rasterio.open(p) as a, rasterio.open(tmp_path / "b" / "albedo" / p.name) as b:
            x, y = a.read(1), b.read(1)
        both = np.isfinite(x) & np.isfinite(y)
        assert both.sum() >= 0.97 * max(np.isfinite(x).sum(), np.isfinite(y).sum())  # edge rows may differ
        assert np.max(np.abs(x[both] / y[both] - 1)) < 1e-3
    assert score(tmp_path / "b", scene)["albedo_rel_rmse"] < 0.025


def test_overlapping_dem_tiles_are_averaged_and_nodata_honoured(tmp_path):
    t = Affine(0.1, 0, 0.0, 0, -0.1, 1.0)
    write_geotiff(tmp_path / "a.tif", np.full((10, 10), 100.0, np.float32), t, MOON_CRS, nodata=-5.0)
    b = np.full((10, 10), 300, np.int16)
    b[:, :5] = -32767  # no nodata in the file: NO_DEM_DATA_VAL applies
    write_geotiff(tmp_path / "b.tif", b, t, MOON_CRS)
    infos = [raster_info(tmp_path / "a.tif"), raster_info(tmp_path / "b.tif")]
    dem = read_dem_onto_grid(infos, t, (10, 10), MOON_CRS, nodata=-32767)
    assert np.allclose(dem[2:8, 6:9], 200.0)  # average of the overlap
    assert np.allclose(dem[2:8, 1:4], 100.0)  # only tile a has data there


def test_dynamic_shadow_mask():
    img = np.array([[10.0, 50.0]])
    r = np.array([[1.0, 1.0]])
    assert shadows.dynamic_lit(img, r, 2.0, 10.0).tolist() == [[False, True]]
    assert shadows.static_lit(img, shadows.THRESHOLD, 40).tolist() == [[False, True]]
    assert shadows.static_lit(img, shadows.NONE, 40).all()


@pytest.mark.parametrize("shadow_type, thresh", [(0, 0), (1, 40), (2, 5), (3, 5)])
def test_every_shadow_type_solves(scene, tmp_path, shadow_type, thresh):
    s = tmp_path / "s.txt"
    text = (scene / "settings.txt").read_text()
    text = text.replace("SHADOW_TYPE               1", f"SHADOW_TYPE               {shadow_type}")
    text = text.replace("SHADOW_THRESH             10", f"SHADOW_THRESH             {thresh}")
    assert f"SHADOW_TYPE               {shadow_type}\n" in text and f"SHADOW_THRESH             {thresh}\n" in text
    s.write_text(text.replace("DRG_DIR                   DRG", f"DRG_DIR {scene / 'DRG'}")
                 .replace("DEM_DIR                   DEM", f"DEM_DIR {scene / 'DEM'}").replace("meta/", f"{scene}/meta/"))
    solve(s, out=tmp_path / "o", workers=1, plots=False)
    sc = score(tmp_path / "o", scene)
    assert sc["albedo_rel_rmse"] < 0.025 and sc["exposure_max_rel_err"] < 0.01, sc
    assert sc["coverage"] > 0.9


def test_real_lola_dem_cube_reads_as_heights(realdata):
    """The real LOLA LDEM_4 cube (SimpleCylindrical metres, int16 radius with Base/Multiplier) as a solver DEM."""
    from lunaralbedo.isis.pixels import read_dem_cube

    cube = realdata / "isis" / "ldem_4_reduced.cub"
    t = Affine(0.5, 0, 0.0, 0, -0.5, 10.0)  # 0.5-degree grid over lon 0..10, lat 0..10
    dem = read_dem_onto_grid([raster_info(cube)], t, (20, 20), MOON_CRS, nodata=-32768)
    assert np.isfinite(dem).all()
    assert -10000 < dem.min() and dem.max() < 10000  # heights, not radii
    heights, ct, ccrs, was_radius = read_dem_cube(cube)  # ingest's reader of the same cube
    assert was_radius
    from rasterio.warp import transform

    xs, ys = transform(MOON_CRS, ccrs, [2.75], [7.25])  # centre of grid pixel (5, 5), in the cube's metres
    col, row = ~ct @ (xs[0], ys[0])
    # bilinear between the cube's pixel centres, as GDAL's warper samples it
    x, y = col - 0.5, row - 0.5
    c0, r0 = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - c0, y - r0
    h = heights[r0:r0 + 2, c0:c0 + 2]
    expect = (h[0, 0] * (1 - fx) + h[0, 1] * fx) * (1 - fy) + (h[1, 0] * (1 - fx) + h[1, 1] * fx) * fy
    assert dem[5, 5] == pytest.approx(expect, abs=1.0)
