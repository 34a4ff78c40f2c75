"""Backplanes of the real LRO WAC cube (push-frame) against ISIS phocube's back.reduced.cub, and the CLI."""
from __future__ import annotations

import numpy as np
import pytest
import rasterio
import spiceypy
from click.testing import CliRunner

from lunaralbedo.backplanes.angles import BAND_NAMES
from lunaralbedo.backplanes.run import camera_geometry
from lunaralbedo.camera.build import build_camera
from lunaralbedo.camera.intersect import ray_sphere
from lunaralbedo.cli.backplanes import command as backplanes_cmd
from lunaralbedo.ingest.observation import open_observation
from lunaralbedo.isis.labels import read_label
from lunaralbedo.isis.pixels import read_band

WAC = "M1181493219CE.vis.odd.reduced.cub"


@pytest.fixture(autouse=True)
def clean_pool():
    spiceypy.kclear()
    yield
    spiceypy.kclear()


@pytest.fixture(scope="module")
def wac_reference(realdata):
    """ISIS phocube bands of band 1: phase, local emission, local incidence, latitude, longitude."""
    back = realdata / "isis/back.reduced.cub"
    return [read_band(back, b) for b in range(1, 6)]


def _abs_diff(ours, ref, name):
    d = ours - ref
    return np.abs((d + 180.0) % 360.0 - 180.0) if name == "Longitude" else np.abs(d)


def test_wac_backplanes_match_isis_phocube(realdata, wac_reference):
    """With the reduced GLD100 (phocube used the full one): lat/lon within 0.03 deg, phase 0.3 deg (95th pct)."""
    planes, shape = camera_geometry(read_label(realdata / "isis" / WAC), band=1)
    assert "WAC_GLD100" in shape.name
    names = ["Phase Angle", "Local Emission Angle", "Local Incidence Angle", "Latitude", "Longitude"]
    p95 = {}
    for name, ref in zip(names, wac_reference):
        assert np.array_equal(np.isfinite(planes[name]), np.isfinite(ref)), name  # every pixel on the Moon
        p95[name] = np.percentile(_abs_diff(planes[name].astype(np.float64), ref, name), 95)
    assert p95["Latitude"] < 0.03 and p95["Longitude"] < 0.03 and p95["Phase Angle"] < 0.3
    # measured: lat 0.0029, lon 0.011, phase < 1e-4; local angles differ by the DEM resolution (~8 deg p95)
    assert p95["Local Emission Angle"] < 20 and p95["Local Incidence Angle"] < 20


def test_wac_camera_is_band_dependent_and_round_trips(realdata):
    """Each filter has its own detector rows: band 5 (689 nm) looks ~100 detector lines from band 1 (415 nm)."""
    with open_observation(realdata / "isis" / WAC, "M1181493219") as obs:
        cams = [build_camera(obs.label, obs.ephemeris, None, band=b) for b in (1, 5)]
    s = np.array([3.0, 11.0, 20.0, 11.0])
    l = np.array([2.0, 35.0, 200.0, 340.0])  # odd framelets (1, 3, 15, 25): this cube holds the odd ones
    pts = []
    for cam in cams:
        o, d = cam.rays(s, l)
        p = ray_sphere(o, d, 1737.4)
        bs, bl = cam.ground_to_image(p)
        np.testing.assert_allclose(bs, s, atol=1e-3)
        np.testing.assert_allclose(bl, l, atol=1e-3)
        pts.append(p)
    shift = np.linalg.norm(pts[0] - pts[1], axis=-1)
    assert np.all(shift > 10.0)  # km: 103 detector lines at ~1 mrad/line from ~100 km up -> > 10 km apart


def test_backplanes_cli_writes_phocube_band_names(realdata, tmp_path):
    out = tmp_path / "bp.tif"
    nac = realdata / "isis/M143947267L.cal.echo.crop.cub"
    r = CliRunner().invoke(backplanes_cmd, [str(nac), "--ellipsoid", "-o", str(out)])
    assert r.exit_code == 0, r.output
    with rasterio.open(out) as ds:
        assert ds.descriptions == BAND_NAMES and ds.count == 7 and ds.dtypes[0] == "float32"
        lat, lon = ds.read(6), ds.read(7)
        e, le = ds.read(2), ds.read(4)
    # centre of the crop as the existing NAC camera test (campt) has it; on the sphere local == plain angles
    assert float(lat[199:201, 199:201].mean()) == pytest.approx(35.9800, abs=2e-3)
    assert float(lon[199:201, 199:201].mean()) == pytest.approx(102.6011, abs=2e-3)
    np.testing.assert_array_equal(e, le)
    bad = CliRunner().invoke(backplanes_cmd, [str(nac), "--band", "3", "--ellipsoid", "-o", str(tmp_path / "x.tif")])
    assert bad.exit_code == 2 and "band 3 out of range" in bad.output and not (tmp_path / "x.tif").exists()
