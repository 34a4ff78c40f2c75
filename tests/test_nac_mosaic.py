"""nacmosaic: a simulated LE/RE pair with a known RE boresight error becomes one seamless ideal-camera cube."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.isis.labels import read_label
from lunaralbedo.isis.pixels import read_band
from lunaralbedo.simulate.nacpair import build_pair, render_ideal

ERROR = (0.6, 0.4)  # RE boresight error (across, along track), pixels; the kernels do not know it
NOISE = 0.003


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("pair")
    return d, build_pair(d, boresight_error=ERROR, noise=NOISE)


@pytest.fixture(scope="module")
def mosaic_cube(pair):
    """``nacmosaic`` of the pair (``m.cub`` and ``m-jitreg.json`` beside it), made once for the tests that read it."""
    d, p = pair
    res = CliRunner().invoke(main, ["nacmosaic", str(p.le), str(p.re), "-o", str(d / "m.cub")])
    assert res.exit_code == 0, res.output
    return d / "m.cub"


def _rms_by_region(mosaic, truth, cols, overlap):
    d = (mosaic[:, cols] / truth - 1.0)[12:-12]  # first/last lines: the along-track offset leaves RE short
    rms = np.sqrt(np.nanmean(d ** 2, axis=0))
    a, b = overlap
    return rms[cols < a].mean(), rms[(cols >= a) & (cols < b)].mean(), rms[cols >= b].mean()


def test_mosaic_is_seamless_and_matches_the_rendered_truth(pair, mosaic_cube):
    d, p = pair
    reg = json.loads((d / "m-jitreg.json").read_text())
    # the measured offset is the rendered boresight error (small-angle: pixels of angle = pixels of offset)
    assert reg["sample_offset"] == pytest.approx(ERROR[0], abs=0.1)
    assert reg["line_offset"] == pytest.approx(ERROR[1], abs=0.1)
    mosaic = read_band(d / "m.cub")
    label = read_label(d / "m.cub")
    inst = label.instrument
    assert str(inst["InstrumentId"]) == "IdealCamera" and int(inst["SampleDetectors"]) == mosaic.shape[1]
    from lunaralbedo.camera.ideal import spec_from_label

    spec = spec_from_label(inst)
    a, b = (int(v) for v in reg["overlap_columns"])
    cols = np.arange(a - 12, b + 12)
    truth = render_ideal(p, spec, cols)
    le_rms, ov_rms, re_rms = _rms_by_region(mosaic, truth, cols, (a, b))
    # no seam: the RE side and the blend are as close to the truth as the LE side, which is
    # noise plus cubic resampling of a texture at 0.2 cycles/pixel
    assert re_rms < 1.3 * le_rms and ov_rms < 1.3 * le_rms, (le_rms, ov_rms, re_rms)
    assert le_rms < 3 * NOISE
    # without the offset the RE side is off by several times more
    res = CliRunner().invoke(main, ["nacmosaic", str(p.le), str(p.re), "-o", str(d / "m0.cub"), "--offset",
                                    str(d / "zero.json")])
    assert res.exit_code == 2 and "not found" in res.output
    (d / "zero.json").write_text(json.dumps({"sample_offset": 0.0, "line_offset": 0.0}))
    res = CliRunner().invoke(main, ["nacmosaic", str(p.le), str(p.re), "-o", str(d / "m0.cub"), "--offset",
                                    str(d / "zero.json")])
    assert res.exit_code == 0, res.output
    _, _, re0 = _rms_by_region(read_band(d / "m0.cub"), truth, cols, (a, b))
    assert re0 > 3 * re_rms


def test_mosaic_cube_is_one_observation_for_the_camera_model_and_ingest(pair, mosaic_cube, tmp_path):
    """build_camera reads the ideal label; ingest orthoprojects the mosaic like any line scanner."""
    d, p = pair
    from lunaralbedo.camera.build import build_camera
    from lunaralbedo.camera.intersect import ray_dem
    from lunaralbedo.ingest.observation import open_observation
    from lunaralbedo.ingest.run import ingest

    with open_observation(d / "m.cub", "M") as obs:
        cam = build_camera(obs.label, obs.ephemeris, obs.code)
        assert cam.is_line_scanner and cam.samples == read_band(d / "m.cub").shape[1]
        # ideal pixel -> ground -> pixel round trip
        s, l = np.array([20.0, 84.5, 150.0]), np.array([30.0, 160.0, 290.0])
        o, v = cam.rays(s, l)
        g = ray_dem(o, v, lambda lo, la: np.nan_to_num(p.scene.height(lo, la)))
        s2, l2 = cam.ground_to_image(g)
        assert np.allclose(s2, s, atol=1e-3) and np.allclose(l2, l, atol=1e-3)
    rep = ingest([d / "m.cub"], [d / "dem" / "dem.tif"], tmp_path / "w")
    assert rep.done and rep.results[0].kind == "line scanner" and rep.results[0].valid_pixels > 1000


def test_ingest_mosaics_the_pair_and_aligns_the_dem(pair, tmp_path):
    d, p = pair
    rng = np.random.default_rng(3)
    lon, lat = rng.uniform(5.6, 6.4, 3000), rng.uniform(-6.4, -5.6, 3000)
    # reference points on the true surface; the DEM given to ingest is the truth, so the transform is ~identity
    radius = 1737.4 + p.scene.height(lon, lat) / 1000.0
    np.savetxt(tmp_path / "ref.csv", np.stack([lon, lat, radius], 1), delimiter=",", header="lon,lat,radius",
               comments="", fmt="%.9f")
    res = CliRunner().invoke(main, ["ingest", str(p.le), str(p.re), "--dem", str(d / "dem" / "dem.tif"), "-o",
                                    str(tmp_path / "w"), "--nac-mosaic", "--dem-align", str(tmp_path / "ref.csv")])
    assert res.exit_code == 0, res.output
    assert "SIMNAC_LE.cub + SIMNAC_RE.cub ->" in res.output and "aligned to" in res.output
    drgs = sorted(p.name for p in (tmp_path / "w" / "DRG").glob("*.tif"))
    assert drgs == ["SIMNAC_____.tif"], drgs  # one observation, not two CCDs
    rep = json.loads((tmp_path / "w" / "nac" / "dem-report.json").read_text())
    assert rep["translation_at_dem_centre"]["horizontal"] < 5.0 and abs(rep["translation_at_dem_centre"]["down"]) < 1.0


def test_backplanes_of_the_mosaic_match_the_rendered_geometry(pair, mosaic_cube, tmp_path):
    """`backplanes` reads the ideal-camera label: angles and lat/lon of every mosaic pixel equal the forward
    model's (the true LE frame and spacecraft path, rays to the same DEM) within 0.001 deg (~0.2 pixel)."""
    d, p = pair
    from lunaralbedo.backplanes.angles import BAND_NAMES, angles, neighbour_normals, planetocentric
    from lunaralbedo.camera.ideal import spec_from_label
    from lunaralbedo.camera.intersect import ray_dem
    from lunaralbedo.simulate.nacpair import ideal_rays

    out = tmp_path / "bp.tif"
    res = CliRunner().invoke(main, ["backplanes", str(d / "m.cub"), "--dem", str(d / "dem" / "dem.tif"), "-o", str(out)])
    assert res.exit_code == 0, res.output
    import rasterio

    with rasterio.open(out) as ds:
        planes = dict(zip(ds.descriptions, ds.read().astype(np.float64)))
    assert tuple(planes) == BAND_NAMES
    spec = spec_from_label(read_label(d / "m.cub").instrument)
    lines, samples = planes["Latitude"].shape
    ll, ss = np.meshgrid(np.arange(1.0, lines + 1), np.arange(1.0, samples + 1), indexing="ij")

    def ground(s, l):
        o, v = ideal_rays(p, spec, s, l)
        return o, ray_dem(o, v, lambda lo, la: np.nan_to_num(p.scene.height(lo, la)), tol_m=1e-4)

    o, pts = ground(ss, ll)
    radial = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    phase, emission, incidence = angles(pts, radial, p.sun, o)
    h = 0.5 - 1e-9
    normals = neighbour_normals(ground(ss, ll - h)[1], ground(ss, ll + h)[1], ground(ss - h, ll)[1],
                                ground(ss + h, ll)[1], pts)
    _, local_e, local_i = angles(pts, normals, p.sun, o)
    lat, lon = planetocentric(pts)
    truth = dict(zip(BAND_NAMES, (phase, emission, incidence, local_e, local_i, lat, lon)))
    assert np.isfinite(planes["Latitude"]).all()
    err = {n: float(np.max(np.abs(planes[n] - truth[n]))) for n in BAND_NAMES}
    # measured: phase 2e-6, emission 3e-4, incidence 7e-5, latitude 3.2e-4 (a 10 m along-track shift, 0.05 px),
    # longitude 6e-6 deg, local angles 0.06 deg (the 10 m on the DEM's slopes); one pixel is 180 m = 0.006 deg,
    # so a misread ideal camera (TransX0/TransY0, pitch, axes) would fail
    assert max(err[n] for n in ("Phase Angle", "Emission Angle", "Incidence Angle")) < 1e-3, err
    assert max(err["Latitude"], err["Longitude"]) < 1e-3, err
    assert max(err["Local Emission Angle"], err["Local Incidence Angle"]) < 0.1, err


