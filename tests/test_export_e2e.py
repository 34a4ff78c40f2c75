"""export-kml after the real pipeline: `simulate` + `solve` (forward model) and `solve` of
PhotometryTK settings 1, both through the CLI, read back through GDAL."""
from __future__ import annotations

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rio_cogeo.cogeo import cog_validate

from lunaralbedo.cli import main
from test_export_common import kml_vs_albedo


def _run(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def _data_extent(out):
    """Union of the valid albedo pixels, cut to SIMULATION_BOX (computed here from the tiles and report.json)."""
    import json

    bounds = []
    for p in sorted((out / "albedo").glob("tile_*.tif")):
        with rasterio.open(p) as ds:
            ok = np.isfinite(ds.read(1))
            if ok.any():
                rows, cols = np.flatnonzero(ok.any(axis=1)), np.flatnonzero(ok.any(axis=0))
                (w, n), (e, s) = ds.transform * (cols[0], rows[0]), ds.transform * (cols[-1] + 1, rows[-1] + 1)
                bounds.append((w, s, e, n))
            rx, ry, x0, y0 = ds.transform.a, -ds.transform.e, ds.transform.c, ds.transform.f
    b = np.array(bounds)
    lon0, lon1, lat0, lat1 = json.loads((out / "report.json").read_text())["settings"]["simulation_box"]
    # the box snapped outward to whole pixels of the tile grid
    lon0, lon1 = x0 + np.floor((lon0 - x0) / rx + 1e-6) * rx, x0 + np.ceil((lon1 - x0) / rx - 1e-6) * rx
    lat0, lat1 = y0 - np.ceil((y0 - lat0) / ry - 1e-6) * ry, y0 - np.floor((y0 - lat1) / ry + 1e-6) * ry
    return (max(b[:, 0].min(), lon0), max(b[:, 1].min(), lat0), min(b[:, 2].max(), lon1), min(b[:, 3].max(), lat1))


def _check_export(out):
    text = _run("export-kml", out, "--workers", "2")
    assert "doc.kml" in text
    worst, alpha_ok, facts, _ = kml_vs_albedo(out)
    extent = _data_extent(out)
    assert facts["bounds"] == pytest.approx(extent, abs=1e-6)
    assert worst == 0 and alpha_ok
    for name in ("albedo_mosaic.tif", "error_mosaic.tif"):
        valid, errors, _ = cog_validate(str(out / name))
        assert valid, errors
    for p in (out / "albedo_sub4").iterdir():
        with rasterio.open(p) as ds:
            w, s, e, n = ds.bounds
            assert extent[0] - 1e-6 <= w and e <= extent[2] + 1e-6 and extent[1] - 1e-6 <= s and n <= extent[3] + 1e-6
    return facts


def test_export_of_a_forward_model_result(tmp_path):
    _run("simulate", tmp_path / "sim")
    _run("solve", tmp_path / "sim" / "settings.txt", "-o", tmp_path / "out", "--quiet", "--workers", "1")
    facts = _check_export(tmp_path / "out")
    assert facts["width"] >= 100 and facts["height"] >= 100


def test_export_of_the_settings_1_solve(photk_tests, tmp_path):
    _run("solve", photk_tests / "photometry_settings_1.txt", "-o", tmp_path / "out", "--quiet", "--workers", "1")
    facts = _check_export(tmp_path / "out")
    # SIMULATION_BOX 6:10:-10:-9 (whole tiles: 4..12, -12..-8) snapped outward to the 4/95-degree pixels
    px = 4 / 95
    assert facts["bounds"] == pytest.approx((4 + 47 * px, -12 + 47 * px, 4 + 143 * px, -12 + 72 * px))
    assert (facts["width"], facts["height"]) == (96, 25)
