#!/usr/bin/env python3
"""Screenshots of the web map for docs/ (headless Chromium + chromedriver, Selenium).

    python tools/web_screenshots.py demo_out/albedo docs/
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
    args = ap.parse_args()
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for f in [*FLAGS, f"--user-data-dir={tempfile.mkdtemp()}"]:
        opts.add_argument(f)
    d = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    try:
        d.get((Path(args.results).resolve() / "web" / "index.html").as_uri())
        time.sleep(1.5)
        shots = {
            "web_albedo.png": "const a = lunaralbedo; a.map.fitBounds(a.overlays.footprints.getBounds()); setTimeout(() => a.showValues(L.latLng(-6.1, 6.2)), 400);",
            "web_error.png": "const a = lunaralbedo; a.map.closePopup(); a.map.removeLayer(a.layers.albedo); a.map.addLayer(a.layers.error); a.map.removeLayer(a.overlays.footprints); document.querySelectorAll('#report details').forEach(d => d.open = d.id === 'cost');",
            "web_hillshade.png": "const a = lunaralbedo; a.map.removeLayer(a.layers.error); a.map.addLayer(a.layers.hillshade);",
        }
        for name, script in shots.items():
            d.execute_script(script)
            time.sleep(1.5)
            img = Image.open(io.BytesIO(d.get_screenshot_as_png())).convert("RGB")
            img.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(Path(args.out) / name, optimize=True)
            print(Path(args.out) / name, (Path(args.out) / name).stat().st_size // 1024, "KB")
    finally:
        d.quit()
    return 0


if __name__ == "__main__":
    sys.exit(main())
