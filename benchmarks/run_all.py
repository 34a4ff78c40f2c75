#!/usr/bin/env python3
"""`make bench`: throughput, peak memory, worker speed-up and convergence of the solver.

Prints, in one run on this machine:

1. solve throughput (pixel-observations/s = image pixels over the box x iterations) for a
   forward-model scene of 50 images of 2000x2000 px, 10 iterations, and the time of one
   plain rasterio read of the same images (ratio solve / read);
2. peak resident memory (VmHWM) of a solve for 25, 50 and 100 images;
3. speed-up 1 -> 2 workers, and from one worker confined to one CPU (its cache writer and GDAL
   threads then share that CPU, as the one-worker runs did before they had threads) to 2 workers;
4. iterations needed to get within 1 % of the converged albedo, default method vs --method seed;
5. camera response fit (Kim et al., ``--response``): seconds per million observations
   (one 8-image stack of ~1 M observations; ``benchmarks/response_bench.py`` has the
   accuracy comparison with OpenCV and more sizes);
6-10. the scale scenes (``benchmarks/scale_bench.py``): the narrow strip at legacy tile
   size, exposure initialisation for 10^3-10^5 images, orthoprojection, memory bandwidth,
   peak memory of one 4000 x 4000 px tile under 16 images (blocks of rows);
11. what two workers cost each other (``benchmarks/contention_bench.py``): the plain pass, the
   strip's prepare and iterate steps alone and in two processes at once, and the ceiling of
   the 1 -> 2 speed-up that follows (needs item 6's scene);
12. any tile size (``benchmarks/scale_bench.py``): peak memory of one 12000 x 12000 px tile
   under 3 narrow images (outputs and cast-shadow DEM a block of rows at a time);
13. the floor of the strip's prepare step on one CPU (``benchmarks/floor_bench.py``): what any
   code must spend per observation to decode the inputs, compute the geometry, keep the
   observations and write the DEM and weight-sum tiles, into new memory and into memory used
   again; then with the solver's own features added at their cheapest (the model layer, the
   exposure initialisation's logarithms, cast shadows by a sweep) (needs item 6's scene and outputs);
14. the image-to-DEM registration (``benchmarks/registration_bench.py``): time per image per Gauss-Newton
   iteration and per level, peak memory, offsets against the truth of a misregistered strip.
15. shape from shading (``benchmarks/sfs_bench.py``, docs/sfs.md): the heights' and the albedo's errors on
   the forward strip with a blurred DEM, ns per observation per evaluation of the height cost, the whole
   refinement against a plain solve of the same scene, peak memory.

Scenes are rendered once into ``bench_out/`` and reused.  ``--quick`` uses smaller scenes
(a smoke run, not the figures of docs/performance.md).
"""
from __future__ import annotations

import argparse
import glob
import json
import platform
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from common import plain_read_seconds, scene, solve_child  # noqa: E402
from lunaralbedo.simulate import SceneSpec  # noqa: E402


def observations(spec: SceneSpec) -> int:
    return spec.n_images * spec.image_px * spec.image_px


def albedo_of(out: Path, bounds, res) -> np.ndarray:
    from rasterio.merge import merge

    mos, _ = merge(sorted(glob.glob(str(out / "albedo" / "*.tif"))), bounds=bounds, res=res, nodata=np.nan, dtype="float32")
    return mos[0]


