"""Legacy mode: pure conventions (grid, weights, interpolation) and bad input, on synthetic data."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from lunaralbedo.errors import InputError, MissingPositionError, SettingsError, SolverError
from lunaralbedo.legacy import solve_legacy
from lunaralbedo.legacy.interp import bicubic_f32, bilinear_f32
from lunaralbedo.legacy.outputs import to_uint8
from lunaralbedo.legacy.vwgeo import Geo, boxes_overlap, tiles_for_images, unpadded_corners
from lunaralbedo.legacy.weights import CenterLines, center_lines, line_weights
from lunaralbedo.settings import parse_legacy

CRS = "+proj=longlat +a=1737400 +b=1737400 +no_defs"


def test_pixel_centre_convention_and_float32_corners():
    g = Geo.from_gdal((0.042343605902381544, 0, 9.135360366542784, 0, -0.0422581076788565, -6.324438818313529), 135, 135)
    assert g.corners()[0] == 9.15653228759765625  # the legacy list value: centre of pixel 0, as float32
    assert g.col(g.lon(17.25)) == pytest.approx(17.25)
    assert boxes_overlap((0, 1, 0, 1), (0.5, 2, 0.5, 2)) and not boxes_overlap((0, 1, 0, 1), (1, 2, 0, 1))


def test_tile_grid_from_reference_spacing():
    ref = Geo.from_gdal((0.04224640792195306, 0, 172.74977475854126, 0, -0.042233358662328274, -21.942195237924917),
                        152, 137)
    tiles = tiles_for_images([(4.02, 9.74, -11.89, -6.28)], 4.0, ref)
    # Named after the unpadded upper-left corner, listed south to north, west to east.
    assert [t.name for t in tiles] == ["tile_4E8S", "tile_8E8S", "tile_4E4S", "tile_8E4S"]
    t = next(t for t in tiles if t.name == "tile_4E8S")
    assert (t.geo.width, t.geo.height) == (105, 105)  # 4 deg / spacing, rounded, plus 2 x 5 pixels of padding
    assert t.geo.c == pytest.approx(4 - 5 * ref.a) and t.geo.f == pytest.approx(-8 - 5 * ref.e)
    assert t.crop_window == (5, 5, 95, 95)
    assert unpadded_corners(t.geo, 4.0) == (4.0, 8.0, -12.0, -8.0)


def test_centre_lines_and_tent_weights():
    valid = np.zeros((5, 7), bool)
    valid[1:4, 2:7] = True
    cl = center_lines(valid)
    assert cl.h_center.tolist() == [3, 4, 4, 4, 3] and cl.h_maxdist.tolist() == [0, 4, 4, 4, 0]
    assert cl.v_center.tolist() == [2, 2, 2, 2, 2, 2, 2] and cl.v_maxdist.tolist() == [0, 0, 2, 2, 2, 2, 2]
    assert CenterLines.from_lines(cl.to_lines()).h_center.tolist() == cl.h_center.tolist()
    w = line_weights(cl, np.array([4.0, 5.0, 6.0, 4.0, -1.0]), np.array([2.0, 2.0, 2.0, 0.0, 2.0]))
    assert w.dtype == np.float32
    assert w.tolist() == [1.0, 0.5, 0.0, 0.0, 0.0]  # centre, half-way, edge, empty row, outside


def test_interpolation_reproduces_linear_functions():
    yy, xx = np.mgrid[0:8, 0:9].astype(np.float32)
    img = 3 * xx + 2 * yy + 1
    x, y = np.array([2.25, 4.5, 6.75]), np.array([3.5, 1.25, 5.0])
    assert np.allclose(bilinear_f32(img, x, y), 3 * x + 2 * y + 1, atol=1e-5)
    assert np.allclose(bicubic_f32(img, x, y), 3 * x + 2 * y + 1, atol=1e-4)


def test_uint8_is_clamped_then_truncated():
    assert to_uint8(np.array([-3.0, 0.99, 127.999, 254.6, 300.0, np.nan])).tolist() == [0, 0, 127, 254, 255, 0]


# ---------------------------------------------------------------- bad input


def _drg(path: Path, lon0: float, lat0: float, dtype="uint8", size=60, res=0.02):
    data = np.full((2, size, size), 200, dtype=dtype)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=2, dtype=dtype,
                       crs=CRS, transform=from_origin(lon0, lat0, res, res)) as ds:
        ds.write(data)


def _settings(tmp_path: Path, drg_dir: Path, extra: str = "", box: str = "0.2:0.8:-0.8:-0.2") -> object:
    text = f"DRG_DIR {drg_dir}\nTILE_SIZE 1\nSIMULATION_BOX {box}\nREFLECTANCE_TYPE 0\nMAX_NUM_ITER 1\n{extra}"
    return parse_legacy(text, tmp_path / "settings.txt")


def test_tiny_mosaic_runs(tmp_path):
    drgs = tmp_path / "drg"
    drgs.mkdir()
    _drg(drgs / "AAAA-M-0001.tif", 0.0, 0.0)
    _drg(drgs / "AAAA-M-0002.tif", 0.5, -0.2)
    summary = solve_legacy(_settings(tmp_path, drgs), tmp_path / "out", progress=False)
    assert summary["tiles_written"] == ["tile_0E0N"]
    with rasterio.open(tmp_path / "out" / "albedo" / "tile_0E0N.tif") as ds:
        d = ds.read()
    # 1 deg / 0.02 deg = 50 pixels, plus the one the legacy crop keeps when the tile edge falls on a
    # pixel half-way point (round(54.5) + 1): the legacy program wrote 51 x 51 here too.
    assert d.shape == (2, 51, 51) and set(np.unique(d[0][d[1] > 0])) == {200}


def test_missing_drg_folder(tmp_path):
    with pytest.raises(InputError, match="DRG folder not found"):
        solve_legacy(_settings(tmp_path, tmp_path / "nope"), tmp_path / "out", progress=False)


def test_non_uint8_drg_names_the_file(tmp_path):
    drgs = tmp_path / "drg"
    drgs.mkdir()
    _drg(drgs / "AAAA-M-0001.tif", 0.0, 0.0, dtype="uint16")
    with pytest.raises(InputError, match="AAAA-M-0001.tif.*uint8"):
        solve_legacy(_settings(tmp_path, drgs), tmp_path / "out", progress=False)


def test_corrupt_drg_names_the_file(tmp_path):
    drgs = tmp_path / "drg"
    drgs.mkdir()
    (drgs / "AAAA-M-0001.tif").write_bytes(b"not a tiff")
    with pytest.raises(InputError, match="AAAA-M-0001.tif"):
        solve_legacy(_settings(tmp_path, drgs), tmp_path / "out", progress=False)


def test_no_image_in_the_box(tmp_path):
    drgs = tmp_path / "drg"
    drgs.mkdir()
    _drg(drgs / "AAAA-M-0001.tif", 50.0, 10.0)  # far from the box
    with pytest.raises(SolverError, match="no DRG overlaps"):
        solve_legacy(_settings(tmp_path, drgs), tmp_path / "out", progress=False)


def test_output_inside_an_input_folder_is_refused(tmp_path):
    drgs = tmp_path / "drg"
    drgs.mkdir()
    _drg(drgs / "AAAA-M-0001.tif", 0.0, 0.0)
    with pytest.raises(SettingsError, match="must not be inside the input folder"):
        solve_legacy(_settings(tmp_path, drgs), drgs / "out", progress=False)
    with pytest.raises(SettingsError, match="must not contain the input"):
        solve_legacy(_settings(tmp_path, drgs), tmp_path, progress=False)
    assert (drgs / "AAAA-M-0001.tif").is_file()


def test_missing_position_names_key_and_file(tmp_path):
    drgs, dems = tmp_path / "drg", tmp_path / "dem"
    drgs.mkdir()
    dems.mkdir()
    _drg(drgs / "AAAA-M-0001.tif", 0.0, 0.0)
    with rasterio.open(dems / "dem.tif", "w", driver="GTiff", width=20, height=20, count=1, dtype="int16", crs=CRS,
                       transform=from_origin(-0.5, 0.5, 0.1, 0.1), nodata=-32767) as ds:
        ds.write(np.zeros((1, 20, 20), np.int16))
    (tmp_path / "sun.txt").write_text("OTHER-KEY-1 1 2 3\n")
    (tmp_path / "sc.txt").write_text("OTHER-KEY-1 1 2 3\n")
    text = (f"DRG_DIR {drgs}\nDEM_DIR {dems}\nSUN_POSITION_FILE {tmp_path / 'sun.txt'}\n"
            f"SPACECRAFT_POSITION_FILE {tmp_path / 'sc.txt'}\nTILE_SIZE 1\nSIMULATION_BOX 0:1:-1:0\nREFLECTANCE_TYPE 2\n")
    s = parse_legacy(text, tmp_path / "settings.txt")
    with pytest.raises(MissingPositionError, match="AAAA-M-0001.*sun.txt|sun.txt.*AAAA-M-0001"):
        solve_legacy(s, tmp_path / "out", progress=False)


@pytest.mark.parametrize("options, named", [
    (["--method", "seed"], "--method"), (["--workers", "2"], "--workers 2"), (["--resume"], "--resume"),
    (["--response", "estimate"], "--response"), (["--max-iter", "3", "--tolerance", "0"], "--max-iter, --tolerance"),
])
def test_legacy_refuses_options_it_cannot_honour(tmp_path, options, named):
    """``solve --legacy`` with a solver option PhotometryTK's pipeline has no counterpart of: exit 2, one line
    naming the option, before anything is read or written (the settings file here does not even exist)."""
    from click.testing import CliRunner

    from lunaralbedo.cli import main

    res = CliRunner().invoke(main, ["solve", str(tmp_path / "none.txt"), "--legacy", "-o", str(tmp_path / "o"), *options])
    assert res.exit_code == 2, res.output
    assert res.output.startswith(f"error: --legacy runs PhotometryTK's pipeline in one process and cannot honour {named}:")
    assert len(res.output.strip().splitlines()) == 1 and not (tmp_path / "o").exists()
    ok = CliRunner().invoke(main, ["solve", str(tmp_path / "none.txt"), "--legacy", "--workers", "1"])
    assert ok.exit_code == 2 and "none.txt" in ok.output and "cannot honour" not in ok.output  # 1 worker is what it does
