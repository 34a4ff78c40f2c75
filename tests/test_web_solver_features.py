"""The web report of a solve that uses the solver's corrections: per-image haze (FLOAT_HAZE 1), image-to-DEM
registration (REGISTER_IMAGES 1), the robust weights (on by default) and shape from shading (REFINE_DEM 1).

One small forward-model strip with every defect these model (haze, hot spots and dropout rows, misregistered
images, a blurred DEM over rough terrain) is solved and exported with the command line; the site is then
checked against the files of the run (``haze.csv``, ``image_offsets.csv``, ``outliers/``, ``DEM/``,
``dem_input/``, ``dem_change/``) and the scene's DRGs, without a browser and in headless Chromium (the
``browser`` fixture and helpers of test_web_browser.py).
"""
from __future__ import annotations

import base64
import csv
import io
import json
import math
import re
import time

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.merge import merge
from rasterio.transform import from_bounds
from rasterio.warp import Resampling, reproject

from lunaralbedo.cli import main
from lunaralbedo.constants import MOON_RADIUS_M
from lunaralbedo.simulate import SceneSpec, render_scene
from test_web_browser import _cells, _click_lonlat, _console_errors, _network, _open, _wait, browser  # noqa: F401

#: 4 images of 40 x 40 px, each column seen by about 3, Sun azimuths spread, fresh craters, the DEM blurred by
#: 2 px, haze of 5-15 DN, 1 % outliers, each image off by up to 1.5 px: 79 x 40 px of result in 2 solver tiles.
SCENE = dict(n_images=4, overlap=2 / 3, image_px=40, res_deg=0.0125, sun_azimuths=(50.0, 90.0, 130.0, 70.0),
             fresh_craters=60.0, dem_relief_m=300.0, tile_size=0.5, seed=3, dem_blur_px=2.0, max_num_iter=10,
             haze_dn=(5.0, 15.0), outlier_fraction=0.01, misregister_px=1.5)
KEYS = {"FLOAT_HAZE": 1, "REGISTER_IMAGES": 1, "REFINE_DEM": 1, "REFINE_DEM_INPUT_BLUR": 2, "REFINE_DEM_MARGIN": 8,
        "REFINE_DEM_WINDOW": 64, "REFINE_DEM_MAX_ITER": 10}
M_PER_DEG = math.radians(1.0) * MOON_RADIUS_M


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """``simulate`` (in Python), ``solve`` and ``export-web`` (the command line) of the strip; the RESULTS_DIR."""
    root = tmp_path_factory.mktemp("webfeatures")
    scene, out = root / "scene", root / "out"
    render_scene(scene, SceneSpec(**SCENE))
    lines = [ln for ln in (scene / "settings.txt").read_text().splitlines() if ln.split()[:1] and ln.split()[0] not in KEYS]
    (scene / "features.txt").write_text("\n".join(lines + [f"{k} {v}" for k, v in KEYS.items()]) + "\n")
    for args in (["solve", str(scene / "features.txt"), "-o", str(out), "--workers", "1", "--quiet"],
                 ["export-web", str(out), "--workers", "1"]):
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 0, res.output
    return out


def _js(path, name):
    return json.loads(re.search(rf"window\.{name} = (.*?);\n", path.read_text(), re.S).group(1))


def _csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _mosaic(run, folder):
    """The tiles of ``folder`` on the web's finest grid (north-up, the site's bounds), and its transform."""
    meta = _js(run / "web" / "data" / "meta.js", "LUNARALBEDO_META")
    w, s, e, n = meta["bounds"]
    fw, fh = meta["finest_size"]
    arr, transform = merge(sorted((run / folder).glob("*.tif")), bounds=(w, s, e, n), res=((e - w) / fw, (n - s) / fh),
                           nodata=np.nan)
    return arr[0], transform