def rel_diff(a: np.ndarray, ref: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(ref)
    s = np.sum(a[ok] * ref[ok]) / np.sum(a[ok] ** 2)  # one global scale is free (A*T)
    return float(np.sqrt(np.mean(((s * a[ok] - ref[ok]) / ref[ok]) ** 2)))


def iterations_to_converge(d: Path, root: Path, method: str, ref: np.ndarray, bounds, res, limit: int) -> int | None:
    def err(n):
        out = root / f"conv_{method}"
        solve_child(d, out, method=method, max_iter=n)
        return rel_diff(albedo_of(out, bounds, res), ref)

    lo, hi, n = 0, None, 1
    while n <= limit:
        if err(n) < 0.01:
            hi = n
            break
        lo, n = n, n * 2
    if hi is None:
        return None
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if err(mid) < 0.01 else (mid, hi)
    return hi


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench_out")
    ap.add_argument("--quick", action="store_true", help="small scenes (smoke run)")
    ap.add_argument("--json", default=None, help="also write the figures as JSON here")
    ap.add_argument("--only", default="1,2,3,4,5,6,7,8,9,10,11,12,13,14,15", help="comma-separated items to run (3 comes with 1)")
    ap.add_argument("--before", default=None, help="source tree of a previous implementation to measure too (items 6, 8, 10, 12)")
    args = ap.parse_args()
    root = (REPO / args.out).resolve()
    root.mkdir(exist_ok=True)
    q = args.quick
    big_px, mem_px = (400, 200) if q else (2000, 1000)
    res_deg = 0.0005 if not q else 0.0025
    figures: dict = {"machine": f"{platform.machine()}, {__import__('os').cpu_count()} cores, Python {platform.python_version()}"}
    print(f"lunaralbedo benchmarks ({'quick' if q else 'full'}) on {figures['machine']}", flush=True)

    only = {int(x) for x in args.only.split(",")}
    if only & {1, 3}:
        throughput(root, q, figures, big_px, res_deg)
    if 2 in only:
        memory(root, figures, mem_px, res_deg)
    if 4 in only:
        convergence(root, q, figures)
    if 5 in only:
        response_fit(q, figures)
    from scale_bench import run_scale_items  # noqa: E402  (items 6-10)

    run_scale_items(root, q, figures, only, Path(args.before).resolve() if args.before else None)
    if 11 in only:
        from contention_bench import contention  # noqa: E402

        contention(root, figures)
    if 13 in only:
        from floor_bench import prepare_floor  # noqa: E402

        prepare_floor(root, q, figures)
    if 14 in only:
        from registration_bench import registration_cost  # noqa: E402

        registration_cost(root, q, figures)
    if 15 in only:
        from sfs_bench import run as sfs_run  # noqa: E402

        f = figures["sfs"] = sfs_run(root, {}, False)
        rd = f["refine"]["rounds"]
        print(f"15. shape from shading (REFINE_DEM 1, docs/sfs.md): heights {f['rms_m']:.1f} m RMS against the truth "
              f"(given {f['given_rms_m']:.1f} m, x{f['height_ratio']:.2f}); albedo {100 * f['albedo_refine']:.2f} % "
              f"(plain {100 * f['albedo_plain']:.2f} %); {rd[-1]['ns_per_observation_evaluation']} ns per observation per "
              f"evaluation of the height cost (one core); whole run {f['time_ratio']:.0f}x the plain solve; peak "
              f"{f['peak_mb_refine']:.0f} MB", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2))
    return 0


def throughput(root: Path, q: bool, figures: dict, big_px: int, res_deg: float) -> None:
    """Items 1 and 3: pixel-observations per second, ratio to one plain read, 1 -> 2 workers."""
    spec = SceneSpec(n_images=50, image_px=big_px, res_deg=res_deg, tile_size=round(big_px * res_deg / 2, 6), max_num_iter=10, seed=50)
    d = scene(root, f"throughput_{big_px}", spec)
    read_s = min(plain_read_seconds(d) for _ in range(2))
    runs = {w: solve_child(d, root / f"out_w{w}", workers=w) for w in (1, 2)}
    one_core = solve_child(d, root / "out_w1_one_cpu", workers=1, one_cpu=True)  # the 1-worker run on one CPU
    obs = observations(spec) * 10
    figures["throughput"] = {
        "images": spec.n_images, "image_px": big_px, "iterations": 10, "pixel_observations": obs,
        "plain_read_s": read_s,
        **{f"solve_s_{w}w": r["seconds"] for w, r in runs.items()},
        **{f"cpu_s_{w}w": r["cpu_s"] for w, r in runs.items()},  # the solving process only (not Dask workers)
        **{f"peak_mb_{w}w": r["peak_mb"] for w, r in runs.items()},  # the solving process only
        **{f"timings_{w}w": r["timings"] for w, r in runs.items()},
        "obs_per_s_1w": obs / runs[1]["seconds"], "obs_per_s_2w": obs / runs[2]["seconds"],
        "ratio_solve_over_read_1w": runs[1]["seconds"] / read_s, "ratio_solve_over_read_2w": runs[2]["seconds"] / read_s,
        "speedup_1_to_2": runs[1]["seconds"] / runs[2]["seconds"],
        "solve_s_1w_one_cpu": one_core["seconds"], "timings_1w_one_cpu": one_core["timings"],
        "speedup_one_cpu_to_2": one_core["seconds"] / runs[2]["seconds"],
    }
    t = figures["throughput"]
    print(f"1. throughput: {obs:,} pixel-observations; plain read {read_s:.2f} s", flush=True)
    for w in (1, 2):
        print(f"   {w} worker(s): solve {runs[w]['seconds']:.1f} s wall ({runs[w]['cpu_s']:.1f} s CPU, peak "
              f"{runs[w]['peak_mb']:.0f} MB of the solving process) "
              f"= {obs / runs[w]['seconds'] / 1e6:.1f} M obs/s, "
              f"solve/read = {runs[w]['seconds'] / read_s:.1f}  (stages: {runs[w]['timings']})", flush=True)

    print(f"   1 worker on one CPU (its threads share it): solve {one_core['seconds']:.1f} s wall "
          f"(stages: {one_core['timings']})", flush=True)
    print(f"3. speed-up 1 -> 2 workers: {t['speedup_1_to_2']:.2f}x; one CPU -> two CPUs (1 worker on one CPU -> "
          f"2 workers): {t['speedup_one_cpu_to_2']:.2f}x", flush=True)


