#!/usr/bin/env python3
"""NAC tools throughput (docs/nac.md): ``jitreg`` lines/s and ``align`` points/s at realistic sizes.

1. jitreg: an LE/RE overlap strip of ``--lines`` lines (default 52224, one full NAC
   observation) x 200 columns (lronacjitreg's crop width), smoothed-noise texture with a
   sub-pixel shift; default window 32 lines every 8 lines.
2. nacmosaic: a simulated LE/RE pair of full NAC width (2 x 5064 samples, 10 urad pixels,
   135-pixel overlap) and ``--mosaic-lines`` lines (default 4096; a full observation has
   52224), offset given (jitreg is item 1); run as the CLI in a child process for its peak
   RSS, with the default 256-line blocks and with one block of all lines (the memory the
   un-blocked version needed).
3. align: a 1000 x 1000 DEM at 5 m (5 x 5 km) and ``--points`` LOLA-like points
   (about; the track spacing is set from it), point-to-plane ICP, displaced 150 m / 15 m.

Runs in a few minutes on one core; ``--quick`` is a smoke run.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lunaralbedo.nac.align import icp  # noqa: E402
from lunaralbedo.nac.jitreg import register  # noqa: E402
from lunaralbedo.nac.synthetic import Terrain  # noqa: E402


def bench_jitreg(lines: int) -> None:
    from scipy import ndimage

    rng = np.random.default_rng(0)
    g = ndimage.gaussian_filter(rng.standard_normal((lines + 16, 216)), 1.2)
    le = g[8:-8, 8:-8].astype(np.float32)
    re = ndimage.shift(g, (0.4, -0.7), order=3)[8:-8, 8:-8].astype(np.float32)
    t = time.perf_counter()
    r = register(le, re)
    dt = time.perf_counter() - t
    s = r.summary()
    print(f"jitreg: {lines} lines x 200 columns in {dt:.1f} s = {lines / dt:,.0f} lines/s "
          f"({r.good.size} windows, {r.n_good} good; offset {s['sample_offset']:+.3f}, {s['line_offset']:+.3f} px, "
          f"truth +0.700, -0.400)")


def bench_mosaic(lines: int, whole: bool = True) -> None:
    import os
    import subprocess
    import tempfile

    from lunaralbedo.simulate.nacpair import build_pair
    from lunaralbedo.isis.labels import read_label

    with tempfile.TemporaryDirectory() as tmp:
        # NAC-like pixels: 10 urad (focal 1000 mm for the 10 um pitch), square on the ground at ~1.6 km/s
        p = build_pair(Path(tmp), samples=5064, overlap=135, lines=lines, ahead=3.0, focal_mm=1000.0,
                       line_rate=0.0005, rendered=False)
        for block in (256, lines) if whole else (256,):
            out = Path(tmp) / f"m{block}.cub"
            t = time.perf_counter()
            child = subprocess.Popen([sys.executable, "-m", "lunaralbedo.cli", "nacmosaic", str(p.le), str(p.re), "-o",
                                      str(out), "--offset", str(_offset_file(Path(tmp))), "--block-lines", str(block)],
                                     stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(ROOT)})
            _pid, status, usage = os.wait4(child.pid, 0)  # this child's own peak RSS (KiB on Linux)
            dt = time.perf_counter() - t
            if status != 0:
                raise SystemExit(f"nacmosaic failed (status {status})")
            _b, nl, ns = read_label(out).shape
            print(f"nacmosaic: 2 x 5064 x {lines} px -> {ns} x {nl} ideal pixels, blocks of {block} lines: {dt:.1f} s = "
                  f"{lines / dt:,.0f} lines/s, peak RSS {usage.ru_maxrss / 1024:,.0f} MB")


def _offset_file(d: Path) -> Path:
    f = d / "offset.json"
    f.write_text('{"sample_offset": 0.6, "line_offset": 0.4}')
    return f


def bench_align(n_points: int) -> None:
    from scipy.spatial import cKDTree

    from lunaralbedo.model.geometry import body_fixed, dem_normals
    from lunaralbedo.nac.align_files import dem_lonlat
    from lunaralbedo.ingest.dem import DemSource

    rng = np.random.default_rng(1)
    ter = Terrain.random(rng, size_m=5000.0, n_craters=60)
    h, tr = ter.dem(5000.0, 5.0, (150.0, -110.0, 15.0))
    src = DemSource(Path("bench"), h, tr, None, False)
    lon, lat = dem_lonlat(src)
    pts_km = body_fixed(lon, lat, h)
    normals = dem_normals(pts_km).reshape(-1, 3)
    pts = pts_km.reshape(-1, 3) * 1000.0
    spacing = max(20.0, 4400.0 * 4400.0 * 5 / 57.0 / n_points)
    ref = ter.tracks(rng, 4400.0, spacing_m=spacing)
    ref_m = body_fixed(ref[:, 0], ref[:, 1], ref[:, 2] * 1000.0 - 1737400.0) * 1000.0
    t = time.perf_counter()
    tree = cKDTree(pts)
    t_tree = time.perf_counter() - t
    t = time.perf_counter()
    res = icp(ref_m, pts, normals, max_displacement=400.0, tree=tree)
    dt = time.perf_counter() - t
    print(f"align: {len(ref):,} points onto a {h.shape[0]}x{h.shape[1]} DEM: k-d tree {t_tree:.1f} s, ICP "
          f"{res.iterations} iterations in {dt:.1f} s = {len(ref) * res.iterations / dt:,.0f} point-iterations/s "
          f"({len(ref) / dt:,.0f} points/s end to end)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lines", type=int, default=52224)
    ap.add_argument("--points", type=int, default=200000)
    ap.add_argument("--mosaic-lines", type=int, default=4096)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    bench_jitreg(4000 if a.quick else a.lines)
    bench_mosaic(512 if a.quick else a.mosaic_lines)
    bench_align(20000 if a.quick else a.points)
    return 0


if __name__ == "__main__":
    sys.exit(main())
