"""sample_data/ is what tools/make_sample_data.py writes (deterministic), small, and physically sane."""
from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import rasterio

from lunaralbedo.model.geometry import body_fixed, dem_normals, illumination, lonlat_grid

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data"


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_regenerating_gives_the_committed_files(tmp_path):
    out = tmp_path / "sd"
    subprocess.run([sys.executable, str(REPO / "tools/make_sample_data.py"), "--out", str(out)], check=True,
                   capture_output=True)
    assert _digest(out) == _digest(SAMPLE)


def test_sample_data_is_small_and_well_lit():
    total = sum(p.stat().st_size for p in SAMPLE.rglob("*") if p.is_file())
    assert total < 10e6
    truth = json.loads((SAMPLE / "truth/truth.json").read_text())
    assert len(truth["images"]) == 5 and (truth["c1"], truth["c2"]) == (1.4, 0.5)
    with rasterio.open(SAMPLE / "dem/dem.tif") as ds:
        h, t = ds.read(1).astype(float), ds.transform
        assert ds.shape == (300, 300)
    with rasterio.open(SAMPLE / "truth/albedo.tif") as ds:
        alb = ds.read(1)
        assert ds.transform == t
    assert 0.05 <= alb.min() and alb.max() <= 0.25
    p = body_fixed(*lonlat_grid(t, h.shape), h)
    n = dem_normals(p)
    for im in truth["images"].values():
        cos_i, cos_e, _ = illumination(p, n, im["sun_km"], im["spacecraft_km"])
        assert cos_i.min() > 0.5  # incidence < 60 degrees everywhere, far from the solver's cos i = 0.3 cut
        assert cos_e.min() > 0.5
        assert 0.7 < im["exposure"] < 1.3
