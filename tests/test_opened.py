"""Raster files kept open across window reads (``io/opened.py``): one open per file, all closed at the end."""
from __future__ import annotations

import numpy as np
import pytest
from rasterio.transform import Affine

from lunaralbedo.io import opened, rasters
from lunaralbedo.io.geotiff import write_geotiff


@pytest.fixture()
def files(tmp_path):
    paths = []
    for k in range(4):
        p = tmp_path / f"f{k}.tif"
        write_geotiff(p, np.full((40, 30), k, np.float32), Affine(0.01, 0, k, 0, -0.01, 0), rasters.MOON_CRS)
        paths.append(p)
    return paths


def test_inside_kept_open_each_file_is_opened_once_and_closed_at_the_end(files):
    with opened.kept_open():
        with opened.open_raster(files[0]) as a:
            first = a.read(1)
        with opened.kept_open():  # nested: the outer block keeps the files
            with opened.open_raster(files[0]) as b:
                assert b is a and not b.closed
        with opened.open_raster(files[0]) as c:
            assert c is a and np.array_equal(c.read(1), first)
        assert not a.closed
    assert a.closed
    with opened.open_raster(files[1]) as d:  # outside: opened for the read and closed after it
        pass
    with opened.open_raster(files[1]) as e:
        assert e is not d
    assert d.closed and e.closed


def test_beyond_max_kept_the_least_recently_used_file_not_in_use_is_closed(files, monkeypatch):
    monkeypatch.setattr(opened, "MAX_KEPT", 2)
    with opened.kept_open():
        with opened.open_raster(files[0]) as f0:
            with opened.open_raster(files[1]) as f1:
                pass
            with opened.open_raster(files[2]) as f2:  # f0 is in use: f1 is closed instead
                assert f1.closed and not f0.closed and not f2.closed
        with opened.open_raster(files[3]) as f3:  # now f0 is the least recently used
            assert f0.closed and not f2.closed and not f3.closed
    assert f2.closed and f3.closed


def test_the_cast_shadow_dem_of_a_tile_opens_each_dem_file_once(tmp_path, monkeypatch):
    """The solver reads a tile's DEM (with its margin) in chunks of rows: each DEM file is opened once for all of
    them, so GDAL decodes each compressed block once; the heights are those of one read of the whole grid."""
    import rasterio

    from lunaralbedo.engine import terrain
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.io.rasters import read_dem_onto_grid
    from lunaralbedo.settings import load_settings
    from lunaralbedo.simulate import SceneSpec, render_scene

    render_scene(tmp_path / "s", SceneSpec(n_images=4, image_px=120, tile_size=0.25, max_num_iter=1, seed=3))
    scene = build_scene(load_settings(tmp_path / "s" / "settings.txt"), False)
    t = max(range(len(scene.tiles)), key=lambda i: len(scene.tile_images[i]))
    opens, real = [], rasterio.open
    monkeypatch.setattr(opened.rasterio, "open", lambda p, *a, **k: (opens.append(str(p)), real(p, *a, **k))[1])
    monkeypatch.setattr(terrain, "READ_ROWS", 7)  # many chunks
    shadows = terrain.TileShadows(scene, scene.tiles[t], scene.tile_images[t])
    assert shadows.dem is not None and shadows.dem.shape[0] > 5 * 7
    assert sorted(opens) == sorted(str(d.path) for d in scene.dems)  # once each
    whole = read_dem_onto_grid(scene.dems, shadows.transform, shadows.dem.shape, scene.crs,
                               scene.settings.no_dem_data_val)
    assert np.array_equal(shadows.dem, whole, equal_nan=True)


def test_open_quietly_reads_an_image_without_a_georeference_silently_and_names_a_bad_file(tmp_path):
    """``io.guard.open_quietly``: no NotGeoreferencedWarning for a Level-1 image; an unreadable file is
    one typed error naming it and what it should have been."""
    import warnings

    import rasterio

    from lunaralbedo.errors import InputError, IsisError
    from lunaralbedo.io.guard import open_quietly

    plain = tmp_path / "level1.tif"
    with rasterio.open(plain, "w", driver="GTiff", width=5, height=4, count=1, dtype="float32") as ds:
        ds.write(np.arange(20, dtype=np.float32).reshape(1, 4, 5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with open_quietly(plain) as ds:
            assert ds.read(1)[3, 4] == 19.0
    bad = tmp_path / "not_a_raster.tif"
    bad.write_bytes(b"II*\x00" + b"\x00" * 20)
    with pytest.raises(InputError, match=r"not_a_raster\.tif: cannot open DEM: "):
        with open_quietly(bad, "DEM"):
            pass
    with pytest.raises(IsisError, match="cannot open cube"):
        with open_quietly(tmp_path / "missing.cub", "cube", IsisError):
            pass
