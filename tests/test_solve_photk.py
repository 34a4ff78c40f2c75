"""End-to-end solves of PhotometryTK's own regression settings (real Apollo 15/16 data)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.io.outputs import read_exposure_csv


def _run(settings, out):
    res = CliRunner().invoke(main, ["solve", str(settings), "-o", str(out), "--workers", "1", "--quiet"])
    assert res.exit_code == 0, res.output
    return res.output


def test_settings_1_lunar_lambert_normalised_cost(photk_tests, tmp_path):
    out = tmp_path / "run1"
    text = _run(photk_tests / "photometry_settings_1.txt", out)
    assert "iterations 2" in text and "tiles 2" in text
    gold = photk_tests / "albedo_gold_1" / "albedo"
    for gold_tile in sorted(gold.glob("tile_*.tif")):
        with rasterio.open(gold_tile) as g, rasterio.open(out / "albedo" / gold_tile.name) as a:
            assert (a.width, a.height) == (g.width, g.height)
            assert (a.bounds.left, a.bounds.top) == pytest.approx((g.bounds.left, g.bounds.top), abs=1e-9)
            alb = a.read(1)
            has_gold = g.read(2) == 255
            assert np.isfinite(alb[has_gold]).mean() > 0.99  # albedo wherever the gold has data
            assert np.nanmin(alb) > 0
            gold_dn = g.read(1).astype(float)
            both = has_gold & np.isfinite(alb)
            # the same surface as the legacy solve (which froze exposures at their start values)
            assert np.corrcoef(alb[both], gold_dn[both])[0, 1] > 0.7
            # and the same brightness scale (TR_CONST convention; legacy multiplied by 1 + c2 at the end)
            c2 = json.loads((out / "report.json").read_text())["parameters"]["c2"][-1]
            assert 0.85 < np.mean(alb[both]) * (1 + c2) / gold_dn[both].mean() < 1.15
    expo = read_exposure_csv(out / "exposure.csv")
    assert len(expo) == 53 and all(v > 0 for v in expo.values())
    rep = json.loads((out / "report.json").read_text())
    assert rep["images_skipped"] == {"AS15-M-0073": "overlaps no tile of SIMULATION_BOX"}
    assert rep["cost_q"][1] < rep["cost_q"][0]
    for tile in rep["tiles"]:  # per tile: images used, and those over it without a usable pixel
        assert len(tile["images"]) > 30 and tile["valid_pixels"] > 8000
        assert not set(tile["images"]) & set(tile["images_without_usable_pixels"])
    assert (out / "error" / "tile_4E8S.tif").exists()


def _image_over_exposure_range(drg_dir, exposures, tile):
    """Per pixel of ``tile``, the least and greatest I/T of the DRGs over it (read and resampled bilinearly
    by GDAL here, not by the solver), NaN where no DRG has data."""
    from rasterio.warp import Resampling, reproject

    with rasterio.open(tile) as ds:
        shape, transform, crs = ds.shape, ds.transform, ds.crs
    lo, hi = np.full(shape, np.inf), np.full(shape, -np.inf)
    for drg in sorted(drg_dir.glob("*.tif")):
        if drg.name[:11] not in exposures:
            continue
        with rasterio.open(drg) as src:
            dn = np.where(src.read(2) > 0, src.read(1), np.nan).astype(np.float32)
            on_tile = np.full(shape, np.nan, np.float32)
            reproject(dn, on_tile, src_transform=src.transform, src_crs=src.crs or crs, src_nodata=np.nan,
                      dst_transform=transform, dst_crs=crs, dst_nodata=np.nan, resampling=Resampling.bilinear)
        ratio = on_tile / exposures[drg.name[:11]]
        lo, hi = np.fmin(lo, ratio), np.fmax(hi, ratio)
    covered = np.isfinite(lo) & np.isfinite(hi)
    return np.where(covered, lo, np.nan), np.where(covered, hi, np.nan)


def test_settings_2_mosaic_without_dem(photk_tests, tmp_path):
    """Mosaic mode (R = 1): each albedo pixel is a weighted mean of the images' I/T over it, so it lies
    between their least and greatest value (measured: within 1.2e-7), wherever a DRG has data except
    where all are in shadow (measured: 97 % of those pixels), and nowhere else."""
    out = tmp_path / "run2"
    _run(photk_tests / "photometry_settings_2.txt", out)
    tiles = sorted(p.name for p in (out / "albedo").glob("*.tif"))
    assert tiles == ["tile_0E8S.tif", "tile_8E8S.tif"]  # 8-degree tiles over lon 6..10
    exposures = read_exposure_csv(out / "exposure.csv")
    for name in tiles:
        with rasterio.open(out / "albedo" / name) as ds:
            alb = ds.read(1)
        lo, hi = _image_over_exposure_range(photk_tests / "DIM_input_2560mpp", exposures, out / "albedo" / name)
        solved, covered = np.isfinite(alb), np.isfinite(lo)
        assert not (solved & ~covered).any()
        assert solved.sum() > 0.95 * covered.sum() > 4000
        assert np.all(alb[solved] >= lo[solved] * (1 - 1e-5)) and np.all(alb[solved] <= hi[solved] * (1 + 1e-5))
    assert not (out / "DEM").exists() and not (out / "error").exists()  # COMPUTE_ERRORS 0, no DEM
    assert all(v > 0 for v in read_exposure_csv(out / "exposure.csv").values())
