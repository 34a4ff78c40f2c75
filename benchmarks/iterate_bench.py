"""The iterate step alone on the strip scene of item 6, in CPU time (docs/performance-history.md, section 1b).

    .venv/bin/python benchmarks/iterate_bench.py [--out bench_out] [--before OTHER_CHECKOUT] [--budget-mb N] [--real-images]

Renders (or reuses) the strip scene of item 6, prepares its tiles once, then times
``iterate_tile`` over every tile after one warm-up pass (steady: 3 passes) and the kernel
alone on the biggest tile, each checkout in a fresh process on its own prepared cache.
``--budget-mb`` sets LUNARALBEDO_STACK_MEMORY_MB (0: stacks re-read every pass).
``--real-images``: also the passes with the default robust weights and with FLOAT_HAZE 1 (the
variants' passes taken in turn, 7 rounds, the median of each) and one
reweight pass (checkouts with the spatial test in the prepare step: its cost there, and the robust
loss's pass only where a pixel has three images), and the ratio of a 10-pass iterate stage with them
to one with the features off (docs/solver.md, "Cost of outliers and haze").
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from common import REPO, scene  # noqa: E402

from lunaralbedo.simulate import SceneSpec  # noqa: E402

#: Passes of item 6's solve (MAX_NUM_ITER): the reweight pass's cost is shared by them.
PASSES = 10
#: Passes of a FLOAT_HAZE solve that take the joint exposure-haze step: the settle rule's least
#: (``model/haze.settled`` needs two steps; item 6's own solve of this strip took 2); the others hold the haze.
JOINT_PASSES = 2

CHILD = r'''
import json, resource, sys
from pathlib import Path
import numpy as np
from lunaralbedo.settings import load_settings
from lunaralbedo.engine.scene import build_scene
from lunaralbedo.engine import prepare, tilework

def cpu():
    t = resource.getrusage(resource.RUSAGE_SELF)
    return t.ru_utime + t.ru_stime

ROUNDS = 7
d, cache = Path(sys.argv[1]), Path(sys.argv[2])
scene = build_scene(load_settings(d / "settings.txt"), False, map_fn=lambda f, xs: list(map(f, xs)))
if len(sys.argv) > 4:  # the stack budget: a Runtime field (older checkouts read LUNARALBEDO_STACK_MEMORY_MB)
    from lunaralbedo.runtime import Runtime
    scene.runtime = Runtime(stack_memory_mb=float(sys.argv[4]))
tiles = range(len(scene.tiles))
for t in tiles:
    prepare.prepare_tile(t, scene=scene, cache_root=cache)
state = tilework.SolveState(np.ones(len(scene.images)), scene.settings.initial_params.copy())
n = sum(np.load(p, mmap_mode="r").shape[0] for p in cache.rglob("weight.npy"))
out = {"observations": n}
run = lambda: [tilework.iterate_tile(t, scene=scene, cache_root=cache, state=state, want_phase=True) for t in tiles]
if len(sys.argv) > 3 and sys.argv[3] == "1":  # outliers and haze: the features off, the defaults, FLOAT_HAZE 1
    from lunaralbedo.engine import robust
    def steady(st):  # a warm-up pass
        global state
        state = st
        run()
    off_state = state
    metas = [tilework.load_meta(tilework.cache_dir(cache, scene, t)) for t in tiles]
    if hasattr(robust, "in_prepare"):  # the spatial test in the prepare step: its cost there, a loss pass if any
        for _ in range(2):  # the second timed: the first compiles
            c0 = cpu()
            for t in tiles:
                for i, _rows in enumerate(metas[t]["blocks"]):
                    arrays = tilework.pixel_stack(tilework.cache_dir(cache, scene, t) / f"block_{i:04d}", cache, scene)
                    if len(arrays["index"]):
                        robust.prepared_block(arrays, scene, scene.tiles[t].width)
            out["spatial_prepare_ns"] = 1e9 * (cpu() - c0) / n
        out["reweight_pass_ns"] = 0.0
        if any(m["spatial"]["loss_possible"] for m in metas):
            for _ in range(2):
                robust.drop_generation(cache, 2)
                c0 = cpu()
                for t in tiles:
                    robust.reweight_tile(t, scene=scene, cache_root=cache, state=tilework.SolveState(state.exposure, state.params, robust=1), gen=2)
                out["reweight_pass_ns"] = 1e9 * (cpu() - c0) / n
    else:
        for _ in range(2):  # the second timed: the first compiles
            robust.drop_generation(cache, 1)  # a solve writes a new generation: no earlier file to unlink in the pass
            c0 = cpu()
            for t in tiles:
                robust.reweight_tile(t, scene=scene, cache_root=cache, state=state, gen=1, pairs=True)  # as a solve: the overlaps for the new start
            out["reweight_pass_ns"] = 1e9 * (cpu() - c0) / n
    variants = {"off_ns": off_state, "default_ns": tilework.SolveState(off_state.exposure, off_state.params, robust=1),
                "haze_ns": tilework.SolveState(off_state.exposure, off_state.params, robust=1, haze=np.zeros(len(scene.images)))}
    try:  # the passes after the haze has settled: held, taken off, no joint step (checkouts before: every pass joint)
        variants["haze_held_ns"] = tilework.SolveState(off_state.exposure, off_state.params, robust=1,
                                                       haze=np.zeros(len(scene.images)), haze_joint=False)
    except TypeError:
        out["haze_held_ns"] = None
    # the variants' passes in turn, ROUNDS times, each the median of its rounds: the machine's load moves them alike
    times = {k: [] for k in variants}
    for st in variants.values():
        steady(st)
    for _ in range(ROUNDS):
        for k, st in variants.items():
            state = st
            c0 = cpu()
            run()
            times[k].append(1e9 * (cpu() - c0) / n)
    out.update({k: float(np.median(v)) for k, v in times.items()})
    state = variants["haze_ns"]
c0 = cpu(); run(); out["first_pass_ns"] = 1e9 * (cpu() - c0) / n
c0 = cpu()
for _ in range(3):
    parts = run()
out["steady_ns"] = 1e9 * (cpu() - c0) / 3 / n
out["q"] = sum(p.q for p in parts)
blk = lambda t: tilework.cache_dir(cache, scene, t) / "block_0000"  # the first block of rows of a tile
t = max(tiles, key=lambda t: np.load(blk(t) / "weight.npy", mmap_mode="r").shape[0])
arrays, meta = tilework.load_stack(blk(t))
obs, _ = tilework._split({k: np.array(v) for k, v in arrays.items()})
m, model = len(obs["weight"]), scene.settings.model
npix = (meta["rows"][1] - meta["rows"][0]) * scene.tiles[t].width

def timed(f, reps=3):
    f(); c0 = cpu()
    for _ in range(reps):
        f()
    return 1e9 * (cpu() - c0) / reps / m

k = {}
if "offsets" not in obs and "chunks" not in obs:  # an image-major cache (before the pixel-major layout): reordered once per tile in memory
    from lunaralbedo.engine import pixelmajor
    pm = tilework.pixel_stack(blk(t), npix, cache)
    names = [x for x in obs if x not in ("pix", "start", "index")]
    k["reorder (once per tile in memory)"] = timed(lambda: pixelmajor.pixel_major(obs, npix, names), 1)
else:
    pm = tilework.pixel_stack(blk(t), cache)
if hasattr(tilework, "TileSums"):  # checkouts before one sums type and the scene's bound model
    s = tilework.TileSums(index=pm["index"], n_params=2, exp_num=np.zeros(len(pm["index"])), exp_den=np.zeros(len(pm["index"])))
    k["fused kernel"] = timed(lambda: tilework.iterate_block(pm, scene.settings, state, True, s))
else:
    from lunaralbedo.model import updates
    s = updates.PassSums(len(pm["index"]), 2, index=pm["index"])
    k["fused kernel"] = timed(lambda: tilework.iterate_block(pm, scene.settings, scene.model, state, True, s))
out["kernels_ns"] = {"tile_observations": m, **k}
out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
'''


def measure(d: Path, cache: Path, src: Path, budget_mb: float | None, real_images: bool = False) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src)}
    args = []
    if budget_mb is not None:
        env["LUNARALBEDO_STACK_MEMORY_MB"] = str(budget_mb)  # read by checkouts before lunaralbedo.runtime
        if (src / "lunaralbedo" / "runtime.py").exists():
            args = [str(budget_mb)]
    res = subprocess.run([sys.executable, "-c", CHILD, str(d), str(cache), "1" if real_images else "0", *args],
                         capture_output=True, text=True, cwd=src, env=env)
    if res.returncode:
        raise RuntimeError(res.stderr[-3000:])
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench_out")
    ap.add_argument("--before", default=None, help="source tree of a previous implementation to measure too")
    ap.add_argument("--real-images", action="store_true",
                    help="also measure the passes with the default robust weights and with FLOAT_HAZE 1, and a reweight pass")
    ap.add_argument("--budget-mb", type=float, default=None, help="LUNARALBEDO_STACK_MEMORY_MB for this checkout")
    args = ap.parse_args()
    root = (REPO / args.out).resolve()
    root.mkdir(exist_ok=True)
    d = scene(root, "strip_2000", SceneSpec(n_images=24, image_px=320, image_rows=2000, res_deg=0.002, tile_size=4.0,
                                            max_num_iter=10, seed=15))
    runs = [("before", Path(args.before).resolve(), None)] if args.before else []
    runs += [("after", REPO, args.budget_mb)]
    for name, src, budget in runs:
        cache = root / f"iterate_cache_{name.split(',')[0]}"  # one cache per checkout: layouts may differ
        r = measure(d, cache, src, budget, real_images=args.real_images)
        print(f"iterate ({name}): {r['steady_ns']:.1f} ns CPU per observation and iteration (first pass "
              f"{r['first_pass_ns']:.0f} ns), kernels on one tile {r['kernels_ns']}, peak {r['peak_rss_mb']:.0f} MB", flush=True)
        if args.real_images:  # the whole iterate stage of a solve of PASSES passes with one reweight pass (the strip has
            off = r["off_ns"]     # no pixel seen by three images: no second one), per observation and pass
            rw = r["reweight_pass_ns"] / PASSES
            held = r.get("haze_held_ns")
            joint = JOINT_PASSES if held is not None else PASSES
            haze = (joint * r["haze_ns"] + (PASSES - joint) * (held or 0.0)) / PASSES
            sp = r.get("spatial_prepare_ns")
            if sp is not None:
                print(f"  the spatial test in the prepare step ({name}): {sp:.1f} ns CPU per observation, once per solve "
                      f"({sp / PASSES:.2f} per pass of {PASSES}, {sp / PASSES / off:.3f} x a features-off pass)", flush=True)
            print(f"  outliers and haze ({name}), CPU ns per observation and pass: features off {off:.2f}; "
                  f"reweight pass {r['reweight_pass_ns']:.1f} per observation (/{PASSES} passes: {rw:.2f}); defaults "
                  f"{r['default_ns']:.2f} + {rw:.2f} = {(r['default_ns'] + rw) / off:.2f} x off; FLOAT_HAZE 1 "
                  f"(joint step {r['haze_ns']:.2f}, haze held {held if held is None else round(held, 2)}; {joint} joint "
                  f"passes of {PASSES}) {haze:.2f} + {rw:.2f} = {(haze + rw) / off:.2f} x off (target <= 1.15)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
