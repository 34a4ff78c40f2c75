"""The web map in a real browser: headless Chromium (Debian's ``chromium`` + ``chromium-driver``)
driven by Selenium, on the `make demo` results served by ``lunaralbedo view`` and from ``file://``.

Skips with the reason when Chromium, chromedriver or Selenium is missing (``make test``
installs Chromium when it runs as root with apt-get).  No browser is downloaded.
"""
from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_bounds
from rasterio.warp import Resampling, reproject

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
FLAGS = ("--headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking "
         "--disable-component-update --disable-sync --disable-default-apps --window-size=1200,800 "
         "--force-device-scale-factor=1").split()


@pytest.fixture(scope="module")
def browser():
    from selenium import webdriver  # a test dependency (pyproject's `test` extra, installed by `make test`)
    from selenium.webdriver.chrome.service import Service

    if not CHROMIUM or not CHROMEDRIVER:
        pytest.skip("needs headless Chromium and chromedriver (Debian: apt-get install chromium chromium-driver; `make test` does it as root)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    profile = tempfile.mkdtemp(prefix="lunaralbedo-chromium-")
    for flag in [*FLAGS, f"--user-data-dir={profile}"]:
        opts.add_argument(flag)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL", "performance": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(30)
    yield driver
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)


def _network(driver) -> tuple[list[str], list[str]]:
    """(URLs requested, failures) since the last call: failed loads and HTTP statuses >= 400."""
    msgs = [json.loads(e["message"])["message"] for e in driver.get_log("performance")]
    urls = [m["params"]["request"]["url"] for m in msgs if m["method"] == "Network.requestWillBeSent"]
    failed = [f"{m['params'].get('type')}: {m['params']['errorText']}" for m in msgs if m["method"] == "Network.loadingFailed"]
    failed += [f"{m['params']['response']['url']}: HTTP {m['params']['response']['status']}" for m in msgs
               if m["method"] == "Network.responseReceived" and m["params"]["response"].get("status", 200) >= 400]
    return urls, failed


