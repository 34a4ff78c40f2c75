#!/usr/bin/env python3
"""The cast-shadow test of the prepare step alone, on the narrow-strip scene of ``make bench`` item 6.

Records once (``--record``, with any checkout) the pixel lists the solver's prepare step asks
``TileShadows.shadowed`` about, tile by tile and image by image, with the answers; then times
(CPU time, user + sys) building each tile's :class:`~lunaralbedo.engine.terrain.TileShadows`
(DEM read with its margin, the march's tables) and answering those lists, and checks that
the answers equal the recorded ones.  ``--src DIR`` times another checkout (e.g. the previous release)
in a child process, so before and after run back to back on the same lists::

    PYTHONPATH=$PWD python benchmarks/shadow_bench.py --record          # once (bench_out/strip_2000)
    PYTHONPATH=$PWD python benchmarks/shadow_bench.py --src OTHER_CHECKOUT  # before, then after
    PYTHONPATH=$PWD python benchmarks/shadow_bench.py --low-sun   # fresh craters, Sun 35-80 deg from the zenith

``--low-sun`` marches every pixel of a 600 x 600 px window of an 800 x 800 px cratered DEM
(the figures of docs/photometry.md) with and without the per-block test of
:func:`lunaralbedo.model.march.lit_cells`, checks that the masks are equal, and prints ns per pixel.

Per observation = per image pixel of the scene (24 x 320 x 2000), as item 6 counts.
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "bench_out" / "strip_2000"
CALLS = REPO / "bench_out" / "shadow_calls.pkl"
N_OBS = 24 * 320 * 2000


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def _scene():
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.settings import load_settings

    return build_scene(load_settings(SCENE / "settings.txt"))


def record() -> None:
    """Run the prepare step's gathering once and keep every ``shadowed`` call (tile, image, rows, cols, answer)."""
    from lunaralbedo.engine import observations, terrain

    sc = _scene()
    calls = []
    real = terrain.TileShadows.shadowed

    def spy(self, k, rows, cols, row0=0, col0=0):  # kept as tile pixels: the timing asks with offsets 0
        out = real(self, k, rows, cols, row0, col0)
        calls.append((self._bench_tile, int(k), (rows + row0).astype("int32"), (cols + col0).astype("int32"),
                      out.copy()))
        return out

    terrain.TileShadows.shadowed = spy
    init = terrain.TileShadows.__init__

    def init_spy(self, scene, tile, images):
        init(self, scene, tile, images)
        self._bench_tile = scene.tiles.index(tile)

    terrain.TileShadows.__init__ = init_spy
    for t in range(len(sc.tiles)):
        for _ in observations.gather_blocks(sc, t):
            pass
    with open(CALLS, "wb") as f:
        pickle.dump(calls, f)
    n = sum(len(c[2]) for c in calls)
    print(f"recorded {len(calls)} calls, {n} pixels, {sum(int(c[4].sum()) for c in calls)} shadowed")


def timing(repeat: int) -> dict:
    import numpy as np

    from lunaralbedo.engine.terrain import TileShadows

    sc = _scene()
    with open(CALLS, "rb") as f:
        calls = pickle.load(f)
    by_tile: dict[int, list] = {}
    for c in calls:
        by_tile.setdefault(c[0], []).append(c)
    t = next(iter(by_tile))  # compile / load the numba caches outside the timings
    warm = TileShadows(sc, sc.tiles[t], sc.tile_images[t])
    warm.shadowed(*by_tile[t][0][1:4])
    build, march, differ, pixels = [], [], 0, 0
    for _ in range(repeat):
        b = m = 0.0
        for t, cs in by_tile.items():
            c0 = cpu()
            ts = TileShadows(sc, sc.tiles[t], sc.tile_images[t])
            c1 = cpu()
            outs = [ts.shadowed(k, rows, cols) for _, k, rows, cols, _ in cs]
            c2 = cpu()
            b, m = b + c1 - c0, m + c2 - c1
            differ += sum(int(np.count_nonzero(o != c[4])) for o, c in zip(outs, cs))
        build.append(b)
        march.append(m)
    pixels = sum(len(c[2]) for c in calls)
    b, m = min(build), min(march)
    return {"tiles": len(by_tile), "calls": len(calls), "pixels": pixels, "shadowed": sum(int(c[4].sum()) for c in calls),
            "differ": differ, "build_s": b, "march_s": m, "march_ns_per_pixel": 1e9 * m / pixels,
            "march_ns_per_obs": 1e9 * m / N_OBS, "build_ns_per_obs": 1e9 * b / N_OBS,
            "total_ns_per_obs": 1e9 * (b + m) / N_OBS}


