"""sample_data/ is what tools/make_sample_data.py writes (deterministic), small, and physically sane."""
from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import rasterio
import spiceypy

from lunaralbedo.model.geometry import body_fixed, dem_normals, illumination, lonlat_grid

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data"


BINARY_KERNELS = (".bsp", ".bc")


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.suffix not in BINARY_KERNELS}


def _daf_arrays(path: Path) -> list[tuple[tuple, tuple, np.ndarray]]:
    """Every array of a DAF kernel (SPK/CK): its summary (doubles, integers) and its data."""
    handle = spiceypy.dafopr(str(path))
    try:
        spiceypy.dafbfs(handle)
        arrays = []
        while spiceypy.daffna():
            dc, ic = spiceypy.dafus(spiceypy.dafgs(), 2, 6)
            data = np.asarray(spiceypy.dafgda(handle, int(ic[4]), int(ic[5])))
            arrays.append((tuple(dc), tuple(ic[:4]), data))
        return arrays
    finally:
        spiceypy.dafcls(handle)


def test_regenerating_gives_the_committed_files(tmp_path):
    """Text, cubes and rasters byte for byte; SPK/CK segments to 1e-12 relative.

    The binary kernels hold trajectories evaluated with NumPy's sin/cos, whose last bit
    differs between NumPy releases (2.4 moved more of them to SIMD code): the committed
    sim.bsp and a regenerated one differ by 6e-14 km, so bytes are the wrong test there.
    """
    out = tmp_path / "sd"
    subprocess.run([sys.executable, str(REPO / "tools/make_sample_data.py"), "--out", str(out)], check=True,
                   capture_output=True)
    assert _digest(out) == _digest(SAMPLE)
    kernels = sorted(p.relative_to(SAMPLE) for p in SAMPLE.rglob("*") if p.suffix in BINARY_KERNELS)
    assert kernels == sorted(p.relative_to(out) for p in out.rglob("*") if p.suffix in BINARY_KERNELS)
    for rel in kernels:
        new, old = _daf_arrays(out / rel), _daf_arrays(SAMPLE / rel)
        assert [(d, i, a.size) for d, i, a in new] == [(d, i, a.size) for d, i, a in old], rel
        for (_, _, a), (_, _, b) in zip(new, old):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0, err_msg=str(rel))


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
