"""Cast shadows of a tile too big to hold its DEM whole (:class:`lunaralbedo.engine.terrain.TileShadows`, banded):
the same margin, DEM rows and answers as the whole tile's, block of rows by block, and the same solve."""
from __future__ import annotations

from lunaralbedo.runtime import Runtime
import numpy as np
import pytest
import rasterio

from lunaralbedo.engine import terrain
from lunaralbedo.engine.scene import build_scene
from lunaralbedo.engine.solve import solve
from lunaralbedo.settings import load_settings
from lunaralbedo.simulate import SceneSpec, render_scene

from test_solve_low_sun import LOW_SUN


@pytest.fixture(scope="module")
def low_sun(tmp_path_factory):
    d = tmp_path_factory.mktemp("bands")
    render_scene(d, SceneSpec(**{**LOW_SUN, "n_images": 4}))
    return d


def _shadows(band, tile, k, b0, b1):
    rows, cols = np.divmod(np.arange((b1 - b0) * tile.width), tile.width)
    return band.shadowed(k, rows, cols, b0, 0)


def test_a_banded_tile_gives_the_whole_tiles_margin_rows_and_shadows(low_sun, monkeypatch):
    monkeypatch.setattr(terrain, "READ_ROWS", 13)  # the margin found from many chunks ...
    monkeypatch.setattr(terrain, "FIRST_MARGIN_PX", 2)  # ... and widened (the frames read again)
    scene = build_scene(load_settings(low_sun / "settings.txt"), False)
    t = max(range(len(scene.tiles)), key=lambda i: len(scene.tile_images[i]))
    tile, images = scene.tiles[t], scene.tile_images[t]
    whole = terrain.TileShadows(scene, tile, images, banded=False)
    banded = terrain.TileShadows(scene, tile, images, banded=True)
    assert banded.banded and banded.dem is None and not whole.banded and whole.dem is not None
    assert banded.margin == whole.margin > terrain.FIRST_MARGIN_PX  # widened: a margin found, not the first guess
    cuts = [0, tile.height // 3, tile.height // 3 + 1, tile.height]  # a one-row block too
    shadowed = 0
    for b0, b1 in zip(cuts[:-1], cuts[1:]):
        band = banded.for_rows(b0, b1)
        assert band.dem.shape == (b1 - b0 + 2 * whole.margin, tile.width + 2 * whole.margin)
        np.testing.assert_array_equal(band.rows(b0 - 1, b1 + 1, -1, tile.width + 1),
                                      whole.rows(b0 - 1, b1 + 1, -1, tile.width + 1))
        for k in images:
            got = _shadows(band, tile, k, b0, b1)
            np.testing.assert_array_equal(got, _shadows(whole, tile, k, b0, b1))
            shadowed += int(got.sum())
    assert shadowed > 200  # a low Sun: shadows to get right
    # control: a band without the margin cuts the rays that cross into other rows, and answers differently
    banded.margin = 2
    assert any((_shadows(banded.for_rows(b0, b1), tile, k, b0, b1) != _shadows(whole, tile, k, b0, b1)).any()
               for b0, b1 in zip(cuts[:-1], cuts[1:]) for k in images)


def test_a_solve_with_banded_tiles_writes_the_same_tiles(low_sun, tmp_path, monkeypatch):
    rt = Runtime(block_rows=37)  # several blocks per tile, in both runs
    solve(low_sun / "settings.txt", out=tmp_path / "whole", workers=1, plots=False, runtime=rt)
    monkeypatch.setattr(terrain, "WHOLE_DEM_BYTES", 0)  # every tile banded
    seen = []
    real = terrain.TileShadows.for_rows
    monkeypatch.setattr(terrain.TileShadows, "for_rows", lambda self, b0, b1: (seen.append(self.banded), real(self, b0, b1))[1])
    solve(low_sun / "settings.txt", out=tmp_path / "banded", workers=1, plots=False, runtime=rt)
    assert seen and all(seen)
    names = sorted(p.relative_to(tmp_path / "whole") for kind in ("albedo", "error", "DEM", "weightsSum")
                   for p in (tmp_path / "whole" / kind).glob("*.tif"))
    assert len(names) >= 8
    for name in names:
        with rasterio.open(tmp_path / "whole" / name) as a, rasterio.open(tmp_path / "banded" / name) as b:
            np.testing.assert_array_equal(a.read(), b.read(), err_msg=str(name))