def test_blocks_of_lines_give_the_same_bytes(pair, monkeypatch):
    """nacmosaic in blocks of 7 lines = in one block (320 lines), byte for byte, measured offset included;
    small tiles (64 CCD rows, 32-row margins) reproduce the whole image's spline coefficients to 1e-12."""
    from lunaralbedo.isis.pixels import read_rows
    from lunaralbedo.nac import noproj
    from lunaralbedo.nac.mosaic import nac_mosaic

    d, p = pair
    whole = noproj.SplineRows(lambda a, b: read_rows(p.le, a, b), (320, 100))
    monkeypatch.setattr(noproj, "TILE_ROWS", 64)
    monkeypatch.setattr(noproj, "NODE_CHUNK", 4)
    tiled = noproj.SplineRows(lambda a, b: read_rows(p.le, a, b), (320, 100))
    ref = whole.rows(0, 320)
    assert np.abs(tiled.rows(0, 320) - ref).max() < 1e-12 * np.abs(ref).max()
    out = {}
    for n in (7, 320):
        r = nac_mosaic(p.le, p.re, d / f"b{n}.cub", block_lines=n, jitreg_prefix=d / f"b{n}-jitreg")
        out[n] = ((d / f"b{n}.cub").read_bytes(), r.sample_offset, r.line_offset, r.overlap)
    assert out[7] == out[320]
    assert np.isfinite(read_band(d / "b7.cub")).mean() > 0.85  # not an empty image
