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


def _tile_union(folder):
    bounds = []
    for p in sorted(folder.glob("tile_*.tif")):
        with rasterio.open(p) as ds:
            bounds.append(tuple(ds.bounds))
    b = np.array(bounds)
    return (b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max())


def _check_export(out):
    text = _run("export-kml", out, "--workers", "2")
    assert "doc.kml" in text
    worst, alpha_ok, facts, _ = kml_vs_albedo(out)
    assert facts["bounds"] == pytest.approx(_tile_union(out / "albedo"), abs=1e-9)
    assert worst == 0 and alpha_ok
    for name in ("albedo_mosaic.tif", "error_mosaic.tif"):
        valid, errors, _ = cog_validate(str(out / name))
        assert valid, errors
    assert sorted(p.name for p in (out / "albedo_sub4").iterdir()) == sorted(p.name for p in (out / "albedo").iterdir())
    return facts


def test_export_of_a_forward_model_result(tmp_path):
    _run("simulate", tmp_path / "sim")
    _run("solve", tmp_path / "sim" / "settings.txt", "-o", tmp_path / "out", "--quiet", "--workers", "1")
    facts = _check_export(tmp_path / "out")
    assert facts["width"] >= 100 and facts["height"] >= 100


def test_export_of_the_settings_1_solve(photk_tests, tmp_path):
    _run("solve", photk_tests / "photometry_settings_1.txt", "-o", tmp_path / "out", "--quiet", "--workers", "1")
    facts = _check_export(tmp_path / "out")
    assert facts["bounds"] == pytest.approx((4.0, -12.0, 12.0, -8.0)) and (facts["width"], facts["height"]) == (190, 95)