def test_site_has_the_layers_and_values_of_the_run(run):
    meta = _js(run / "web" / "data" / "meta.js", "LUNARALBEDO_META")
    assert [m["id"] for m in meta["layers"]] == ["albedo", "error", "outliers", "hillshade", "hillshade_input", "dem_change"]
    assert meta["values"] == ["albedo", "error", "outliers", "dem_change"]
    assert meta["finest_size"] == meta["native_size"]  # one click = one pixel of the tiles
    # the value scripts hold the outliers' and the height change's tiles exactly (NaN where no data on both sides)
    ts = meta["tile_size"]
    fw, fh = meta["finest_size"]
    shown = {k: np.full((fh, fw), np.nan, np.float32) for k in ("outliers", "dem_change")}
    for col, row in meta["tiles"][str(meta["levels"] - 1)]:
        text = (run / "web" / "data" / "values" / str(col) / f"{row}.js").read_text()
        p = json.loads(re.fullmatch(r"LUNARALBEDO_VALUES\(\d+,\d+,(.*)\);\n", text, re.S).group(1))
        for k in shown:
            shown[k][row * ts: row * ts + p["height"], col * ts: col * ts + p["width"]] = np.frombuffer(
                base64.b64decode(p[k]), "<f4").reshape(p["height"], p["width"])
    for k in shown:
        np.testing.assert_array_equal(shown[k], _mosaic(run, k)[0])
    assert 0 < np.nanmax(shown["outliers"]) <= 1 and np.nanmin(shown["outliers"]) >= 0
    assert np.nanmax(np.abs(shown["dem_change"])) > 10  # the refinement moved the heights by tens of metres


@pytest.fixture(scope="module")
def page(run, browser):  # noqa: F811 (the fixture imported above)
    """The site opened from ``file://``, with what it requested and logged while loading."""
    urls, failed, console = _open(browser, (run / "web" / "index.html").as_uri())
    browser.execute_script("document.querySelectorAll('#report details').forEach(d => d.open = true);")
    return {"urls": urls, "failed": failed, "console": console}


def _table(browser, selector: str) -> list[list[str]]:
    """The text of the cells of the tables matching ``selector``, row by row (header rows left out)."""
    return browser.execute_script("""return [...document.querySelectorAll(arguments[0] + ' tr')]
        .map(tr => [...tr.querySelectorAll('td')].map(td => td.textContent)).filter(r => r.length);""", selector)


def test_panel_shows_haze_csv_and_image_offsets_csv(run, browser, page):  # noqa: F811
    assert page["failed"] == [] and page["console"] == []
    report = json.loads((run / "report.json").read_text())
    haze = _csv(run / "haze.csv")
    rows = _cells(browser, "#haze")
    assert [(k, float(h)) for k, h, _, _ in rows] == [(r["key"], float(r["haze"])) for r in haze]
    bad = set(report["haze_inseparable"])
    assert [flag for *_, flag in rows] == ["NO" if r["key"] in bad else "yes" for r in haze]
    assert [float(se) for _, _, se, _ in rows] == pytest.approx([report["haze_sigma"][r["key"]] for r in haze], rel=5e-3)
    assert browser.execute_script("return document.querySelectorAll('#haze svg circle').length") == len(haze)
    offsets = _csv(run / "image_offsets.csv")
    shown = _table(browser, "#offsets table.offsets-m")
    cols = ("east_m", "north_m", "east_se_m", "north_se_m")
    assert [(k, *map(float, v)) for k, *v in shown] == [(r["key"], *(float(r[c]) for c in cols)) for r in offsets]
    px = _table(browser, "#offsets table.offsets-px")
    assert [(k, float(e), float(n)) for k, e, n in px] == [(k, *v) for k, v in report["registration"]["offsets_px"].items()]
    assert float(dict(_table(browser, "#refine_dem table.kv"))["dem_change_rms_m"]) == report["refine_dem"]["dem_change_rms_m"]
    # every id once: the panel's sections do not take the map's (a second #map was a black 100vh box)
    ids = browser.execute_script("return [...document.querySelectorAll('[id]')].map(e => e.id);")
    assert len(ids) == len(set(ids)), sorted(i for i in ids if ids.count(i) > 1)
    assert _console_errors(browser) == []


