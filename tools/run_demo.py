#!/usr/bin/env python3
"""`make demo`: ingest -> solve -> export-kml -> export-web on sample_data/, then compare with the truth.

Runs the real commands (as a user would type them) and prints where the results are.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def rel(path: Path) -> str:
    """A path relative to the repository when it is inside it (shorter commands to read)."""
    try:
        return str(path.relative_to(REPO))
    except ValueError:
        return str(path)


def run(*args: str) -> None:
    cmd = [sys.executable, "-m", "lunaralbedo.cli", *args]
    print("$ lunaralbedo " + " ".join(args), flush=True)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=REPO)
    print(f"  ({time.perf_counter() - t0:.1f} s)\n", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="demo_out", help="output folder (replaced)")
    ap.add_argument("--sample", default="sample_data", help="sample data folder")
    args = ap.parse_args()
    out, sample = (REPO / args.out).resolve(), (REPO / args.sample).resolve()
    if out.exists():
        shutil.rmtree(out)
    cubes = sorted(rel(p) for p in (sample / "cubes").glob("*.cub"))
    if not cubes:
        print(f"no cubes in {sample}/cubes: run `make sample-data` first", file=sys.stderr)
        return 1
    work, results = out / "work", out / "albedo"
    # on the DEM's grid: the sample data's truth (albedo, DEM) was rendered on it and the scores below compare there
    run("ingest", *cubes, "--dem", rel(sample / "dem"), "--match-dem", "-o", rel(work))
    run("solve", rel(work / "settings.txt"), "-o", rel(results))
    run("export-kml", rel(results))
    run("export-web", rel(results))

    from lunaralbedo.simulate import score

    sc = score(results, sample)
    print("Compared with the forward model's truth (sample_data/truth):")
    print(f"  albedo relative RMSE  {100 * sc['albedo_rel_rmse']:.2f} %  (after the one global scale A*T leaves free)")
    print(f"  worst exposure error  {100 * sc['exposure_max_rel_err']:.3f} %  over {sc['images_compared']} images")
    print(f"  coverage              {100 * sc['coverage']:.1f} % of the truth grid\n")
    print("Results:")
    for what, path in [
        ("ingested DRGs + positions", work),
        ("albedo tiles (float32)", results / "albedo"),
        ("error maps (eq. 7)", results / "error"),
        ("exposures", results / "exposure.csv"),
        ("plots", results / "exposure.png"),
        ("run report", results / "report.json"),
        ("Google Earth (Moon) KML", results / "kml" / "doc.kml"),
        ("Cloud-Optimized GeoTIFF", results / "albedo_mosaic.tif"),
        ("web map + run report", results / "web" / "index.html"),
    ]:
        print(f"  {what:<27} {rel(path)}")
    page = results / "web" / "index.html"
    print(f"\nOpen the web map and run report:\n  {page.as_uri()}\n  (or serve it: lunaralbedo view {rel(results)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
