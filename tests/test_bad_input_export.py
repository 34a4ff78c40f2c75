"""Bad-input matrix of ``export-kml``: exit 2, one line naming the culprit, the previous export intact."""
from __future__ import annotations

import pytest

from bad_input_common import assert_clean_failure, cli, truncate
from test_export_common import make_result


@pytest.fixture
def result(tmp_path):
    root = make_result(tmp_path / "res", [(0, 0), (4, 0)], n=64)
    assert cli("export-kml", root, "--workers", "1").exit_code == 0
    return root


def listing(root):
    return sorted((p.relative_to(root), p.stat().st_size) for p in root.rglob("*") if p.is_file())


@pytest.mark.parametrize("keep", [0.5, 300], ids=["pixels-cut-short", "header-only"])
def test_truncated_albedo_tile_keeps_the_previous_export(result, keep):
    bad = result / "albedo" / "tile_4E0N.tif"
    truncate(bad, keep)
    before = listing(result)
    assert_clean_failure(cli("export-kml", result, "--workers", "2"), 2, bad)
    assert listing(result) == before, "a failed export must leave the previous one (and no staging folder)"


def test_missing_results_folder(tmp_path):
    assert_clean_failure(cli("export-kml", tmp_path / "nothing"), 2, tmp_path / "nothing", absent=tmp_path / "nothing")


def test_all_nodata_albedo(tmp_path):
    import numpy as np
    import rasterio

    root = make_result(tmp_path / "res", [(0, 0)], n=16)
    with rasterio.open(root / "albedo" / "tile_0E0N.tif", "r+") as ds:
        ds.write(np.full((16, 16), np.nan, np.float32), 1)
    assert_clean_failure(cli("export-kml", root), 2, root / "albedo", "no valid pixel", absent=root / "kml")