def _seen_at(scene, offsets, lon, lat, moved=True):
    """Keys of the DRGs with a valid pixel at (lon, lat) once each is moved by its offset (image_offsets.csv)."""
    seen = []
    for drg in sorted((scene / "DRG").glob("*.tif")):
        key = drg.stem.removesuffix("_drg")
        with rasterio.open(drg) as ds:
            clat = (ds.bounds.bottom + ds.bounds.top) / 2
            e, n = offsets[key] if moved else (0.0, 0.0)
            r, c = ds.index(lon - e / (M_PER_DEG * math.cos(math.radians(clat))), lat - n / M_PER_DEG)
            if 0 <= r < ds.height and 0 <= c < ds.width:
                v, w = ds.read(1)[r, c], ds.read(2)[r, c]
                if np.isfinite(v) and w > 0:
                    seen.append(key)
    return seen


def test_click_reads_the_outliers_and_height_change_of_the_rasters(run, browser, page):  # noqa: F811
    outl, transform = _mosaic(run, "outliers")
    dz = _mosaic(run, "dem_change")[0]
    albedo = _mosaic(run, "albedo")[0]
    # a pixel partly down-weighted (neither 0 nor 1) where the heights moved most
    cand = np.isfinite(albedo) & (outl > 0) & (outl < 1) & np.isfinite(dz)
    r, c = np.unravel_index(np.argmax(np.where(cand, np.abs(dz), -1)), dz.shape)
    lon, lat = transform @ (c + 0.5, r + 0.5)
    browser.execute_script("lunaralbedo.map.setView([arguments[1], arguments[0]], lunaralbedo.map.getMaxZoom() - 1);", lon, lat)
    time.sleep(0.5)  # the zoom animation
    _click_lonlat(browser, lon, lat)
    _wait(browser, "return document.getElementById('readout').dataset.albedo")
    shown = dict(_cells(browser, "#readout"))
    data = browser.execute_script("return Object.assign({}, document.getElementById('readout').dataset);")
    print("readout", shown, "rasters", outl[r, c], dz[r, c])
    assert float(shown["outlier weight lost"]) == pytest.approx(float(outl[r, c]), rel=1e-6)
    assert float(shown["height change (m)"]) == pytest.approx(float(dz[r, c]), rel=1e-6)
    assert np.float32(float(data["outliers"])) == outl[r, c] and np.float32(float(data["dem_change"])) == dz[r, c]
    assert float(shown["albedo"]) == pytest.approx(float(albedo[r, c]), rel=1e-6)
    assert _network(browser)[1] == [] and _console_errors(browser) == []


