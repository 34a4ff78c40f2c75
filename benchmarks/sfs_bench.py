#!/usr/bin/env python3
"""Shape from shading (``REFINE_DEM 1``, docs/sfs.md): accuracy, cost and the figures of docs/sfs.md.

The strip of docs/sfs.md (8 images, each column seen by about 3, Sun azimuths 90 +- 40 degrees, small
fresh craters, the DEM given blurred by 3 pixels, 8 tiles) is solved three ways in fresh processes:
with the true DEM, with the blurred one (a plain solve), and with the blurred one and ``REFINE_DEM 1``.
Prints the heights' RMS error against the truth (all pixels, within 3 px of a tile edge, elsewhere; and the same
bands of a refinement on one tile, where no seam can exist),
the albedo's error, the time of the refinement against the plain solve, nanoseconds per observation
per L-BFGS iteration (one core), the peak memory and
``dem_sigma/`` against the heights' errors; ``--figures`` writes docs/sfs_*.png.

    python benchmarks/sfs_bench.py [--out bench_out] [--figures] [--set KEY=VALUE ...]
"""
from __future__ import annotations

import argparse
import glob
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from common import mosaic, scene, solve_child  # noqa: E402
from lunaralbedo.simulate import SceneSpec  # noqa: E402

STRIP = dict(n_images=8, overlap=2 / 3, image_px=120, sun_azimuths=(50.0, 90.0, 130.0, 70.0, 110.0), fresh_craters=5.0,
             tile_size=1.0, seed=7, max_num_iter=10)
REFINE = {"REFINE_DEM": 1}  # every other key at its default (the input's blur estimated)


def with_keys(d: Path, name: str, keys: dict) -> Path:
    lines = [ln for ln in (d / "settings.txt").read_text().splitlines() if ln.split()[:1] and ln.split()[0] not in keys]
    path = d / name
    path.write_text("\n".join(lines + [f"{k} {v}" for k, v in keys.items()]) + "\n")
    return path


def height_errors(out: Path, d: Path, tile_deg: float) -> dict:
    """RMS of the heights against the truth: the given DEM, the solved one, near tile edges and elsewhere (metres)."""
    import rasterio

    like = d / "truth" / "albedo.tif"
    truth, given = mosaic([d / "truth/dem.tif"], like), mosaic([d / "DEM/dem.tif"], like)
    dem = mosaic(glob.glob(str(out / "DEM" / "*.tif")), like)
    with rasterio.open(like) as t:
        b, res = t.bounds, t.res
    rows, cols = np.mgrid[0:dem.shape[0], 0:dem.shape[1]]
    lon, lat = b.left + (cols + 0.5) * res[0], b.top - (rows + 0.5) * res[1]
    px = lambda x, r: np.abs(x / tile_deg - np.round(x / tile_deg)) * tile_deg / r  # noqa: E731  pixels to a tile edge
    near = np.minimum(px(lon, res[0]), px(lat, res[1])) < 3
    inside = (cols >= 3) & (cols < dem.shape[1] - 3) & (rows >= 3) & (rows < dem.shape[0] - 3) & np.isfinite(dem)
    err, gerr = dem - truth, given - truth
    rms = lambda e, m: float(np.sqrt(np.mean(e[m] ** 2)))  # noqa: E731
    return {"given_rms_m": rms(gerr, inside), "rms_m": rms(err, inside),
            "edge_rms_m": rms(err, inside & near), "elsewhere_rms_m": rms(err, inside & ~near),
            # the terrain near the edges may be harder or easier than elsewhere: the given DEM's errors there
            "given_edge_rms_m": rms(gerr, inside & near), "given_elsewhere_rms_m": rms(gerr, inside & ~near)}