def low_sun(repeat: int) -> None:
    import numpy as np
    from rasterio.transform import Affine

    from lunaralbedo.model import geometry
    from lunaralbedo.model.cast_shadows import MarchGrid
    from lunaralbedo.simulate import truth_dem
    from lunaralbedo.simulate.forward import sun_position

    n, res = 800, 0.0025
    tr = Affine(res, 0, 20.0 - n * res / 2, 0, -res, n * res / 2)
    lon, lat = geometry.lonlat_grid(tr, (n, n))
    dem = truth_dem(lon, lat, (lon.min(), lon.max(), lat.min(), lat.max()), 600.0, fresh_per_square_degree=2.0 / res)
    rows, cols = (a.ravel() for a in np.mgrid[100:700, 100:700])
    centre = geometry.body_fixed(20.0, 0.0, 0.0)
    for inc in (80.0, 60.0, 35.0):
        sun = sun_position(centre, 240.0, 90.0 - inc)
        times, masks = {}, {}
        for cells in (True, False):
            best = np.inf
            for _ in range(repeat):
                grid = MarchGrid(dem, tr)  # each run builds its pyramid, as a tile does
                c0 = time.process_time()
                masks[cells] = grid.march(sun, rows, cols, cells=cells)
                best = min(best, time.process_time() - c0)
            times[cells] = 1e9 * best / rows.size
        assert np.array_equal(masks[False], masks[True])
        print(f"low Sun, incidence {inc:.0f} deg ({masks[True].mean():.0%} shadowed): march of every pixel "
              f"{times[False]:.0f} ns/pixel, with the per-block test {times[True]:.0f} ns/pixel (same mask)", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--record", action="store_true", help="record the pixel lists (runs the prepare gathering once)")
    ap.add_argument("--src", default=None, help="also time this checkout's lunaralbedo first (the 'before')")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs; the least CPU time is reported")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--low-sun", action="store_true", help="the per-block test on and off at low Suns over fresh craters")
    args = ap.parse_args()
    if args.low_sun:
        low_sun(args.repeat)
        return
    if args.record:
        record()
        return
    if args.child:
        print(json.dumps(timing(args.repeat)))
        return
    runs = []
    if args.src:
        runs.append(("before", args.src))
    runs.append(("after", str(REPO)))
    for name, src in runs:
        env = {**os.environ, "PYTHONPATH": src}
        res = subprocess.run([sys.executable, __file__, "--child", "--repeat", str(args.repeat)], env=env, cwd=src,
                             capture_output=True, text=True)
        if res.returncode:
            raise RuntimeError(res.stderr[-3000:])
        r = json.loads(res.stdout.strip().splitlines()[-1])
        print(f"{name} ({src}): {r['pixels']} pixels tested in {r['calls']} calls over {r['tiles']} tiles, "
              f"{r['shadowed']} shadowed, {r['differ']} answers differ from the recorded ones; "
              f"march {r['march_s']:.3f} s CPU = {r['march_ns_per_pixel']:.1f} ns/pixel = {r['march_ns_per_obs']:.1f} ns/obs; "
              f"TileShadows build {r['build_s']:.3f} s = {r['build_ns_per_obs']:.1f} ns/obs; "
              f"total {r['total_ns_per_obs']:.1f} ns/obs", flush=True)


if __name__ == "__main__":
    main()
