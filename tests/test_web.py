"""export-web without a browser: the site's files against the rasters they come from.

The browser tests (test_web_browser.py) load the same site in headless Chromium.
"""
from __future__ import annotations

import base64
import json
import re
import warnings
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.constants import MOON_RADIUS_M
from lunaralbedo.web.render import hillshade, pixel_size_m


def read_js(path: Path, name: str):
    """The JSON value a data script assigns to ``window.NAME``."""
    text = path.read_text()
    m = re.search(rf"window\.{name} = (.*?);\n", text, re.S)
    return json.loads(m.group(1))


def values_of(path: Path) -> dict:
    col, row, payload = re.fullmatch(r"LUNARALBEDO_VALUES\((\d+),(\d+),(.*)\);\n", path.read_text(), re.S).groups()
    p = json.loads(payload)
    arrays = {k: np.frombuffer(base64.b64decode(v), "<f4").reshape(p["height"], p["width"]) for k, v in p.items() if isinstance(v, str)}
    return {"col": int(col), "row": int(row), **arrays}


def test_values_scripts_hold_the_raster_values_exactly(demo_results):
    site = demo_results / "web"
    meta = read_js(site / "data" / "meta.js", "LUNARALBEDO_META")
    finest = meta["levels"] - 1
    fw, fh = meta["finest_size"]
    assert meta["finest_size"] == meta["native_size"]  # the demo's pyramid lands on the native grid
    with rasterio.open(demo_results / "albedo_mosaic.tif") as a, rasterio.open(demo_results / "error_mosaic.tif") as e:
        albedo, error = a.read(1), e.read(1)
        assert a.bounds == pytest.approx(meta["bounds"])
    full = {k: np.full((fh, fw), np.nan, np.float32) for k in ("albedo", "error")}
    ts = meta["tile_size"]
    for col, row in meta["tiles"][str(finest)]:
        v = values_of(site / "data" / "values" / str(col) / f"{row}.js")
        for k in full:
            full[k][row * ts: row * ts + v[k].shape[0], col * ts: col * ts + v[k].shape[1]] = v[k]
    np.testing.assert_array_equal(full["albedo"], albedo)  # NaN where no data on both sides
    np.testing.assert_array_equal(full["error"], error)


def test_albedo_tiles_are_the_kml_tiles(demo_results):
    """export-web and export-kml share the tiling code and the stretch: identical pixels (the web's
    short edge tiles padded to the full tile size with transparent pixels, as Leaflet needs)."""
    web = sorted((demo_results / "web" / "tiles" / "albedo").rglob("*.png"))
    kml = sorted((demo_results / "kml").rglob("*.png"))
    assert [p.relative_to(demo_results / "web" / "tiles" / "albedo") for p in web] == [p.relative_to(demo_results / "kml") for p in kml]
    for a, b in zip(web, kml):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)  # a PNG tile has no georeferencing
            x, y = rasterio.open(a), rasterio.open(b)
        with x, y:
            web_px, kml_px = x.read(), y.read()
        _, h, w = kml_px.shape
        assert web_px.shape[1:] == (256, 256)
        np.testing.assert_array_equal(web_px[:, :h, :w], kml_px)
        assert not web_px[3, h:].any() and not web_px[3, :, w:].any()


def test_footprints_match_the_valid_pixels_of_each_image(demo_results):
    fc = read_js(demo_results / "web" / "data" / "footprints.js", "LUNARALBEDO_FOOTPRINTS")
    exposures = {r.split(",")[0]: float(r.split(",")[1]) for r in (demo_results / "exposure.csv").read_text().split()[1:]}
    drgs = sorted((demo_results.parent / "work" / "DRG").glob("*.tif"))
    assert [f["properties"]["key"] for f in fc["features"]] == [p.name[:11] for p in drgs]
    for f, path in zip(fc["features"], drgs):
        assert f["properties"]["exposure"] == exposures[f["properties"]["key"]]
        area = 0.0
        for poly in f["geometry"]["coordinates"]:
            for i, ring in enumerate(poly):
                x, y = np.array(ring).T
                a = 0.5 * abs(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]))
                area += a if i == 0 else -a
        with rasterio.open(path) as ds:
            valid = np.isfinite(ds.read(1)) & (ds.read(2) > 0)
            pixel = abs(ds.transform.a * ds.transform.e)
        assert area == pytest.approx(valid.sum() * pixel, rel=1e-6)  # traced at full resolution (131 px < 256)


