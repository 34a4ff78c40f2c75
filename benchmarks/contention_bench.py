"""Item 11 of ``make bench``: what two workers cost each other on this machine (the ceiling of the 1 -> 2 speed-up).

The same work is run in one process alone, then in two processes at once (each with its
own copy of everything, started together after a warm-up): the plain NumPy pass of item 9,
the strip's prepare step (item 6's scene, all tiles, cast shadows on) and its iterate step
(10 passes over the prepared tiles, the stacks in memory).  Two workers share the memory
bus, the caches beyond L2 and the page cache; if each runs ``s`` times slower beside the
other, no scheduling can make the 2-worker run more than ``2 / s`` times faster than one
worker on this work.  Reported per work: CPU seconds (user + sys) and wall seconds of each
process, the slow-down ``s`` (CPU time together / alone; stalled cycles count as CPU
time) and ``2 / s``.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, os, shutil, sys, time
from pathlib import Path
import numpy as np
kind, scene_dir, work, me, n = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4], int(sys.argv[5])

def cpu():
    t = os.times()
    return t.user + t.system

if kind == "pass":
    a = np.ones(256 * 1024 * 1024, np.float32)
    a.sum()
    run = lambda: [a.sum(dtype=np.float64) for _ in range(3)]
else:
    from lunaralbedo.engine import tilework
    from lunaralbedo.engine.prepare import prepare_tile
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.settings import load_settings
    scene = build_scene(load_settings(scene_dir / "settings.txt"), False, map_fn=lambda f, xs: list(map(f, xs)))
    tiles = range(len(scene.tiles))
    cache = work / f"cache_{me}"
    def prepare():
        shutil.rmtree(cache, ignore_errors=True)
        cache.mkdir(parents=True)
        for t in tiles:
            prepare_tile(t, scene=scene, cache_root=cache)
    prepare()  # warm: numba caches, GDAL, the page cache of the inputs
    if kind == "prepare":
        run = prepare
    else:
        state = tilework.SolveState(np.ones(len(scene.images)), scene.settings.initial_params.copy())
        def run():
            for _ in range(10):
                for t in tiles:
                    tilework.iterate_tile(t, scene=scene, cache_root=cache, state=state, want_phase=True)
        run()  # warm: the stacks read into memory
(work / f"ready_{me}").touch()
while len(list(work.glob("ready_*"))) < n:  # start together
    time.sleep(0.001)
c0, t0 = cpu(), time.perf_counter()
run()
print(json.dumps({"cpu_s": cpu() - c0, "wall_s": time.perf_counter() - t0}))
"""


def _together(kind: str, scene_dir: Path, work: Path, n: int) -> list[dict]:
    """Run ``kind`` in ``n`` processes started together; their figures."""
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, kind, str(scene_dir), str(work), str(i), str(n)],
                              cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in range(n)]
    out = []
    for p in procs:
        so, se = p.communicate()
        if p.returncode:
            raise RuntimeError(se[-3000:])
        out.append(json.loads(so.strip().splitlines()[-1]))
    shutil.rmtree(work, ignore_errors=True)
    return out


def contention(root: Path, figures: dict) -> None:
    """Item 11 (see the module docstring); needs item 6's strip scene (rendered by ``--only 6``)."""
    strip = root / "strip_2000"
    if not (strip / "settings.txt").exists():
        strip = root / "strip_400"  # --quick
    kinds = ["pass"] + (["prepare", "iterate"] if (strip / "settings.txt").exists() else [])
    figures["contention"] = {}
    for kind in kinds:
        alone = _together(kind, strip, root / "contention_work", 1)[0]
        time.sleep(1.0)
        both = _together(kind, strip, root / "contention_work", 2)
        s = sum(b["cpu_s"] for b in both) / 2 / alone["cpu_s"]
        figures["contention"][kind] = {"alone": alone, "together": both, "slowdown_cpu": s, "speedup_ceiling": 2 / s}
        cpus = ", ".join(f"{b['cpu_s']:.2f}" for b in both)
        walls = ", ".join(f"{b['wall_s']:.2f}" for b in both)
        print(f"11. two processes at once, {kind}: alone {alone['cpu_s']:.2f} s CPU ({alone['wall_s']:.2f} s wall); "
              f"together {cpus} s CPU ({walls} s wall): each {s:.2f} x slower, 1 -> 2 speed-up at most {2 / s:.2f} x",
              flush=True)
