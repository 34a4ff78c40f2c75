"""`lunaralbedo ingest`: round trips on forward-model cubes, the real NAC crop, settings and failures."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio
import spiceypy
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.model.grid import Grid
from lunaralbedo.ingest.keys import make_keys
from lunaralbedo.ingest.run import ingest
from lunaralbedo.model.geometry import body_fixed, dem_normals, illumination
from lunaralbedo.simulate.forward import exposure_signal
from lunaralbedo.simulate.mission import C1, C2, MODEL, Scene, build
from lunaralbedo.io.positions import read_positions
from lunaralbedo.settings import load_settings

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data"


@pytest.fixture(autouse=True)
def clean_pool():
    spiceypy.kclear()
    yield
    assert spiceypy.ktotal("ALL") == 0
    spiceypy.kclear()


def _scene(sample: Path) -> Scene:
    with rasterio.open(sample / "truth/albedo.tif") as ds:
        alb, t = ds.read(1).astype(float), ds.transform
    with rasterio.open(sample / "dem/dem.tif") as ds:
        dem = ds.read(1).astype(float)
    return Scene(Grid(t, alb.shape), dem, alb)


def truth_on_grid(scene: Scene, exposure: float, sun_km, sc_km) -> np.ndarray:
    """A * T * R at the DEM pixel centres (what an ideal DRG holds): eq. 1 on the scene's own albedo and DEM."""
    pts = body_fixed(*scene.grid.lonlat(), scene.heights)
    cos_i, cos_e, alpha = illumination(pts, dem_normals(pts), sun_km, sc_km)
    return exposure_signal(scene.albedo, exposure, MODEL.reflectance(cos_i, cos_e, alpha, (C1, C2)))


def _drg_errors(sample: Path, work: Path, key: str, im: dict):
    """Relative error of a DRG against A*T*R on the DEM grid, away from the footprint edge."""
    scene = _scene(sample)
    ref = truth_on_grid(scene, im["exposure"], im["sun_km"], im["spacecraft_km"])
    with rasterio.open(work / "DRG" / f"{key}.tif") as ds:
        v, t, mask = ds.read(1).astype(float), ds.transform, ds.read(2)
        assert ds.crs is not None and ds.res == pytest.approx(scene.grid.res)
    T = scene.grid.transform
    c0, r0 = (t.c - T.c) / T.a, (t.f - T.f) / T.e
    assert abs(c0 - round(c0)) < 1e-6 and abs(r0 - round(r0)) < 1e-6  # same pixel grid as the DEM
    sub = ref[round(r0):round(r0) + v.shape[0], round(c0):round(c0) + v.shape[1]]
    ok = np.isfinite(v)
    assert np.array_equal(ok, mask > 0)
    inner = ok.copy()
    for sh in [(1, 0), (-1, 0), (0, 1), (0, -1), (2, 0), (-2, 0), (0, 2), (0, -2)]:
        inner &= np.roll(ok, sh, axis=(0, 1))
    return (v[inner] - sub[inner]) / sub[inner], int(ok.sum())


def test_sample_data_round_trip(tmp_path):
    """Frame cameras: ingested DRGs = A*T*R of the forward model (noise 0.5 %), positions = truth."""
    truth = json.loads((SAMPLE / "truth/truth.json").read_text())
    cubes = sorted((SAMPLE / "cubes").glob("*.cub"))
    work = tmp_path / "work"
    t0 = time.perf_counter()
    report = ingest(cubes, [SAMPLE / "dem"], work, match_dem=True)  # the truth is on the DEM grid
    elapsed = time.perf_counter() - t0
    assert len(report.done) == len(truth["images"]) == 5
    sun, sc = read_positions(work / "meta/sunpos.txt"), read_positions(work / "meta/spacecraftpos.txt")
    for key, im in truth["images"].items():
        # Sun: the same spkpos(LT+S) convention; spacecraft: the built position, LT+S shifts it by ~10 m
        assert np.linalg.norm(sun[key] - im["sun_km"]) < 1e-3
        assert np.linalg.norm(sc[key] - im["spacecraft_km"]) < 0.02
        rel, n = _drg_errors(SAMPLE, work, key, im)
        print(f"{key}: {n} px, |rel err| median {np.median(np.abs(rel)):.4f} p99 {np.percentile(np.abs(rel), 99):.4f}")
        assert n > 10000
        assert abs(np.mean(rel)) < 0.002
        assert np.median(np.abs(rel)) < 0.005
        assert np.percentile(np.abs(rel), 99) < 0.02
    px = sum(r.grid_pixels for r in report.done) / sum(r.seconds for r in report.done)
    print(f"frame-camera orthoprojection: {px:,.0f} output px/s; ingest of 5 cubes {elapsed:.2f} s")
    # settings: accepted by load_settings, relative paths, float32-friendly shadows, box = union of footprints
    s = load_settings(work / "settings.txt")
    assert s.drg_dir == (work / "DRG").resolve() and s.dem_dir == (work / "DEM").resolve()
    assert s.sun_position_file == (work / "meta/sunpos.txt").resolve()
    assert (s.reflectance_type, s.shadow_type, s.max_num_iter) == (2, 0, 10)
    boxes = np.array([r.box for r in report.done])
    assert s.simulation_box == pytest.approx((boxes[:, 0].min(), boxes[:, 2].max(), boxes[:, 1].min(), boxes[:, 3].max()),
                                             abs=1e-5)
    assert "DRG" in (work / "settings.txt").read_text() and str(work) not in (work / "settings.txt").read_text()
    with rasterio.open(SAMPLE / "dem/dem.tif") as given, rasterio.open(work / "DEM/dem.tif") as ds:
        assert ds.nodata == -32767 and ds.res == pytest.approx(given.res)  # the DEM's own grid


