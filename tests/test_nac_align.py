"""align: a DEM displaced from LOLA-like tracks (rendered from one analytic terrain) is put back."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.io.rasters import MOON_CRS
from lunaralbedo.io.geotiff import write_geotiff
from lunaralbedo.nac.synthetic import Terrain

SHIFT = (150.0, -110.0, 15.0)  # east, north, up (m): the DEM's displacement from the truth


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    d = tmp_path_factory.mktemp("align")
    rng = np.random.default_rng(5)
    ter = Terrain.random(rng, size_m=4000.0, n_craters=30)
    h, tr = ter.dem(4000.0, 10.0, SHIFT)
    write_geotiff(d / "dem.tif", h.astype(np.float32), tr, MOON_CRS, nodata=np.nan, dtype="float32")
    pts = ter.tracks(rng, 3500.0, noise_m=0.5)
    # a few gross outliers (e.g. noise shots) that --max-displacement must drop
    bad = pts[:10].copy()
    bad[:, 2] += 0.9
    np.savetxt(d / "lola.csv", np.vstack([pts, bad]), delimiter=",", header="lon,lat,radius", comments="", fmt="%.9f")
    truth, _ = ter.dem(4000.0, 10.0)
    return d, ter, truth, len(pts)


def _run(d, *extra):
    res = CliRunner().invoke(main, ["align", str(d / "dem.tif"), "--reference", str(d / "lola.csv"), "-o",
                                    str(d / "run" / "a"), "--max-displacement", "400", *extra])
    assert res.exit_code == 0, res.output
    return json.loads((d / "run" / "a-report.json").read_text())


def test_point_to_plane_puts_the_dem_back(case):
    d, ter, truth, n = case
    r = _run(d)
    t = r["translation_at_dem_centre"]
    assert r["converged"] and r["inliers"] == n  # the 10 shots 900 m above the surface are outliers
    assert np.hypot(t["east"] + SHIFT[0], t["north"] + SHIFT[1]) < 2.0
    assert abs(t["down"] - SHIFT[2]) < 0.5
    assert r["after"]["median"] <= 1.0 and r["before"]["median"] > 5.0
    assert r["after"]["le90"] < 1.5 and r["after"]["ce90"] < r["before"]["ce90"]
    # transforms are inverses of each other and the matrix file holds the report's matrix
    m = np.loadtxt(d / "run" / "a-transform.txt")
    assert np.allclose(m, r["transform"]) and np.allclose(m @ np.loadtxt(d / "run" / "a-inverse-transform.txt"), np.eye(4), atol=1e-9)
    # per-point errors: lon,lat,radius(km),error(m), the end median equals the report's
    rows = list(csv.DictReader((d / "run" / "a-end_errors.csv").open()))
    assert list(rows[0]) == ["lon", "lat", "radius", "error"] and len(rows) == n
    assert 1737.0 < float(rows[0]["radius"]) < 1738.0
    assert np.median([float(x["error"]) for x in rows]) == pytest.approx(r["after"]["median"], abs=1e-3)
    # the aligned DEM equals the truth surface (inside, away from the moved-in border)
    with rasterio.open(d / "run" / "a-trans_dem.tif") as ds:
        aligned = ds.read(1)
    inner = (slice(40, -40), slice(40, -40))
    diff = aligned[inner] - truth[inner]
    assert np.nanmedian(np.abs(diff)) < 0.5 and np.isfinite(diff).mean() > 0.99
    assert (d / "run" / "a-errors.png").stat().st_size > 5000


def test_point_to_point_and_translation_only(case):
    d, ter, truth, n = case
    r = _run(d, "--method", "point-to-point")
    t = r["translation_at_dem_centre"]
    # point-to-point converges slowly along the surface (documented): looser horizontal bound
    assert np.hypot(t["east"] + SHIFT[0], t["north"] + SHIFT[1]) < 5.0 and abs(t["down"] - SHIFT[2]) < 0.5
    assert r["after"]["median"] <= 1.0
    r = _run(d, "--translation-only")
    m = np.array(r["transform"])
    assert np.allclose(m[:3, :3], np.eye(3))
    t = r["translation_at_dem_centre"]
    assert np.hypot(t["east"] + SHIFT[0], t["north"] + SHIFT[1]) < 2.0 and abs(t["down"] - SHIFT[2]) < 0.5


def test_bad_reference_is_a_clear_error(case, tmp_path):
    d, *_ = case
    (tmp_path / "bad.csv").write_text("lon,lat,radius\n30,-10,1737400\n")
    res = CliRunner().invoke(main, ["align", str(d / "dem.tif"), "--reference", str(tmp_path / "bad.csv"), "-o",
                                    str(tmp_path / "x")])
    assert res.exit_code == 2 and "km" in res.output and not list(tmp_path.glob("x-*"))
    res = CliRunner().invoke(main, ["align", str(d / "dem.tif"), "--reference", str(d / "lola.csv"), "-o",
                                    str(tmp_path / "x"), "--max-displacement", "0.01"])
    assert res.exit_code == 2 and "max-displacement" in res.output