def memory(root: Path, figures: dict, mem_px: int, res_deg: float) -> None:
    """Item 2: peak resident memory (VmHWM) of a solve for 25, 50 and 100 images."""
    figures["memory"] = {}
    for n in (25, 50, 100):
        ms = SceneSpec(n_images=n, image_px=mem_px, res_deg=res_deg * 2, tile_size=round(mem_px * res_deg, 6), max_num_iter=3, seed=n)
        r = solve_child(scene(root, f"memory_{n}_{mem_px}", ms), root / "out_mem", max_iter=3)
        figures["memory"][n] = {"peak_mb": r["peak_mb"], "seconds": r["seconds"], "image_px": mem_px}
        print(f"2. peak memory, {n:3d} images of {mem_px} px: {r['peak_mb']:.0f} MB ({r['seconds']:.0f} s)", flush=True)


def convergence(root: Path, q: bool, figures: dict) -> None:
    """Item 4: iterations to within 1 % of the converged albedo, per method.

    Two references: the default method's converged albedo (200 iterations), and each
    method's own answer after many iterations — the seed's undamped phase step walks
    (c1, c2) along a nearly flat valley of Q, so it settles on a different albedo.
    """
    cs = SceneSpec(seed=71)
    dc = scene(root, "convergence", cs)
    solve_child(dc, root / "conv_ref", max_iter=200)
    import rasterio

    with rasterio.open(dc / "truth" / "albedo.tif") as tds:
        bounds, res = tds.bounds, (tds.transform.a, -tds.transform.e)
    ref = albedo_of(root / "conv_ref", bounds, res)
    long_run = 256 if q else 4096
    solve_child(dc, root / "conv_seed_ref", method="seed", max_iter=long_run)
    seed_ref = albedo_of(root / "conv_seed_ref", bounds, res)
    figures["convergence"] = {"seed_vs_default_after_long_run": rel_diff(seed_ref, ref)}
    for method, reference, what, limit in (
        ("overlap", ref, "the converged albedo", 64),
        ("seed", ref, "the default method's converged albedo", long_run // 2),
        ("seed", seed_ref, f"its own answer after {long_run} iterations", long_run // 2),
    ):
        n = iterations_to_converge(dc, root, method, reference, bounds, res, limit)
        figures["convergence"][f"{method}: {what}"] = n
        print(f"4. iterations to within 1 % of {what}, {method}: {n if n else f'> {limit}'}", flush=True)
    print(f"   (seed after {long_run} iterations differs from the default's answer by "
          f"{100 * figures['convergence']['seed_vs_default_after_long_run']:.1f} %)", flush=True)


def response_fit(q: bool, figures: dict) -> None:
    """Item 5: time of the camera-response fit per million observations (known exposure times)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    from response_bench import timing

    print("5. camera response fit (8 images, known exposure times):", flush=True)
    figures["response_fit"] = timing([(120, 120)] if q else [(350, 350)])


if __name__ == "__main__":
    sys.exit(main())