def test_line_scanner_round_trip(tmp_path):
    """A generated line-scan cube (moving spacecraft, per-point line search) orthoprojects onto the truth."""
    sample = tmp_path / "sim"
    truth = build(sample, seed=7, n_frames=1, with_line=True)
    key = "SIM-L-00001"
    work = tmp_path / "work"
    report = ingest([sample / "cubes" / f"{key}.cub"], [sample / "dem"], work, match_dem=True)
    (res,) = report.done
    assert res.kind == "line scanner"
    rel, n = _drg_errors(sample, work, key, truth["images"][key])
    print(f"line scanner: {n} px, |rel err| median {np.median(np.abs(rel)):.4f}; {res.pixels_per_second:,.0f} px/s")
    assert n > 4000
    assert abs(np.mean(rel)) < 0.003 and np.median(np.abs(rel)) < 0.006 and np.percentile(np.abs(rel), 99) < 0.03


def test_real_nac_crop_orthoprojected_on_ldem(realdata, tmp_path):
    """The real NAC crop on the LOLA DEM cube (radius values) at 1 m/px: footprint ~0.22 km, I/F preserved
    (the DRG's mean is the cube's as GDAL reads it: measured 0.10367 against 0.10371), and the settings' box
    is the DRG's extent."""
    cube = realdata / "isis/M143947267L.cal.echo.crop.cub"
    with rasterio.open(cube) as ds:  # GDAL's ISIS3 driver masks the special pixels
        cube_mean = float(ds.read(1, masked=True).astype(np.float64).mean())
    work = tmp_path / "nac"
    result = CliRunner().invoke(main, ["ingest", str(cube),
                                       "--dem", str(realdata / "isis/ldem_4_reduced.cub"), "-o", str(work), "--mpp", "1"])
    assert result.exit_code == 0, result.output
    assert "values are radius" in result.output and "line scanner" in result.output
    with rasterio.open(work / "DRG/M143947267L.tif") as ds:
        v = ds.read(1)
        assert ds.res[0] == pytest.approx(np.degrees(1.0 / 1737400.0))
        w, s, e, n = ds.bounds
        px = ds.res[0]
    assert 102.59 < w < e < 102.61 and 35.97 < s < n < 35.99
    assert 40000 < np.isfinite(v).sum() < 90000  # ~ 220 m x 240 m at 1 m/px
    assert np.nanmean(v) == pytest.approx(cube_mean, rel=0.005)
    box = load_settings(work / "settings.txt").simulation_box  # lon_min, lon_max, lat_min, lat_max
    assert np.allclose(box, (w, e, s, n), rtol=0, atol=px)


