"""The real-data figures of docs/sfs.md, section "Real data": shape from shading on real images.

    .venv/bin/python tools/sfs_real_data.py [--out DIR] [--only apollo|nac|wac ...]

Each scene is solved twice with the command line, as a user would (`lunaralbedo solve`, one worker):
plainly and with ``REFINE_DEM 1`` (every other key at its default), into DIR (default: a temporary
folder; nothing is written under ``../shared``). Printed, and written to ``DIR/summary.json``:

* **apollo**: PhotometryTK's regression scene (``../shared/photk_tests``, settings 1: 53 Apollo 15/16
  Metric frames, ``--max-iter 10``). The measure of topography leaking into the albedo: for every image
  and tile, the correlation over the image's usable pixels (those the solver observes: valid, lit, not
  saturated, outside cast shadows, cos i and cos e above the solver's floors) between the albedo and
  that image's cos i, from the input DEM and from the refined heights (``OUTDIR/DEM/``), averaged
  weighted by pixels (``|corr|`` and the signed mean). Also solved: plainly without outlier rejection and
  robust loss (the defaults of the earlier figures), and with ``REFINE_DEM_INPUT_BLUR 0`` (the input held
  pixel by pixel).
* **nac**, **wac**: the real LRO cubes of ``../shared/realdata/isis`` (an NAC crop; a WAC cube whose
  five bands share one geometry), each ingested over the GLD100 DEM: single observations.

For both: the heights' change RMS, the median standard error (``dem_sigma``), the input blur used
and the wall-clock time of each solve (``report.json`` ``refine_dem``).

The cosines are those of the solver's own code (:class:`lunaralbedo.engine.observations.BlockGeometry`
``observe``, i.e. :func:`lunaralbedo.model.geometry.observe_window`; cast shadows by
:class:`lunaralbedo.engine.terrain.TileShadows`; the image's pixels by
:func:`lunaralbedo.io.drgs.read_drg_onto_grid`), on the tile grid of the solve.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rasterio

from lunaralbedo.engine.observations import BlockGeometry, saturation_of
from lunaralbedo.engine.scene import build_scene
from lunaralbedo.engine.terrain import TileShadows
from lunaralbedo.io.drgs import read_drg_onto_grid
from lunaralbedo.io.rasters import raster_info
from lunaralbedo.model import shadows
from lunaralbedo.settings import load_settings

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
ISIS = SHARED / "realdata" / "isis"
GLD100 = ISIS / "WAC_GLD100_V1.0_GLOBAL_with_LOLA_30M_POLE.16bit.reduced.cub"
CUBES = {"nac": ISIS / "M143947267L.cal.echo.crop.cub", "wac": ISIS / "M1181493219CE.vis.odd.reduced.cub"}
CLI = [sys.executable, "-m", "lunaralbedo"]


def _run(args: list, log: Path) -> float:
    """Run the command line; the wall-clock seconds (the output kept in ``log``)."""
    t0 = time.perf_counter()
    res = subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    log.write_text(res.stdout + res.stderr)
    if res.returncode:
        raise SystemExit(f"{' '.join(map(str, args))} failed ({log}):\n{res.stderr[-2000:]}")
    return seconds


def _with_keys(settings: Path, out: Path, keys: dict) -> Path:
    """A copy of the legacy settings file ``settings`` in ``out`` with its folders and files made absolute
    and ``keys`` set (replaced or added)."""
    lines = []
    for line in settings.read_text().splitlines():
        words = line.split()
        if words and words[0] in keys:
            continue
        if words and re.fullmatch(r"\w+_(DIR|FILE)", words[0]) and not Path(words[1]).is_absolute():
            line = f"{words[0]} {(settings.parent / words[1]).resolve()}"
        lines.append(line)
    path = out / f"{settings.stem}_{'_'.join(f'{k}{v}' for k, v in keys.items()) or 'plain'}.txt"
    path.write_text("\n".join(lines + [f"{k} {v}" for k, v in keys.items()]) + "\n")
    return path


def leakage(settings: Path, results: Path, dem_files: list[Path] | None = None) -> dict:
    """Per image and tile, the correlation of the albedo of ``results`` with the image's cos i over its usable
    pixels; cos i from the settings' DEM, or from ``dem_files`` (e.g. ``results/DEM/*.tif``, the refined heights).
    Returns the pixel-weighted mean of ``|corr|`` and of ``corr``, the pairs and pixels counted."""
    scene = build_scene(load_settings(settings), skip_missing=True)
    if dem_files:
        scene = dataclasses.replace(scene, dems=[raster_info(p) for p in dem_files])
    s = scene.settings
    thresh = s.shadow_thresh if s.shadow_type == shadows.THRESHOLD else None
    pairs = []
    for t, tile in enumerate(scene.tiles):
        path = results / "albedo" / f"{tile.name}.tif"
        if not path.exists():
            continue
        with rasterio.open(path) as ds:
            albedo = ds.read(1).astype(np.float64)
        assert albedo.shape == (tile.height, tile.width), (path, albedo.shape)
        geo = BlockGeometry(scene, tile, 0, tile.height)
        cast = TileShadows(scene, tile, scene.tile_images[t]) if s.uses_cast_shadows else None
        for k in scene.tile_images[t]:
            info = scene.images[k]
            got = read_drg_onto_grid(info, scene.profiles[k], tile.transform, (tile.height, tile.width), scene.crs,
                                     thresh, saturation=saturation_of(info.dtype))
            if got is None:
                continue
            val, ok, wt, use = got
            use &= (val > 0) & ((wt if s.use_weights else ok) > 0) & np.isfinite(albedo)
            rows, cols, cos_i = geo.observe(use, 0, 0, scene.sun[k], scene.spacecraft[k])[:3]
            if cast is not None and len(rows):
                lit = ~cast.shadowed(k, rows, cols)
                rows, cols, cos_i = rows[lit], cols[lit], cos_i[lit]
            a = albedo[rows, cols]
            if len(rows) < 3 or np.std(a) == 0 or np.std(cos_i) == 0:
                continue
            pairs.append((info.key, tile.name, len(rows), float(np.corrcoef(a, cos_i)[0, 1])))
    n = np.array([p[2] for p in pairs], np.float64)
    c = np.array([p[3] for p in pairs], np.float64)
    return {"abs_corr": float(np.sum(n * np.abs(c)) / n.sum()) if n.size else None,
            "corr": float(np.sum(n * c) / n.sum()) if n.size else None,
            "pairs": len(pairs), "pixels": int(n.sum()), "by_pair": pairs}


def _refine_report(results: Path) -> dict:
    rep = json.loads((results / "report.json").read_text()).get("refine_dem", {})
    return {k: rep.get(k) for k in ("dem_change_rms_m", "dem_sigma_median_m", "input_blur_px", "pixel_m", "fidelity")}


def _pair(settings: Path, out: Path, extra: list) -> dict:
    """The plain and ``REFINE_DEM 1`` solves of ``settings`` into ``out/plain`` and ``out/refine``."""
    plain, refine = out / "plain", out / "refine"
    got = {"plain_s": _run(["solve", settings, "-o", plain, "--workers", 1, "--quiet", *extra], out / "plain.log")}
    ref = _with_keys(settings, out, {"REFINE_DEM": 1})
    got["refine_s"] = _run(["solve", ref, "-o", refine, "--workers", 1, "--quiet", *extra], out / "refine.log")
    got.update(_refine_report(refine))
    got["leakage"] = {
        "plain_input_dem": leakage(settings, plain),
        "refine_input_dem": leakage(settings, refine),
        "refine_refined_dem": leakage(settings, refine, sorted((refine / "DEM").glob("*.tif"))),
    }
    return got


def apollo(out: Path, iterations: int) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    given = SHARED / "photk_tests" / "photometry_settings_1.txt"
    settings = _with_keys(given, out, {})
    got = _pair(settings, out, ["--max-iter", iterations])
    # the plain solve without outlier rejection and robust loss (the defaults before they were switched on)
    plain = _with_keys(given, out, {"REJECT_OUTLIERS": 0, "ROBUST_LOSS": "none"})
    got["plain_no_robust_s"] = _run(["solve", plain, "-o", out / "plain_no_robust", "--workers", 1, "--quiet",
                                     "--max-iter", iterations], out / "plain_no_robust.log")
    got["leakage"]["plain_no_robust_input_dem"] = leakage(plain, out / "plain_no_robust")
    # the input held pixel by pixel (the blur stated 0): how much of the above rests on the estimated blur
    sharp, folder = _with_keys(given, out, {"REFINE_DEM": 1, "REFINE_DEM_INPUT_BLUR": 0}), out / "refine_blur0"
    got["refine_blur0_s"] = _run(["solve", sharp, "-o", folder, "--workers", 1, "--quiet", "--max-iter", iterations],
                                 out / "refine_blur0.log")
    got["refine_blur0"] = _refine_report(folder)
    got["leakage"]["refine_blur0_refined_dem"] = leakage(sharp, folder, sorted((folder / "DEM").glob("*.tif")))
    return got


def lro(name: str, out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    work = out / "work"
    got = {"ingest_s": _run(["ingest", CUBES[name], "--dem", GLD100, "-o", work], out / "ingest.log")}
    got.update(_pair(work / "settings.txt", out, []))
    return got


def _brief(got: dict) -> dict:
    """``got`` without the per-pair correlations (kept in summary.json)."""
    return {k: ({m: {n: v for n, v in x.items() if n != "by_pair"} for m, x in w.items()} if k == "leakage" else w)
            for k, w in got.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="folder for the runs (default: a temporary one)")
    ap.add_argument("--only", nargs="*", choices=("apollo", "nac", "wac"), default=["apollo", "nac", "wac"])
    ap.add_argument("--iterations", type=int, default=10, help="MAX_NUM_ITER of the Apollo solves")
    args = ap.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="sfs_real_"))
    out = out.resolve()
    if SHARED.resolve() in (out, *out.parents):
        raise SystemExit(f"{out}: not under {SHARED} (the reference data are read only)")
    summary = {}
    for name in args.only:
        summary[name] = apollo(out / name, args.iterations) if name == "apollo" else lro(name, out / name)
        print(name, json.dumps(_brief(summary[name]), indent=1), flush=True)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(f"written {out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
