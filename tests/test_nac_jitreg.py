"""jitreg: LE/RE offset and jitter series recovered from rendered pairs and from the real NAC crop."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.io.geotiff import write_geotiff
from lunaralbedo.isis.write import write_cube
from lunaralbedo.nac.jitreg import register
from lunaralbedo.nac.synthetic import WaveTexture, jitter_pair
from rasterio.transform import Affine


def sinusoid(lines, mean: float, amplitude: float, period: float, phase: float = 0.0) -> np.ndarray:
    """A jitter series ``mean + amplitude * sin(2 pi line / period + phase)`` (pixels)."""
    return mean + amplitude * np.sin(2 * np.pi * np.asarray(lines, dtype=np.float64) / period + phase)


LINES, SAMPLES, OVERLAP = 1200, 280, 100


@pytest.fixture(scope="module")
def jitter_case():
    rng = np.random.default_rng(17)
    tex = WaveTexture.random(rng, n_waves=150)
    rows = np.arange(LINES)
    so = sinusoid(rows, 2.37, 0.3, 333.0)
    lo = sinusoid(rows, -1.21, 0.2, 517.0, 1.0)
    le, re = jitter_pair(tex, LINES, SAMPLES, OVERLAP, so, lo, noise=0.02, rng=rng)
    return le, re, so, lo


def test_mean_offset_and_jitter_series(jitter_case):
    le, re, so, lo = jitter_case
    r = register(le, re, window=32, step=8)
    s = r.summary()
    c, g = r.lines, r.good
    assert r.n_good >= 0.95 * g.size
    # the overlap is the middle OVERLAP columns (rendered with NaN outside each CCD)
    assert abs(r.columns[0] - (SAMPLES - OVERLAP) // 2) <= 1 and r.columns[1] - r.columns[0] >= OVERLAP - 2
    assert abs(s["sample_offset"] - so[c].mean()) < 0.05
    assert abs(s["line_offset"] - lo[c].mean()) < 0.05
    rms_s = np.sqrt(np.mean((r.sample_offset[g] - so[c][g]) ** 2))
    rms_l = np.sqrt(np.mean((r.line_offset[g] - lo[c][g]) ** 2))
    assert rms_s < 0.1 and rms_l < 0.1, (rms_s, rms_l)
    # the standard error is honest: the mean error is within 3 of them
    assert abs(s["sample_offset"] - so[c].mean()) < 3 * s["sample_offset_stderr"] + 0.02


def test_cli_outputs_and_asp_log(jitter_case, tmp_path):
    le, re, so, lo = jitter_case
    for name, img in (("le", le), ("re", re)):
        write_geotiff(tmp_path / f"{name}.tif", img, Affine.identity(), None, nodata=np.nan, dtype="float32")
    res = CliRunner().invoke(main, ["jitreg", str(tmp_path / "le.tif"), str(tmp_path / "re.tif"), "-o",
                                    str(tmp_path / "out/reg"), "--output-log", str(tmp_path / "flat.txt")])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "out/reg.json").read_text())
    rows = list(csv.DictReader((tmp_path / "out/reg-lines.csv").open()))
    assert list(rows[0]) == ["line", "sample_offset", "line_offset", "correlation"]
    lines = np.array([int(r["line"]) for r in rows])
    s_off = np.array([float(r["sample_offset"]) for r in rows])
    assert np.sqrt(np.mean((s_off - so[lines]) ** 2)) < 0.1
    assert (tmp_path / "out/reg-jitter.png").stat().st_size > 5000
    # ASP's log: the averages lronac2mosaic.py parses, with ASP's (opposite) sign
    log = (tmp_path / "flat.txt").read_text().splitlines()
    avg = {ln.split(":")[0].strip("# ").strip(): ln for ln in log if "Average" in ln}
    parse = lambda ln: float(ln[ln.rfind("Offset:") + 7:ln.rfind("StdDev:")])  # noqa: E731 (lronac2mosaic's rule)
    assert parse(avg["Average Sample Offset"]) == pytest.approx(-summary["sample_offset"], abs=1e-3)
    assert parse(avg["Average Line Offset"]) == pytest.approx(-summary["line_offset"], abs=1e-3)
    row = next(ln for ln in log if ln and not ln.startswith("#"))
    assert row.count(",") == 2 and "Count =" in row and "Std =" in row


def test_real_nac_crop_against_shifted_copy(realdata, tmp_path):
    """The real LRO NAC crop registered against itself shifted by (1.6, -2.3) px (cubic spline shift)."""
    from scipy import ndimage

    from lunaralbedo.isis.pixels import read_band

    img = read_band(realdata / "isis" / "M143947267L.cal.echo.crop.cub")
    assert np.isfinite(img).all()
    so, lo = 1.6, -2.3
    # RE(x, y) = LE(x + so, y + lo): ndimage.shift moves content by +shift, so shift by (-lo, -so)
    shifted = ndimage.shift(img, (-lo, -so), order=3, mode="nearest")
    write_cube(tmp_path / "re.cub", shifted, {})
    res = CliRunner().invoke(main, ["jitreg", str(realdata / "isis" / "M143947267L.cal.echo.crop.cub"),
                                    str(tmp_path / "re.cub"), "-o", str(tmp_path / "reg"), "--window", "24"])
    assert res.exit_code == 0, res.output
    s = json.loads((tmp_path / "reg.json").read_text())
    assert s["good_matches"] >= 30
    assert s["sample_offset"] == pytest.approx(so, abs=0.05)
    assert s["line_offset"] == pytest.approx(lo, abs=0.05)


def test_bad_input_is_a_clear_error(tmp_path):
    write_cube(tmp_path / "a.cub", np.ones((50, 40)), {})
    write_cube(tmp_path / "b.cub", np.ones((60, 40)), {})
    res = CliRunner().invoke(main, ["jitreg", str(tmp_path / "a.cub"), str(tmp_path / "b.cub"), "-o", str(tmp_path / "x")])
    assert res.exit_code == 2 and "one size" in res.output and not (tmp_path / "x.json").exists()
    res = CliRunner().invoke(main, ["jitreg", str(tmp_path / "nope.cub"), str(tmp_path / "b.cub"), "-o", str(tmp_path / "x")])
    assert res.exit_code == 2 and "not found" in res.output