def test_skipped_cubes_are_reported_and_failures_write_nothing(realdata, tmp_path):
    bad = tmp_path / "broken.cub"
    bad.write_bytes(b"garbage")
    cubes = [SAMPLE / "cubes/SIM-F-00001.cub", bad, realdata / "apollo15_metric/AS15-M-1450_isis3.lbl",
             realdata / "isis/M1181493219CE.vis.odd.reduced.cub"]
    out = CliRunner().invoke(main, ["ingest", *map(str, cubes), "--dem", str(SAMPLE / "dem"), "-o", str(tmp_path / "w")])
    assert out.exit_code == 0, out.output
    assert "skipped broken_____" in out.output and "skipped AS15-M-1450" in out.output
    # the WAC push-frame cube is modelled now; it is skipped per band only because it lies outside the sample DEM
    assert "skipped M1181493B01" in out.output and "pushframe geometry is not supported" not in out.output
    assert sorted(p.name for p in (tmp_path / "w/DRG").iterdir()) == ["SIM-F-00001.tif"]
    assert list(read_positions(tmp_path / "w/meta/sunpos.txt")) == ["SIM-F-00001"]
    # nothing ingestible: exit 2 with the reasons, no settings file
    out = CliRunner().invoke(main, ["ingest", str(bad), "--dem", str(SAMPLE / "dem"), "-o", str(tmp_path / "w2")])
    assert out.exit_code == 2 and "error: no cube could be ingested" in out.output and "broken.cub" in out.output
    assert not (tmp_path / "w2/settings.txt").exists()
    # re-ingesting into the same WORKDIR with other cubes removes the earlier run's DRGs
    out = CliRunner().invoke(main, ["ingest", str(SAMPLE / "cubes/SIM-F-00002.cub"), "--dem", str(SAMPLE / "dem"),
                                    "-o", str(tmp_path / "w")])
    assert out.exit_code == 0 and "removed" in out.output
    assert sorted(p.name for p in (tmp_path / "w/DRG").iterdir()) == ["SIM-F-00002.tif"]
    out = CliRunner().invoke(main, ["ingest", str(cubes[0]), "--dem", str(tmp_path / "nodem"), "-o", str(tmp_path / "w3")])
    assert out.exit_code == 2 and "DEM file or folder not found" in out.output


def test_legacy_8bit_drgs(tmp_path):
    work = tmp_path / "w"
    ingest([SAMPLE / "cubes/SIM-F-00002.cub"], [SAMPLE / "dem/dem.tif"], work, legacy_8bit=True)
    with rasterio.open(work / "DRG/SIM-F-00002.tif") as ds:
        assert ds.dtypes == ("uint8", "uint8")
        v, a = ds.read(1), ds.read(2)
    assert set(np.unique(a)) == {0, 255} and v[a == 255].min() >= 1 and v[a == 0].max() == 0
    assert load_settings(work / "settings.txt").shadow_type == 1


def test_key_rule():
    assert make_keys(["a/M143947267L.cal.echo.crop.cub", "b/AS15-M-1450_isis3.lbl", "x.cub"]) == [
        "M143947267L", "AS15-M-1450", "x__________"]
    assert make_keys(["d1/LONGNAME_0001.cub", "d2/LONGNAME_0001.cub", "LONGNAME_0001b.cub"]) == [
        "LONGNAME_00", "LONGNAME001", "LONGNAME002"]


@pytest.mark.slow
def test_ingested_sample_data_solves_to_the_truth_albedo(tmp_path):
    """Cubes -> ingest -> solve: the albedo equals the truth up to the global albedo*exposure scale."""
    import lunaralbedo
    from rasterio.warp import Resampling, reproject

    truth = json.loads((SAMPLE / "truth/truth.json").read_text())
    work = tmp_path / "work"
    ingest(sorted((SAMPLE / "cubes").glob("*.cub")), [SAMPLE / "dem"], work, match_dem=True)
    lunaralbedo.solve(work / "settings.txt", out=tmp_path / "albedo", plots=False)
    tiles = sorted((tmp_path / "albedo/albedo").glob("*.tif"))
    assert tiles
    ratios = []
    with rasterio.open(SAMPLE / "truth/albedo.tif") as tds:
        true_alb, tt, tcrs = tds.read(1), tds.transform, tds.crs
    for tile in tiles:
        with rasterio.open(tile) as ds:
            a = ds.read(1).astype(np.float64)
            ref = np.full(a.shape, np.nan, dtype=np.float32)
            reproject(true_alb, ref, src_transform=tt, src_crs=tcrs, dst_transform=ds.transform, dst_crs=ds.crs,
                      resampling=Resampling.bilinear, dst_nodata=np.nan)
            ok = np.isfinite(a) & np.isfinite(ref) & (a > 0)
            if ds.nodata is not None and np.isfinite(ds.nodata):
                ok &= a != ds.nodata
            ratios.append(a[ok] / ref[ok])
    r = np.concatenate(ratios)
    assert r.size > 20000
    dev = np.abs(r / np.median(r) - 1.0)
    print(f"albedo/truth scale {np.median(r):.4f}; |deviation| median {np.median(dev):.4f} p95 {np.percentile(dev, 95):.4f}")
    assert np.median(dev) < 0.01 and np.percentile(dev, 95) < 0.03
    # exposure ratios between images are the true ones (the solver's exposure.csv)
    lines = (tmp_path / "albedo/exposure.csv").read_text().splitlines()[1:]
    solved = {ln.split(",")[0]: float(ln.split(",")[1]) for ln in lines}
    scale = [solved[k] / im["exposure"] for k, im in truth["images"].items()]
    assert np.ptp(scale) / np.mean(scale) < 0.01
