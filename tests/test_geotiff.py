"""GeoTIFF outputs written a block of rows at a time (:class:`lunaralbedo.io.geotiff.GeoTiffRows`): the file of one
whole write, read back through GDAL, and nothing at the target unless every row was written."""
from __future__ import annotations

import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from lunaralbedo.errors import OutputError
from lunaralbedo.io.geotiff import BLOCK, GeoTiffRows, write_geotiff
from lunaralbedo.io.rasters import MOON_CRS

TR = Affine(0.01, 0, 10.0, 0, -0.01, 5.0)


def _tile(h=700, w=900):
    rng = np.random.default_rng(5)
    a = rng.normal(size=(h, w)).astype(np.float32).cumsum(1)  # smooth rows: the predictor has work
    a[rng.random((h, w)) < 0.05] = np.nan
    return a


@pytest.mark.parametrize("options", [{"nodata": float("nan")}, {"predictor": 2}, {"predictor": 1, "threads": 2}])
def test_rows_in_whole_output_blocks_give_the_bytes_of_one_write(tmp_path, options):
    a = _tile()
    write_geotiff(tmp_path / "whole.tif", a, TR, MOON_CRS, **options)
    f = GeoTiffRows(tmp_path / "rows.tif", a.shape, TR, MOON_CRS, **options)
    for r in range(0, a.shape[0], 2 * BLOCK):  # blocks of rows of 512, the last one 188
        f.write(a[r:r + 2 * BLOCK], r)
    assert not (tmp_path / "rows.tif").exists()  # renamed into place only when closed
    f.close()
    assert (tmp_path / "rows.tif").read_bytes() == (tmp_path / "whole.tif").read_bytes()


def test_rows_that_end_inside_an_output_block_read_back_the_same(tmp_path):
    """Blocks of 37 rows, written last to first: every pixel as written, the profile of one write."""
    a = _tile()
    f = GeoTiffRows(tmp_path / "rows.tif", a.shape, TR, MOON_CRS, nodata=float("nan"))
    for r in reversed(range(0, a.shape[0], 37)):
        f.write(a[r:r + 37], r)
    f.close()
    write_geotiff(tmp_path / "whole.tif", a, TR, MOON_CRS, nodata=float("nan"))
    with rasterio.open(tmp_path / "rows.tif") as got, rasterio.open(tmp_path / "whole.tif") as ref:
        np.testing.assert_array_equal(got.read(1), a)
        mine, theirs = dict(got.profile), dict(ref.profile)
        assert np.isnan(mine.pop("nodata")) and np.isnan(theirs.pop("nodata"))
        assert mine == theirs and got.transform == TR
        assert got.tags(ns="IMAGE_STRUCTURE") == ref.tags(ns="IMAGE_STRUCTURE")


def test_missing_rows_or_an_abort_leave_nothing_at_the_target(tmp_path):
    a = _tile(300, 40)
    f = GeoTiffRows(tmp_path / "t.tif", a.shape, TR, MOON_CRS)
    f.write(a[:200], 0)
    with pytest.raises(OutputError, match=r"t\.tif: 200 of 300 rows were written"):
        f.close()
    g = GeoTiffRows(tmp_path / "u.tif", a.shape, TR, MOON_CRS)
    g.write(a[:100], 0)
    g.abort()
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no file, no temporary
    with pytest.raises(ValueError, match="do not fit"):
        GeoTiffRows(tmp_path / "v.tif", a.shape, TR, MOON_CRS).write(a[:, :30], 0)