def test_footprints_and_images_seen_follow_the_image_offsets(run, browser, page):  # noqa: F811
    """The albedo was solved with each image moved by its offset: a click lists the images whose moved
    DRG has a valid pixel there; a point where the stated georeference would give another list is chosen."""
    scene = run.parent / "scene"
    offsets = {r["key"]: (float(r["east_m"]), float(r["north_m"])) for r in _csv(run / "image_offsets.csv")}
    albedo, transform = _mosaic(run, "albedo")
    rows, cols = np.nonzero(np.isfinite(albedo))
    order = np.argsort((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2)
    for k in order[::7]:  # from the centre outwards, the first point where moving the images matters
        lon, lat = transform @ (cols[k] + 0.5, rows[k] + 0.5)
        seen = _seen_at(scene, offsets, lon, lat)
        if seen != _seen_at(scene, offsets, lon, lat, moved=False):
            break
    else:
        pytest.fail("no pixel where the offsets change the images seen")
    got = browser.execute_script("return lunaralbedo.showValues(L.latLng(arguments[1], arguments[0])).then(v => v.images);", lon, lat)
    assert got == seen, (lon, lat, got, seen)
    tips = browser.execute_script("return lunaralbedo.overlays.footprints.getLayers().map(l => l.feature.properties);")
    assert {p["key"]: (p["east_m"], p["north_m"]) for p in tips} == offsets


def _screen(browser, layer):
    """The map area with only ``layer`` shown (overlays, controls and popups hidden), as gray levels."""
    from PIL import Image
    from selenium.webdriver.common.by import By

    browser.execute_script("""const a = lunaralbedo; a.map.closePopup();
        for (const l of Object.values(a.layers)) a.map.removeLayer(l);
        a.map.removeLayer(a.overlays.footprints); a.map.removeLayer(a.overlays.graticule);
        document.querySelector('.leaflet-control-container').style.display = 'none';
        document.body.dataset.shown = ''; a.layers[arguments[0]].once('load', () => { document.body.dataset.shown = arguments[0]; });
        a.map.addLayer(a.layers[arguments[0]]);""", layer)
    _wait(browser, f"return document.body.dataset.shown === '{layer}'")
    time.sleep(0.2)
    return np.asarray(Image.open(io.BytesIO(browser.find_element(By.ID, "map").screenshot_as_png)).convert("L"), np.float64)


def _on_screen(browser):
    """``f(values, transform)``: a raster of the web grid resampled (nearest) onto the map's screen pixels."""
    w, h = browser.execute_script("const s = lunaralbedo.map.getSize(); return [s.x, s.y];")
    bounds = browser.execute_script("const b = lunaralbedo.map.getBounds(); return [b.getWest(), b.getSouth(), b.getEast(), b.getNorth()];")
    screen = from_bounds(*bounds, w, h)

    def resample(values, transform):
        out = np.full((h, w), np.nan, np.float32)
        reproject(values.astype(np.float32), out, src_transform=transform, dst_transform=screen, src_crs="EPSG:4326",
                  dst_crs="EPSG:4326", src_nodata=np.nan, dst_nodata=np.nan, resampling=Resampling.nearest)
        return out

    return resample


def test_outliers_layer_shows_the_weight_lost(run, browser, page):  # noqa: F811
    """The layer's colours (``inferno``: black at 0, pale yellow at 1) follow the ``outliers/`` raster on screen."""
    browser.execute_script("const a = lunaralbedo; a.map.fitBounds(a.layers.albedo.options.bounds);")
    time.sleep(0.4)
    gray = _screen(browser, "outliers")
    frac = _mosaic(run, "outliers")
    shown = _on_screen(browser)(*frac)
    # screen pixels whose 3x3 neighbourhood is one raster pixel (not on a pixel's edge, where placement rounds)
    from scipy import ndimage

    flat = (ndimage.maximum_filter(np.nan_to_num(shown, nan=-1), 3) == ndimage.minimum_filter(np.nan_to_num(shown, nan=-1), 3))
    zero, one, part = flat & (shown == 0), flat & (shown == 1), flat & (shown > 0) & (shown < 1)
    assert zero.sum() > 1000 and one.sum() > 20 and part.sum() > 100
    print(f"outliers layer: gray {np.median(gray[zero]):.0f} where 0, {np.median(gray[one]):.0f} where 1, "
          f"r = {np.corrcoef(gray[part], shown[part])[0, 1]:.3f} between")
    assert np.median(gray[zero]) < 10 and np.median(gray[one]) > 220
    assert np.corrcoef(gray[part], shown[part])[0, 1] > 0.9  # inferno's lightness rises with the value
    assert _network(browser)[1] == [] and _console_errors(browser) == []


def _hillshade(z, transform):
    """The test's own hillshade: cosine between the normal of ``z`` (metres on a lon/lat grid, central differences,
    x east, y north) and a Sun at azimuth 315 deg, 45 deg up (the legend's), clipped at 0."""
    rows = np.arange(z.shape[0])
    lat = np.radians(transform.f + (rows + 0.5) * transform.e)
    dzdr, dzdc = np.gradient(z)
    gx = dzdc / (M_PER_DEG * transform.a * np.cos(lat))[:, None]
    gy = -dzdr / (M_PER_DEG * -transform.e)
    az, alt = math.radians(315.0), math.radians(45.0)
    sun = (math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt))
    return np.clip((-gx * sun[0] - gy * sun[1] + sun[2]) / np.sqrt(gx ** 2 + gy ** 2 + 1), 0, 1)


