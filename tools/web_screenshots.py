#!/usr/bin/env python3
"""Screenshots of the web map for docs/ (headless Chromium + chromedriver, Selenium).

    python tools/web_screenshots.py demo_out/albedo docs/
    python tools/web_screenshots.py --solver-features RESULTS docs/   # a FLOAT_HAZE, REGISTER_IMAGES, REFINE_DEM run

The second form shoots the report panel's haze and image offsets over the outliers layer
(web_features_panel.png), the height change layer with a click's values (web_dem_change.png) and the
hillshade before and after REFINE_DEM side by side (web_hillshade_before_after.png).
"""
from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image
from selenium import webdriver
from selenium.webdriver.chrome.service import Service

FLAGS = ("--headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking "
         "--disable-component-update --disable-sync --window-size=1280,760 --force-device-scale-factor=1").split()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("results")
    ap.add_argument("out")
    ap.add_argument("--solver-features", action="store_true", help="the shots of a run with haze, registration, SfS")
    args = ap.parse_args()
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for f in [*FLAGS, f"--user-data-dir={tempfile.mkdtemp()}"]:
        opts.add_argument(f)
    d = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    try:
        d.get((Path(args.results).resolve() / "web" / "index.html").as_uri())
        time.sleep(1.5)
        if args.solver_features:
            return _solver_features(d, Path(args.out))
        shots = {
            "web_albedo.png": "const a = lunaralbedo; a.map.fitBounds(a.overlays.footprints.getBounds()); setTimeout(() => a.showValues(L.latLng(-6.1, 6.2)), 400);",
            "web_error.png": "const a = lunaralbedo; a.map.closePopup(); a.map.removeLayer(a.layers.albedo); a.map.addLayer(a.layers.error); a.map.removeLayer(a.overlays.footprints); document.querySelectorAll('#report details').forEach(d => d.open = d.id === 'cost');",
            "web_hillshade.png": "const a = lunaralbedo; a.map.removeLayer(a.layers.error); a.map.addLayer(a.layers.hillshade);",
        }
        for name, script in shots.items():
            d.execute_script(script)
            time.sleep(1.5)
            _save(Image.open(io.BytesIO(d.get_screenshot_as_png())), Path(args.out) / name)
    finally:
        d.quit()
    return 0


def _save(img: Image.Image, path: Path) -> None:
    img.convert("RGB").quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    print(path, path.stat().st_size // 1024, "KB")


def _solver_features(d, out: Path) -> int:
    show = """const a = lunaralbedo; a.map.closePopup(); for (const l of Object.values(a.layers)) a.map.removeLayer(l);
        a.map.addLayer(a.layers[arguments[0]]); a.map.fitBounds(a.layers.albedo.options.bounds);
        document.querySelectorAll('#report details').forEach(x => x.open = arguments[1].includes(x.id));
        document.getElementById(arguments[1][0]).scrollIntoView();"""
    d.set_window_size(1280, 1040)  # room for the haze and offsets sections
    d.execute_script(show, "outliers", ["haze", "offsets"])
    time.sleep(1.5)
    _save(Image.open(io.BytesIO(d.get_screenshot_as_png())), out / "web_features_panel.png")
    d.execute_script(show, "dem_change", ["refine_dem", "outliers"])
    d.execute_script("const c = lunaralbedo.map.getCenter(); lunaralbedo.showValues(c);")
    time.sleep(1.5)
    _save(Image.open(io.BytesIO(d.get_screenshot_as_png())), out / "web_dem_change.png")
    d.execute_script("""const a = lunaralbedo; a.map.removeLayer(a.overlays.footprints); a.map.removeLayer(a.overlays.graticule);
        document.querySelector('.leaflet-control-container').style.display = 'none';""")
    pair = []
    for layer in ("hillshade_input", "hillshade"):
        d.execute_script(show, layer, ["summary"])
        time.sleep(1.5)
        from selenium.webdriver.common.by import By

        pair.append(Image.open(io.BytesIO(d.find_element(By.ID, "map").screenshot_as_png)).convert("RGB"))
    w, h = pair[0].size
    both = Image.new("RGB", (2 * w + 8, h), "white")
    both.paste(pair[0], (0, 0))
    both.paste(pair[1], (w + 8, 0))
    _save(both.crop((0, h // 5, 2 * w + 8, h - h // 5)), out / "web_hillshade_before_after.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
