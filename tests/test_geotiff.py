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
        GeoTiffRows(tmp_path / "v.tif", a.shape, TR, MOON_CRS).write(a[:, :30], 0, col0=20)


def _sparse_tile():
    """A 700 x 900 px tile whose 256 px blocks are: data, all NaN (the no-data value), all NaN but one pixel of
    another NaN payload, all NaN but one finite pixel."""
    a = _tile()
    a[:256, 256:512] = np.nan  # empty
    a[256:512, :768] = np.nan  # empty, empty, and ...
    a[300, 600] = np.frombuffer(np.uint32(0xFFC00001).tobytes(), np.float32)[0]  # ... a NaN of other bits
    a[512:, 512:768] = np.nan
    a[600, 700] = 1.5  # not empty
    return a


def test_blocks_of_no_data_only_are_left_to_gdal_with_the_same_bits(tmp_path):
    """Blocks holding nothing but the bits GDAL fills a block never written with are not written; the file reads back
    bit for bit (other NaN payloads, -0.0 against 0), the same for rows written in whole blocks as for one write."""
    from lunaralbedo.io.geotiff import empty_blocks, fill_bits

    a = _sparse_tile()
    fill = fill_bits(np.float32, float("nan"))
    assert fill == 0x7FC00000
    assert empty_blocks(a[None, :256], fill).tolist() == [False, True, False, False]
    assert empty_blocks(a[None, 256:512], fill).tolist() == [True, True, False, False]  # the other NaN: block 2
    assert empty_blocks(a[None, 512:], fill).tolist() == [False, False, False, False]
    write_geotiff(tmp_path / "whole.tif", a, TR, MOON_CRS, nodata=float("nan"))
    f = GeoTiffRows(tmp_path / "rows.tif", a.shape, TR, MOON_CRS, nodata=float("nan"))
    for r in range(0, a.shape[0], BLOCK):
        f.write(a[r:r + BLOCK], r)
    f.close()
    assert (tmp_path / "rows.tif").read_bytes() == (tmp_path / "whole.tif").read_bytes()
    with rasterio.open(tmp_path / "whole.tif") as ds:
        assert all(ds.block_size(1, i, j) > 0 for i in range(3) for j in range(4))  # every block present: not sparse
        np.testing.assert_array_equal(ds.read(1).view(np.uint32), a.view(np.uint32))
    z = np.zeros((300, 600), np.float32)  # no no-data value: GDAL fills with 0.0; a block of -0.0 is written
    z[:256, 256:512] = -0.0
    z[280, 10] = 2.0
    assert empty_blocks(z[None, :256], fill_bits(np.float32, None)).tolist() == [True, False, True]
    write_geotiff(tmp_path / "z.tif", z, TR, MOON_CRS, predictor=2)
    with rasterio.open(tmp_path / "z.tif") as ds:
        np.testing.assert_array_equal(ds.read(1).view(np.uint32), z.view(np.uint32))
    # a no-data value the dtype cannot hold exactly: GDAL would round or clamp it, so no block is left to GDAL
    assert fill_bits(np.uint8, -32768) is None and fill_bits(np.float32, 0.1) is None
    assert fill_bits(np.int16, -32767.0) == 0x8001 and fill_bits(np.uint8, 255) == 255
    t = np.full((300, 300), np.float32(0.1))
    t[280, 10] = 2.0
    write_geotiff(tmp_path / "t.tif", t, TR, MOON_CRS, nodata=0.1)
    with rasterio.open(tmp_path / "t.tif") as ds:
        np.testing.assert_array_equal(ds.read(1).view(np.uint32), t.view(np.uint32))
    d = np.zeros((2, 520, 300), np.uint8)  # two bands: a block is empty only when both are
    d[1, 10:20, 10:20] = 255
    d[0, 300:, 290] = 7
    write_geotiff(tmp_path / "d.tif", d, TR, MOON_CRS)
    with rasterio.open(tmp_path / "d.tif") as ds:
        np.testing.assert_array_equal(ds.read(), d)


def test_the_empty_blocks_are_not_handed_to_gdal(tmp_path):
    """The windows written into a real GeoTIFF skip exactly the empty blocks of rows covered whole; rows that end
    inside a block of the file are written whole (GDAL must merge them with the block's other rows)."""
    from lunaralbedo.io.geotiff import geotiff_profile, write_rows

    a = _sparse_tile()
    prof = geotiff_profile(1, *a.shape, "float32", TR, MOON_CRS, nodata=float("nan"))

    class Recorder:  # the real dataset, its writes' windows noted
        def __init__(self, ds):
            self.ds, self.windows = ds, []

        def __getattr__(self, name):
            return getattr(self.ds, name)

        def write(self, arr, window):
            self.windows.append((int(window.row_off), int(window.col_off), int(window.height), int(window.width)))
            self.ds.write(arr, window=window)

    with rasterio.open(tmp_path / "t.tif", "w", **prof) as ds:
        rec = Recorder(ds)
        write_rows(rec, a[None, :600], 0)  # blocks of rows 0 and 1 whole, then rows 512:600 of block 2
        write_rows(rec, a[None, 600:], 600)  # the rest of block 2: not whole, written as is
    assert rec.windows == [(0, 0, 256, 256), (0, 512, 256, 388), (256, 512, 256, 388), (512, 0, 88, 900),
                           (600, 0, 100, 900)]
    with rasterio.open(tmp_path / "t.tif") as ds:
        np.testing.assert_array_equal(ds.read(1).view(np.uint32), a.view(np.uint32))