def test_hillshade_before_and_after_show_the_input_and_refined_dems(run, browser, page):  # noqa: F811
    browser.execute_script("const a = lunaralbedo; a.map.fitBounds(a.layers.albedo.options.bounds);")
    time.sleep(0.4)
    after, before = _screen(browser, "hillshade"), _screen(browser, "hillshade_input")
    on_screen = _on_screen(browser)
    dem, t = _mosaic(run, "DEM")
    hs_after, hs_before = on_screen(_hillshade(dem, t), t), on_screen(_hillshade(_mosaic(run, "dem_input")[0], t), t)
    dz = on_screen(_mosaic(run, "dem_change")[0], t)
    k = 8
    h, w = (after.shape[0] // k) * k, (after.shape[1] // k) * k

    def blocks(a):
        return a[:h, :w].reshape(h // k, k, w // k, k).mean(axis=(1, 3))

    # blocks inside the data, away from its edges (one-sided differences there)
    inside = blocks(np.isfinite(hs_after) & np.isfinite(hs_before) & np.isfinite(dz)) == 1.0
    inside[[0, -1]], inside[:, [0, -1]] = False, False
    assert inside.sum() > 100
    r = lambda a, b: np.corrcoef(blocks(a)[inside], blocks(b)[inside])[0, 1]  # noqa: E731
    r_after, r_before, r_cross = r(after, hs_after), r(before, hs_before), r(after, hs_before)
    # where the heights changed the two layers differ, and by what the two DEMs' shading says
    r_diff = r(np.abs(after - before), np.abs(hs_after - hs_before))
    print(f"screen vs hillshade: after r = {r_after:.3f}, before r = {r_before:.3f}, after vs input {r_cross:.3f}, "
          f"|after - before| r = {r_diff:.3f}, mean |after - before| = {np.abs(after - before)[np.isfinite(dz)].mean():.1f} gray")
    assert r_after > 0.9 and r_before > 0.9 and r_cross < r_after - 0.1
    assert r_diff > 0.6 and np.abs(after - before)[np.isfinite(dz)].mean() > 5
    assert np.nanmax(np.abs(dz)) > 10
    assert _network(browser)[1] == [] and _console_errors(browser) == []


@pytest.mark.parametrize("name, text", [("haze.csv", "key,haze\nSIM-IMG-000,a lot\n"),
                                        ("image_offsets.csv", "key,east_m\nSIM-IMG-000,3\n")])
def test_a_broken_table_is_a_clear_error_and_the_site_stays(run, tmp_path, name, text):
    import shutil

    copy = tmp_path / "out"
    shutil.copytree(run, copy)
    (copy / name).write_text(text)
    before = sorted(p.relative_to(copy) for p in (copy / "web").rglob("*"))
    res = CliRunner().invoke(main, ["export-web", str(copy), "--workers", "1"])
    assert res.exit_code == 2 and "Traceback" not in res.output
    errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and str(copy / name) in errors[0], res.output
    assert sorted(p.relative_to(copy) for p in (copy / "web").rglob("*")) == before


def test_offsets_not_determined_are_empty_cells(tmp_path):
    """``image_offsets.csv`` leaves a standard error empty where it was not determined: None in the page's table."""
    from lunaralbedo.web.data import read_key_table

    path = tmp_path / "image_offsets.csv"
    path.write_text("key,east_m,north_m,east_se_m,north_se_m\nA,-300,12.5,,4\n")
    cols = ("key", "east_m", "north_m", "east_se_m", "north_se_m")
    assert read_key_table(path, cols) == [{"key": "A", "east_m": -300.0, "north_m": 12.5, "east_se_m": None, "north_se_m": 4.0}]
    assert read_key_table(tmp_path / "absent.csv", cols) == []