def test_report_script_is_report_json(demo_results):
    site = demo_results / "web" / "data" / "report.js"
    assert read_js(site, "LUNARALBEDO_REPORT") == json.loads((demo_results / "report.json").read_text())
    rows = read_js(site, "LUNARALBEDO_EXPOSURES")
    assert [(r["key"], r["exposure"]) for r in rows] == [
        (line.split(",")[0], float(line.split(",")[1])) for line in (demo_results / "exposure.csv").read_text().split()[1:]
    ]


def test_export_web_without_a_solve_is_a_clear_error(tmp_path):
    (tmp_path / "albedo").mkdir()
    result = CliRunner().invoke(main, ["export-web", str(tmp_path)])
    assert result.exit_code == 2
    assert "report.json" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "web").exists()


def test_view_of_a_folder_without_a_result_is_a_clear_error(tmp_path):
    """``view`` builds the site first; on a folder that holds no solve it stops there: exit 2, one line."""
    (tmp_path / "albedo").mkdir()
    result = CliRunner().invoke(main, ["view", str(tmp_path), "--port", "0", "--no-browser"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "report.json" in errors[0]
    assert not (tmp_path / "web").exists()


def test_view_on_a_port_in_use_is_a_clear_error(tmp_path):
    """A port that cannot be bound is named with a hint, exit 2, and nothing is served."""
    import socket

    site = tmp_path / "site"
    site.mkdir()
    (site / "index.html").write_text("<html></html>")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        result = CliRunner().invoke(main, ["view", str(site), "--port", str(port), "--no-browser"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert f"cannot serve on 127.0.0.1:{port}" in result.output and "--port 0" in result.output
    assert sorted(p.name for p in site.iterdir()) == ["index.html"]


def test_hillshade_of_planes():
    """A plane facing the Sun is fully lit, a flat one at sin(altitude), one facing away dark."""
    rows, cols, d = 5, 6, 100.0
    y, x = np.mgrid[0:rows, 0:cols] * d
    north = -y  # row 0 is north: heights grow northwards when -y grows
    flat = hillshade(np.zeros((rows, cols)), d, d, azimuth_deg=0.0, altitude_deg=30.0)
    np.testing.assert_allclose(flat, np.sin(np.radians(30.0)), rtol=1e-6)
    # sun in the south at altitude 30 deg; a plane rising northwards with slope 60 deg faces it
    facing = hillshade(np.tan(np.radians(60.0)) * north, d, d, azimuth_deg=180.0, altitude_deg=30.0)
    np.testing.assert_allclose(facing, 1.0, rtol=1e-6)
    away = hillshade(-np.tan(np.radians(70.0)) * north, d, d, azimuth_deg=180.0, altitude_deg=30.0)
    assert np.all(away == 0.0)
    east = hillshade(np.tan(np.radians(45.0)) * x, d, d, azimuth_deg=270.0, altitude_deg=45.0)  # rises east, lit from west
    np.testing.assert_allclose(east, 1.0, rtol=1e-6)


def test_pixel_size_on_the_moon_sphere():
    dx, dy = pixel_size_m((0.0, 0.0, 1.0, 60.0), (60, 10))
    assert dy == pytest.approx(np.radians(1.0) * MOON_RADIUS_M)
    assert dx[0] == pytest.approx(np.radians(0.1) * MOON_RADIUS_M * np.cos(np.radians(59.5)))


def test_the_package_carries_leaflet_and_its_licence():
    static = resources.files("lunaralbedo.web") / "static"
    assert "BSD 2-Clause" in (static / "leaflet" / "LICENSE").read_text()
    assert 'version="1.9.4"' in (static / "leaflet" / "leaflet.js").read_text()
    page = (static / "index.html").read_text()
    assert "http" not in page.replace('rel="icon"', "")  # no CDN: every script and style is relative
