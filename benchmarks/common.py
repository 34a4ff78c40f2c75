"""Helpers shared by the benchmarks: rendered scenes, a plain read, a solve in a fresh process."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from lunaralbedo.simulate import SceneSpec, render_scene  # noqa: E402


def scene(root: Path, name: str, spec: SceneSpec) -> Path:
    d = root / name
    stamp = d / "spec.json"
    want = json.dumps(spec.__dict__, sort_keys=True)
    if not (stamp.exists() and stamp.read_text() == want):
        shutil.rmtree(d, ignore_errors=True)
        t0 = time.perf_counter()
        render_scene(d, spec)
        stamp.write_text(want)
        print(f"  rendered {name}: {spec.n_images} images of {spec.image_px} px in {time.perf_counter() - t0:.0f} s", flush=True)
    return d


def plain_read_seconds(d: Path, dem: bool = False) -> float:
    """One plain rasterio read of the scene's DRGs (and, with ``dem``, of its DEM too: every raster the solve reads)."""
    import rasterio

    t0 = time.perf_counter()
    for f in sorted((d / "DRG").glob("*.tif")) + (sorted((d / "DEM").glob("*.tif")) if dem else []):
        with rasterio.open(f) as ds:
            ds.read()
    return time.perf_counter() - t0


SOLVE_CHILD = """
import json, os, sys, time
from lunaralbedo.engine.solve import solve
t0 = time.perf_counter()
r = solve(sys.argv[1], out=sys.argv[2], workers=int(sys.argv[3]), plots=False, method=sys.argv[4], max_iter=int(sys.argv[5]), tolerance=float(sys.argv[6]))
dt = time.perf_counter() - t0
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
cpu = os.times()
print(json.dumps({"seconds": dt, "cpu_s": cpu.user + cpu.system, "user_s": cpu.user, "sys_s": cpu.system,
                  "peak_mb": int(hwm.split()[1]) / 1024, "iterations": r.iterations, "timings": r.report["timings_s"]}))
"""


def solve_child(d: Path, out: Path, workers: int = 1, method: str = "overlap", max_iter: int = 10, src: Path | None = None,
                tolerance: float = 0.0, one_cpu: bool = False, settings_name: str = "settings.txt") -> dict:
    """Solve in a fresh process (clean memory figures), the page cache's earlier writes flushed first; returns
    seconds, CPU seconds, peak MB, timings.

    ``src``: run another checkout's ``lunaralbedo`` (e.g. the previous implementation) instead of this one.
    ``tolerance``: the early stop (0: every one of ``max_iter`` passes, the default of the benchmarks).
    ``settings_name``: the settings file of the scene folder ``d`` to solve.
    ``one_cpu``: the process may run on one CPU only (its affinity), so its threads (the cache writer,
    GDAL's compression) share that CPU: the one-core run a 1 -> 2 speed-up compares with.
    """
    shutil.rmtree(out, ignore_errors=True)
    os.sync()  # no write of an earlier solve (its cache, its tiles) still in flight while this one is timed
    first = min(os.sched_getaffinity(0)) if one_cpu else None
    res = subprocess.run(
        [sys.executable, "-c", SOLVE_CHILD, str(d / settings_name), str(out), str(workers), method, str(max_iter), repr(tolerance)],
        capture_output=True, text=True, cwd=src or REPO,
        preexec_fn=(lambda: os.sched_setaffinity(0, {first})) if one_cpu else None,
    )
    if res.returncode:
        raise RuntimeError(res.stderr[-3000:])
    return json.loads(res.stdout.strip().splitlines()[-1])


def mosaic(files, like: Path):
    """The rasters ``files`` merged onto the grid of ``like`` (band 1, NaN where none has a value)."""
    import numpy as np
    import rasterio
    from rasterio.merge import merge

    with rasterio.open(like) as t:
        return merge(sorted(str(f) for f in files), bounds=t.bounds, res=t.res, nodata=np.nan)[0][0]
