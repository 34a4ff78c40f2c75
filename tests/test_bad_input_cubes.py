"""Bad-input matrix of ``ingest`` and ``positions`` (ISIS cubes, kernels, DEM, output paths).

Every case: the exit code, one line ``error: ...`` naming the culprit, no traceback,
nothing half-written.  Inputs are the repository's sample cubes, edited in a copy.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio

from bad_input_common import assert_clean_failure, cli, truncate

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data"
CUBE = "SIM-F-00001.cub"


@pytest.fixture
def data(tmp_path) -> Path:
    for sub in ("cubes", "kernels", "dem"):
        shutil.copytree(SAMPLE / sub, tmp_path / sub)
    return tmp_path


def edit_label(cube: Path, old: str, new: str) -> None:
    """Replace label text in place, padded to the same length (the pixels start at a fixed byte)."""
    data = cube.read_bytes()
    assert old.encode() in data
    cube.write_bytes(data.replace(old.encode(), new.ljust(len(old)).encode(), 1))


def ingest(data: Path, *cubes: Path, dem: Path | None = None, out: Path | None = None):
    cubes = cubes or (data / "cubes" / CUBE,)
    return cli("ingest", *cubes, "--dem", dem or data / "dem" / "dem.tif", "-o", out or data / "work")


def positions(data: Path, cube: Path | None = None, sun: Path | None = None):
    return cli("positions", cube or data / "cubes" / CUBE, "--sun", sun or data / "sun.txt",
               "--spacecraft", data / "sc.txt")


def test_good_cube_ingests_and_gives_positions(data):
    assert ingest(data).exit_code == 0
    assert positions(data).exit_code == 0


@pytest.mark.parametrize("keep", [0.5, 16384], ids=["pixels-cut-short", "header-only"])
def test_truncated_cube(data, keep):
    cube = data / "cubes" / CUBE
    truncate(cube, keep)
    assert_clean_failure(ingest(data), 2, cube, absent=data / "work")


def test_missing_label_key(data):
    cube = data / "cubes" / CUBE
    edit_label(cube, "StartTime                 = 2021-05-23T00:00:54.265895", "")
    for res in (ingest(data), positions(data)):
        msg = assert_clean_failure(res, 2, cube, absent=data / "work")
        assert "StartTime" in msg
    assert not (data / "sun.txt").exists()


def test_unknown_camera(data):
    cube = data / "cubes" / CUBE
    edit_label(cube, "NaifFrameCode       = -999001", "NaifFrameCode       = -999777")
    msg = assert_clean_failure(ingest(data), 2, cube, absent=data / "work")
    assert "-999777" in msg


def test_kernels_that_do_not_cover_the_time(data):
    cube = data / "cubes" / CUBE
    edit_label(cube, "StartTime                 = 2021-05-23T00:00:54.265895",
               "StartTime                 = 1999-05-23T00:00:54.265895")
    for res in (ingest(data), positions(data)):
        assert_clean_failure(res, 2, cube, absent=data / "work")
    assert not (data / "sun.txt").exists()


def test_dem_cut_short(data):
    dem = data / "dem" / "dem.tif"
    truncate(dem, 0.4)
    assert_clean_failure(ingest(data), 2, dem, absent=data / "work")


def test_output_below_a_regular_file(data):
    blocker = data / "afile"
    blocker.write_text("x")
    assert_clean_failure(ingest(data, out=blocker / "work"), 2, blocker)
    assert_clean_failure(positions(data, sun=blocker / "sun.txt"), 2, blocker)
    assert blocker.read_text() == "x"


def test_nan_inf_pixels_and_a_dem_hole_are_left_out(data):
    """NaN/Inf pixels in the cube and a no-data hole of the DEM under the footprint: the
    DRG is NaN there and finite elsewhere (handled, not an error)."""
    cube = data / "cubes" / CUBE
    raw = bytearray(cube.read_bytes())
    px = np.frombuffer(raw, dtype="<f4", offset=16384, count=200 * 200).copy().reshape(200, 200)
    px[:, :20] = np.nan
    px[:, 20:40] = np.inf
    raw[16384:16384 + px.nbytes] = px.astype("<f4").tobytes()
    cube.write_bytes(bytes(raw))
    dem = data / "dem" / "dem.tif"
    with rasterio.open(dem, "r+") as ds:
        z = ds.read(1)
        nodata = ds.nodata if ds.nodata is not None else -32767.0
        if ds.nodata is None:
            ds.nodata = nodata
        # a hole over the middle of the footprint (lon 6.2, lat -6.3)
        r, c = ds.index(6.24, -6.28)
        z[r - 3:r + 3, c - 3:c + 3] = nodata
        ds.write(z, 1)
    res = ingest(data)
    assert res.exit_code == 0, res.stderr
    with rasterio.open(data / "work" / "DRG" / "SIM-F-00001.tif") as ds:
        drg = ds.read(1, masked=True).filled(np.nan)
        r, c = ds.index(6.24, -6.28)
    assert not np.isinf(drg).any()
    assert np.isnan(drg[r, c]), "the DEM hole must give no DRG value"
    assert np.isfinite(drg).sum() > 1000
