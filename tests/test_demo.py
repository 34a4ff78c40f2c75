"""`make demo` end to end: sample_data cubes -> ingest -> solve -> export-kml, compared with the truth."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import rasterio

REPO = Path(__file__).resolve().parents[1]


def test_demo_runs_from_cubes_to_kml_and_matches_truth(tmp_path):
    out = tmp_path / "demo"
    res = subprocess.run([sys.executable, str(REPO / "tools" / "run_demo.py"), "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]
    rmse = float(re.search(r"albedo relative RMSE\s+([\d.]+) %", res.stdout).group(1))
    expo = float(re.search(r"worst exposure error\s+([\d.]+) %", res.stdout).group(1))
    assert rmse < 2.5 and expo < 1.0, res.stdout
    for p in ("work/settings.txt", "work/meta/sunpos.txt", "albedo/report.json", "albedo/kml/doc.kml", "albedo/albedo_mosaic.tif"):
        assert (out / p).exists(), p
    with rasterio.open(out / "albedo" / "kml" / "doc.kml") as ds:  # GDAL's KMLSUPEROVERLAY driver
        assert ds.driver == "KMLSUPEROVERLAY" and ds.width > 0
    assert not (REPO / "sample_data" / "DRG").exists()  # nothing written into the inputs