def _console_errors(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def _open(driver, url: str) -> tuple[list[str], list[str], list[str]]:
    """Load the page, wait for the albedo tiles, return (requested URLs, failures, console errors)."""
    driver.get("about:blank")
    _network(driver), _console_errors(driver)  # drain what the browser did at start-up
    driver.get(url)
    _wait(driver, "return document.body.dataset.mapReady === '1'")
    return (*_network(driver), _console_errors(driver))


def _wait(driver, script: str, timeout: float = 20.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for: {script}")


@pytest.fixture(scope="module")
def served(demo_results, browser):
    """``lunaralbedo view RESULTS --port 0 --no-browser`` running; the page loaded from it."""
    proc = subprocess.Popen([sys.executable, "-m", "lunaralbedo.cli", "view", str(demo_results), "--port", "0", "--no-browser"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert "serving" in line, (line, proc.stderr.read() if proc.poll() is not None else "")
        url = line.split(" at ")[1].split()[0]
        urls, failed, console = _open(browser, url)
        yield {"url": url, "urls": urls, "failed": failed, "console": console}
    finally:
        proc.terminate()
        proc.wait(10)


def test_page_loads_from_view_without_failures(served, demo_results):
    origin = served["url"].rsplit("/", 1)[0] + "/"
    assert served["failed"] == [] and served["console"] == []
    assert all(u.startswith((origin, "data:")) for u in served["urls"]), [u for u in served["urls"] if not u.startswith(origin)]
    meta_js = (demo_results / "web" / "data" / "meta.js").read_text()
    meta = json.loads(meta_js.split("=", 1)[1].strip().rstrip(";"))
    # the page opens on the data extent and fetches albedo tiles that export-web wrote
    written = {f"tiles/albedo/{z}/{c}/{r}.png" for z in range(meta["levels"]) for c, r in meta["tiles"][str(z)]}
    assert any(u.endswith(tuple(written)) for u in served["urls"])


def test_map_shows_the_albedo_of_the_cog(served, browser, demo_results):
    """The map area's brightness pattern is the albedo COG's overview at the same extent."""
    from PIL import Image
    from selenium.webdriver.common.by import By

    browser.execute_script("""const a = lunaralbedo; a.map.closePopup();
        a.map.removeLayer(a.overlays.footprints); a.map.removeLayer(a.overlays.graticule);
        document.querySelector('.leaflet-control-container').style.display = 'none';""")
    time.sleep(0.3)
    shot = browser.find_element(By.ID, "map").screenshot_as_png
    gray = np.asarray(Image.open(io.BytesIO(shot)).convert("L"), dtype=np.float64)
    size = browser.execute_script("const s = lunaralbedo.map.getSize(); return [s.x, s.y];")
    west, south, east, north = browser.execute_script("const b = lunaralbedo.map.getBounds(); return [b.getWest(), b.getSouth(), b.getEast(), b.getNorth()];")
    assert list(gray.shape) == size[::-1]
    cog_path = demo_results / "albedo_mosaic.tif"
    with rasterio.open(cog_path) as ds:
        # the COG's first overview; a mosaic smaller than one COG block (the demo's data extent) has none
        overview = {"overview_level": 0} if ds.overviews(1) else {}
    with rasterio.open(cog_path, **overview) as ov:
        cog = np.full(gray.shape, np.nan, np.float32)
        reproject(ov.read(1), cog, src_transform=ov.transform, src_crs=ov.crs, dst_transform=from_bounds(west, south, east, north, size[0], size[1]),
                  dst_crs=ov.crs, src_nodata=np.nan, dst_nodata=np.nan, resampling=Resampling.nearest)
    data = np.isfinite(cog)
    assert data.mean() > 0.05  # the data is in view
    assert gray[data].std() > 10 and np.median(gray[~data]) < 5  # not blank: albedo contrast on black
    # the brightness pattern: both images as means over 8x8-px blocks wholly inside the data, so that the
    # browser's smoothing of magnified tiles and sub-pixel placement do not count
    k = 8
    h, w = (gray.shape[0] // k) * k, (gray.shape[1] // k) * k

    def blocks(a):
        return a[:h, :w].reshape(h // k, k, w // k, k).mean(axis=(1, 3))

    inside = blocks(data.astype(np.float64)) == 1.0
    r = np.corrcoef(blocks(gray)[inside], blocks(np.where(data, cog, 0.0))[inside])[0, 1]
    print(f"screenshot vs COG: r = {r:.4f} over {inside.sum()} blocks of {k}x{k} px")
    assert r > 0.9


def _cells(browser, where: str) -> list[list[str]]:
    """The text of the table cells below ``where``, row by row (header rows left out)."""
    return browser.execute_script("""return [...document.querySelectorAll(arguments[0] + ' table tr')]
        .map(tr => [...tr.querySelectorAll('td')].map(td => td.textContent)).filter(r => r.length);""", where)


def _click_lonlat(browser, lon: float, lat: float):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    el = browser.find_element(By.ID, "map")
    x, y = browser.execute_script("const p = lunaralbedo.map.latLngToContainerPoint([arguments[1], arguments[0]]); return [p.x, p.y];", lon, lat)
    w, h = browser.execute_script("const s = lunaralbedo.map.getSize(); return [s.x, s.y];")
    ActionChains(browser).move_to_element_with_offset(el, round(x - w / 2), round(y - h / 2)).click().perform()


def test_click_reads_back_the_raster_values(served, browser, demo_results):
    with rasterio.open(demo_results / "albedo" / "tile_4E4S.tif") as a, rasterio.open(demo_results / "error" / "tile_4E4S.tif") as e:
        albedo, error, transform = a.read(1), e.read(1), a.transform
    rows, cols = np.nonzero(np.isfinite(albedo))
    k = np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2)  # a pixel inside the data
    r, c = int(rows[k]), int(cols[k])
    lon, lat = transform @ (c + 0.5, r + 0.5)
    seen = []
    for drg in sorted((demo_results.parent / "work" / "DRG").glob("*.tif")):
        with rasterio.open(drg) as ds:
            dr, dc = ds.index(lon, lat)
            if 0 <= dr < ds.height and 0 <= dc < ds.width and np.isfinite(ds.read(1)[dr, dc]) and ds.read(2)[dr, dc] > 0:
                seen.append(drg.name[:11])
    browser.execute_script("lunaralbedo.map.setView([arguments[1], arguments[0]], lunaralbedo.map.getMaxZoom() - 1);", lon, lat)
    time.sleep(0.5)  # the zoom animation
    _click_lonlat(browser, lon, lat)
    _wait(browser, "return document.getElementById('readout').dataset.albedo")
    shown = dict(_cells(browser, "#readout"))
    print("readout", shown, "raster", albedo[r, c], error[r, c])
    assert float(shown["albedo"]) == pytest.approx(float(albedo[r, c]), rel=1e-6)
    assert float(shown["error"]) == pytest.approx(float(error[r, c]), rel=1e-3)
    assert float(shown["lon"].rstrip("°")) == pytest.approx(lon, abs=0.5 * transform.a)
    assert float(shown["lat"].rstrip("°")) == pytest.approx(lat, abs=0.5 * transform.a)
    assert shown[f"images seen ({len(seen)})"].split() == seen and len(seen) >= 2
    assert _network(browser)[1] == [] and _console_errors(browser) == []


def test_report_panel_shows_report_json(served, browser, demo_results):
    report = json.loads((demo_results / "report.json").read_text())
    browser.execute_script("document.querySelectorAll('#report details').forEach(d => d.open = true);")

    def cells(section):
        return _cells(browser, f"#{section}")

    assert [float(q) for _, q in cells("cost")] == report["cost_q"]
    names = list(report["parameters"])
    assert names == ["c1", "c2"]  # the demo is Lunar-Lambert
    assert [[float(v) for v in row[1:]] for row in cells("parameters")] == [list(p) for p in zip(*report["parameters"].values())]
    expo = [line.split(",") for line in (demo_results / "exposure.csv").read_text().split()[1:]]
    assert [(k, float(t), float(t0)) for k, t, t0, _ in cells("exposures")] == [(k, float(t), float(t0)) for k, t, t0 in expo]
    timings = {k: float(v) for k, v in cells("timings")}
    assert {k: timings[k] for k in report["timings_s"]} == report["timings_s"]
    settings = dict(cells("settings"))
    assert float(settings["tr_const"]) == report["settings"]["tr_const"] and settings["drg_dir"] == report["settings"]["drg_dir"]
    assert dict(cells("summary"))["iterations"] == str(report["iterations"])


def test_report_panel_shows_a_camera_response(served, browser, demo_results):
    """A solve run with ``--response`` adds report.json ``response`` and ``residuals``
    (response/solve_hook.py's format, with the nested ``smoothing`` record); the panel shows the curve
    dn -> g and the per-DN residual."""
    from lunaralbedo.response.solve_hook import report_parts
    from lunaralbedo.response.model import observations_from_stack
    from lunaralbedo.response.smoothing import fit_regularised
    from lunaralbedo.response.aligned import fit_report
    from lunaralbedo.response.synthetic import render_stack

    s = render_stack(n_images=4, shape=(60, 60))
    fit = fit_regularised(observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool)), s["exposure"])
    report = json.loads((demo_results / "report.json").read_text())
    report.update(report_parts({"source": "estimate", **fit_report(fit, ["a", "b", "c", "d"])}))
    text = json.dumps(report, allow_nan=False)  # as report.js carries report.json: strict JSON, key order kept
    browser.execute_script("""const d = document.createElement('div'); d.id = 'resp-test'; document.body.append(d);
        LunarPanel.render(d, JSON.parse(arguments[0]), window.LUNARALBEDO_EXPOSURES, window.LUNARALBEDO_META);
        d.querySelectorAll('details').forEach(x => x.open = true);""", text)
    try:
        curve = _cells(browser, "#resp-test #response")
        n = len(report["response"]["dn"])
        assert [(int(a), float(b)) for a, b in curve[:n]] == list(zip(report["response"]["dn"], report["response"]["g"]))
        assert dict(curve[n:])["source"] == "estimate"
        assert browser.execute_script("return document.querySelectorAll('#resp-test #response svg circle').length") == n
        resid = _cells(browser, "#resp-test #residuals")
        m = len(report["residuals"]["dn"])
        assert [float(b) for _, b in resid[:m]] == report["residuals"]["bias_log"]
        assert float(dict(resid[m:])["chi2_per_dof"]) == report["residuals"]["chi2_per_dof"]
    finally:
        browser.execute_script("document.getElementById('resp-test').remove();")


def test_footprint_tooltip_shows_key_and_exposure(served, browser, demo_results):
    """Hovering a footprint shows an image that covers the point, with its exposure from exposure.csv."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    browser.execute_script("const a = lunaralbedo; a.map.closePopup(); a.map.addLayer(a.overlays.footprints); a.map.fitBounds(a.overlays.footprints.getBounds());")
    time.sleep(0.4)
    lon, lat = browser.execute_script("const c = lunaralbedo.overlays.footprints.getBounds().getCenter(); return [c.lng, c.lat];")
    covering = browser.execute_script("return lunaralbedo.showValues(L.latLng(arguments[1], arguments[0])).then(v => v.images);", lon, lat)
    browser.execute_script("lunaralbedo.map.closePopup();")
    el = browser.find_element(By.ID, "map")
    x, y = browser.execute_script("const p = lunaralbedo.map.latLngToContainerPoint([arguments[1], arguments[0]]); return [p.x, p.y];", lon, lat)
    w, h = browser.execute_script("const s = lunaralbedo.map.getSize(); return [s.x, s.y];")
    ActionChains(browser).move_to_element_with_offset(el, -w // 2 + 2, -h // 2 + 2).move_to_element_with_offset(el, round(x - w / 2), round(y - h / 2)).perform()
    tip = _wait(browser, "const t = document.querySelector('.leaflet-tooltip'); return t && t.innerText;")
    expo = {k: float(t) for k, t, _ in (line.split(",") for line in (demo_results / "exposure.csv").read_text().split()[1:])}
    key, shown = tip.split("\n")[:2]
    assert key in covering and len(covering) >= 2, (tip, covering)
    assert float(shown.removeprefix("exposure ")) == pytest.approx(expo[key], rel=1e-6)


def test_page_opens_from_a_file_url(browser, demo_results):
    page = demo_results / "web" / "index.html"
    urls, failed, console = _open(browser, page.as_uri())
    assert failed == [] and console == []
    assert all(u.startswith(("file://", "data:")) for u in urls)
    assert _wait(browser, "return document.querySelectorAll('#cost table tr').length") == len(json.loads((demo_results / "report.json").read_text())["cost_q"]) + 1