def sigma_check(out: Path, d: Path) -> dict:
    """``dem_sigma/`` against the heights' errors: the median, the RMS error in the pixels below the median sigma,
    between the median and the 90th percentile and above it, and the fraction with |error| < 3 sigma."""
    like = d / "truth" / "albedo.tif"
    err = mosaic(glob.glob(str(out / "DEM" / "*.tif")), like) - mosaic([d / "truth/dem.tif"], like)
    sig = mosaic(glob.glob(str(out / "dem_sigma" / "*.tif")), like)
    ok = np.isfinite(err) & np.isfinite(sig)
    e, s = err[ok], sig[ok]
    q50, q90 = np.percentile(s, [50, 90])
    bands = [s < q50, (s >= q50) & (s < q90), s >= q90]
    return {"sigma_median_m": float(q50), "error_rms_by_sigma_band_m": [float(np.sqrt(np.mean(e[b] ** 2))) for b in bands],
            "within_3_sigma": float(np.mean(np.abs(e) < 3 * s))}


def run(root: Path, extra: dict, figures: bool) -> dict:
    from lunaralbedo.simulate import score

    truth_scene = scene(root, "sfs_true", SceneSpec(**STRIP))
    d = scene(root, "sfs_blur3", SceneSpec(dem_blur_px=3.0, **STRIP))
    runs = {"true_dem": solve_child(truth_scene, root / "sfs_out_true"), "plain": solve_child(d, root / "sfs_out_plain")}
    runs["refine"] = solve_child(with_keys(d, "settings_refine.txt", {**REFINE, **extra}).parent, root / "sfs_out_refine",
                                 settings_name="settings_refine.txt")
    # the seam-free reference: the same refinement on one tile (10 degrees: the whole strip), measured on the same bands
    solve_child(with_keys(d, "settings_one_tile.txt", {**REFINE, **extra, "TILE_SIZE": 10}).parent,
                root / "sfs_out_one_tile", settings_name="settings_one_tile.txt")
    report = json.loads((root / "sfs_out_refine" / "report.json").read_text())
    rd = report["refine_dem"]
    fig = {
        "albedo_true_dem": score(root / "sfs_out_true", truth_scene)["albedo_rel_rmse"],
        "albedo_plain": score(root / "sfs_out_plain", d)["albedo_rel_rmse"],
        "albedo_refine": score(root / "sfs_out_refine", d)["albedo_rel_rmse"],
        "exposure_refine": score(root / "sfs_out_refine", d)["exposure_max_rel_err"],
        **height_errors(root / "sfs_out_refine", d, STRIP["tile_size"]),
        "seconds_plain": runs["plain"]["seconds"], "seconds_refine": runs["refine"]["seconds"],
        "peak_mb_refine": runs["refine"]["peak_mb"], "peak_mb_plain": runs["plain"]["peak_mb"],
        "refine": rd,
    }
    fig["sigma"] = sigma_check(root / "sfs_out_refine", d)
    fig["time_ratio"] = fig["seconds_refine"] / fig["seconds_plain"]
    fig["height_ratio"] = fig["rms_m"] / fig["given_rms_m"]
    fig["edge_ratio"] = fig["edge_rms_m"] / fig["elsewhere_rms_m"]
    fig["edge_ratio_relative_to_given"] = fig["edge_ratio"] / (fig["given_edge_rms_m"] / fig["given_elsewhere_rms_m"])
    one = height_errors(root / "sfs_out_one_tile", d, STRIP["tile_size"])
    fig["edge_ratio_one_tile"] = one["edge_rms_m"] / one["elsewhere_rms_m"]  # no seam can exist: the terrain's share
    if "height_ns" in rd:
        fig["ns_per_observation_iteration"] = rd["height_ns"]
    if figures:
        from sfs_figures import draw

        draw(root, d, truth_scene, REPO / "docs")
    return fig


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="bench_out")
    ap.add_argument("--figures", action="store_true", help="write docs/sfs_*.png")
    ap.add_argument("--set", nargs="*", default=[], help="REFINE_DEM_* settings, KEY=VALUE")
    args = ap.parse_args()
    extra = dict(kv.split("=", 1) for kv in args.set)
    fig = run((REPO / args.out).resolve(), extra, args.figures)
    print(json.dumps(fig, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
