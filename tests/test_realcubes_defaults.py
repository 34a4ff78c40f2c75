"""The real LRO cubes out of the box: ``ingest`` with the GLD100 DEM and no resolution or tile option,
then ``solve`` -> ``export-kml`` -> ``export-web``, each a process of its own under a minute and 1 GB.

The resolution ``ingest`` picks is checked against independent figures: for the WAC, ISIS
``phocube``'s latitude/longitude backplanes of band 1 (``back.reduced.cub``: the ground spacing of
neighbouring pixels at the centre); for the NAC, the instantaneous field of view of the LROC IK
(``INS-85600_IFOV``) times the range from the spacecraft to the ground.
"""
from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest
import rasterio

pytestmark = pytest.mark.slow

GLD100 = "WAC_GLD100_V1.0_GLOBAL_with_LOLA_30M_POLE.16bit.reduced.cub"
NAC = "M143947267L.cal.echo.crop.cub"
WAC = "M1181493219CE.vis.odd.reduced.cub"
LIMIT_S, LIMIT_BYTES = 60.0, 2**30


#: Runs the command line with ``sys.argv[2:]`` and writes the process's own peak resident memory (VmHWM, kB) to
#: ``sys.argv[1]`` at exit.  Not ``ru_maxrss`` of the child: on Linux a forked child starts from its parent's
#: peak (the test process's, over 1 GB late in a full run), which is not the command's.
_PEAK = """
import atexit, runpy, sys
out = sys.argv[1]
def peak():
    with open("/proc/self/status") as f:
        kb = [line.split()[1] for line in f if line.startswith("VmHWM")][0]
    with open(out, "w") as f:
        f.write(kb)
atexit.register(peak)
sys.argv = ["lunaralbedo", *sys.argv[2:]]
runpy.run_module("lunaralbedo.cli", run_name="__main__")
"""


def run(*args) -> tuple[str, float, int]:
    """``lunaralbedo ARGS`` in a process of its own: (output, wall seconds, peak resident bytes of that process)."""
    import tempfile

    with tempfile.NamedTemporaryFile("r", suffix=".peak") as peak:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", _PEAK, peak.name, *map(str, args)], stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
        seconds = time.perf_counter() - t0
        assert proc.returncode == 0, proc.stdout[-3000:]
        return proc.stdout, seconds, int(open(peak.name).read()) * 1024


def resolution_written(work) -> float:
    text = (work / "settings.txt").read_text()
    return float(re.search(r"# Resolution ([0-9.e+-]+) m/px", text).group(1))


def ingest_solve_export(isis, cube, work):
    figures = {}
    out, figures["ingest"], mem = run("ingest", isis / cube, "--dem", isis / GLD100, "-o", work)
    figures["ingest_mem"] = mem
    assert "1 of 1" in out or "5 of 5" in out, out
    for step, args in (("solve", (work / "settings.txt", "-o", work / "albedo")),
                       ("export-kml", (work / "albedo",)), ("export-web", (work / "albedo",))):
        out, figures[step], figures[f"{step}_mem"] = run(step, *args)
    for step in ("ingest", "solve", "export-kml", "export-web"):
        assert figures[step] < LIMIT_S, (step, figures)
        assert figures[f"{step}_mem"] < LIMIT_BYTES, (step, figures)
    assert (work / "albedo/kml/doc.kml").is_file() and (work / "albedo/web/index.html").is_file()
    with rasterio.open(work / "albedo/albedo_mosaic.tif") as ds:
        a = ds.read(1, masked=True)
    assert a.count() > 1000 and float(a.min()) > 0
    print(cube, {k: round(v, 2) if k in ("ingest", "solve", "export-kml", "export-web") else f"{v / 2**20:.0f} MB" for k, v in figures.items()})
    return figures


@pytest.mark.usefixtures("clean_spice_pool")
def test_wac_defaults(realdata, tmp_path):
    isis = realdata / "isis"
    work = tmp_path / "wac"
    ingest_solve_export(isis, WAC, work)
    from lunaralbedo.isis.pixels import read_band

    lat, lon = np.radians(read_band(isis / "back.reduced.cub", 4)), np.radians(read_band(isis / "back.reduced.cub", 5))
    r, c = lat.shape[0] // 2, lat.shape[1] // 2
    ds = 1737400 * math.hypot(lat[r, c + 1] - lat[r, c], (lon[r, c + 1] - lon[r, c]) * math.cos(lat[r, c]))
    dl = 1737400 * math.hypot(lat[r + 1, c] - lat[r, c], (lon[r + 1, c] - lon[r, c]) * math.cos(lat[r, c]))
    phocube = (ds + dl) / 2  # 205 m (232 across, 178 along)
    # ours, band 1's: 211.7 m (247 across, 176 along: the push-frame camera's sample spacing is 6 % above phocube's)
    assert resolution_written(work) == pytest.approx(phocube, rel=0.05)
    # `positions` keys and positions are those of ingest's DRGs (one per band)
    from lunaralbedo.io.positions import read_positions

    run("positions", isis / WAC, "--sun", tmp_path / "sun.txt", "--spacecraft", tmp_path / "sc.txt")
    for name, mine in (("sunpos.txt", "sun.txt"), ("spacecraftpos.txt", "sc.txt")):
        ingested, alone = read_positions(work / "meta" / name), read_positions(tmp_path / mine)
        assert list(alone) == list(ingested) == [f"M1181493B0{b}" for b in range(1, 6)]
        assert all(np.array_equal(alone[k], ingested[k]) for k in alone)
    for b in range(1, 6):  # one DRG per band, on the native grid
        with rasterio.open(work / f"DRG/M1181493B0{b}.tif") as drg:
            assert 1737400 * math.radians(drg.res[0]) == pytest.approx(resolution_written(work), rel=1e-5)


@pytest.mark.usefixtures("clean_spice_pool")
def test_nac_defaults(realdata, tmp_path):
    isis = realdata / "isis"
    work = tmp_path / "nac"
    ingest_solve_export(isis, NAC, work)
    ifov = float(re.search(r"INS-85600_IFOV\s*=\s*([0-9.E+-]+)", (realdata / "lro/lro_lroc_v18.ti").read_text()).group(1))
    sc = np.array(open(work / "meta/spacecraftpos.txt").read().split()[1:4], dtype=float)
    with rasterio.open(work / "DEM/dem.tif") as dem:
        h = dem.read(1, masked=True)
        lon0, lat0 = (dem.bounds.left + dem.bounds.right) / 2, (dem.bounds.bottom + dem.bounds.top) / 2
        height = float(h[h.shape[0] // 2, h.shape[1] // 2])
    lo, la, rad = math.radians(lon0), math.radians(lat0), 1737.4 + height / 1000
    ground = rad * np.array([math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)])
    expected = ifov * np.linalg.norm(sc - ground) * 1000  # ~0.56 m across track
    assert resolution_written(work) == pytest.approx(expected, rel=0.08)
    text = (work / "settings.txt").read_text()
    tile = float(re.search(r"^TILE_SIZE\s+(\S+)", text, re.M).group(1))
    px = tile / math.degrees(resolution_written(work) / 1737400)
    assert 1000 <= px <= 2100, px  # tiles of one to two thousand pixels a side, not 121 000
