"""The end of a solve: its tables, plots and ``report.json``, the tiles moved into ``OUTDIR``, the result object.

Split from :mod:`.solve` (the driver); the output folder's layout (:data:`CHECKPOINT_DIR` and the rest)
is defined here, where the finished run is assembled.
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io import outputs
from ..response.solve_hook import move_outputs, report_parts
from . import robust

CHECKPOINT_DIR = "checkpoint"  # everything --resume needs; removed when the run succeeds
STATE_FILE = f"{CHECKPOINT_DIR}/state.json"
CACHE_DIR = f"{CHECKPOINT_DIR}/cache"
TILES_DIR = f"{CHECKPOINT_DIR}/tiles"  # finalised tiles, moved into OUTDIR at the end
RESPONSE_DIR = f"{CHECKPOINT_DIR}/response"  # camera response files (response/solve_hook.py), moved likewise
MARKER = ".lunaralbedo"  # written first into every OUTDIR: marks it as ours
TILE_DIRS = ("albedo", "error", "DEM", "weightsSum", "outliers")
OUTPUT_DIRS = (*TILE_DIRS, "weight")
REFINE_DIRS = ("sfs", "dem_change", "dem_lit", "dem_input", "dem_sigma")  # REFINE_DEM 1 (engine/refine.py)
RESULT_FILES = ("report.json", "exposure.csv", "haze.csv", "phase.csv", "exposure.png", "cost.png",
                "response.csv", "response.png", "loglik.png", "residuals.png", "image_offsets.csv")


@dataclass
class SolveResult:
    """What a solve produced (also written to ``report.json``)."""

    out_dir: Path
    keys: list[str]
    exposure: np.ndarray
    parameters: dict[str, float]  # the photometric model's fitted parameters by name (none for mosaic/Lambert)
    cost_history: list[float]
    iterations: int
    tiles: list[str]
    report: dict = field(repr=False, default_factory=dict)


def move_tiles_into_place(out: Path) -> None:
    """Move the finalised tile folders from the checkpoint into OUTDIR (one rename each)."""
    for name in TILE_DIRS:
        staged = out / TILES_DIR / name
        if staged.is_dir():
            shutil.rmtree(out / name, ignore_errors=True)
            staged.replace(out / name)


def stage_costs(timings: dict, n_obs: int | None, passes: int) -> dict:
    """The run's size and the cost of its stages per pixel-observation (``report.json``'s ``observations``):
    ``count`` (observations cached over all tiles), nanoseconds of wall time per observation to
    prepare, per observation and pass to iterate (the passes this process ran), per observation
    to finalise (None where not known: a cache resumed from a version that did not count).  A
    stage that found its work done before (a resumed run) counts what it did."""
    per = lambda seconds, n: round(1e9 * seconds / n, 2) if n else None  # noqa: E731  (n None: not counted)
    return {"count": n_obs, "prepare_ns": per(timings.get("prepare", 0.0), n_obs),
            "iterate_ns_per_pass": per(timings.get("iterate", 0.0), (n_obs or 0) * passes),
            "finalise_ns": per(timings.get("finalise", 0.0), n_obs)}



def write_run_outputs(scene, out, method, state, t_init, ck, tile_reports, timings, executor, plots, resume_info, costs,
                      extra=None) -> SolveResult:
    """Write a finished run's tables, plots and ``report.json``, move its tiles into ``out`` and remove the
    checkpoint; the run's :class:`SolveResult`."""
    keys = scene.keys
    outputs.write_exposure_csv(out / "exposure.csv", keys, state.exposure, t_init)
    names = scene.model.parameters
    if names:
        outputs.write_phase_csv(out / "phase.csv", names, ck["params_history"])
    for key, prof in zip(keys, scene.profiles):
        outputs.write_weight_profile(out / "weight" / f"{key}_weight.txt", prof)
    if state.haze is not None:
        outputs.write_haze_csv(out / "haze.csv", keys, state.haze)
    if plots:
        outputs.plot_exposures(out / "exposure.png", keys, state.exposure, t_init, haze=state.haze)
        if ck["q"]:
            outputs.plot_cost(out / "cost.png", ck["q"])
    report = {
        "settings": scene.settings.to_dict(),
        "method": method,
        "executor": executor.description,
        "iterations": ck["iteration"],
        "converged": ck["done"],
        "cost_q": ck["q"],
        "photometric_model": scene.model.name,
        "parameters": {name: [h[m] for h in ck["params_history"]] for m, name in enumerate(names)},
        "images_used": len(keys),
        "images_skipped": scene.skipped,
        "tiles": tile_reports,
        "resumed": resume_info if any(resume_info.values()) else None,
        **report_parts(ck.get("response")),
        "exposure_fixed": bool(ck.get("exposure_fixed")),
        "exposure_mode": "fixed" if ck.get("exposure_fixed") else scene.settings.exposure_mode,
        "outliers": robust.report(keys, ck, scene.settings),
        "haze": None if state.haze is None else dict(zip(keys, state.haze.tolist())),
        "haze_inseparable": ck.get("haze_inseparable", []),
        "haze_sigma": dict(zip(keys, ck["haze_sigma"])) if ck.get("haze_sigma") else None,
        "haze_joint_passes": ck.get("haze_joint_passes") if state.haze is not None else None,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        "observations": costs,
        **(extra or {}),
    }
    from .registration import finish

    report["registration"] = finish(out / CHECKPOINT_DIR, out)  # image_offsets.csv into OUTDIR (None: not registered)
    move_tiles_into_place(out)
    move_outputs(out / RESPONSE_DIR, out)
    outputs.write_json(out / "report.json", report)  # last: its presence means the run finished
    shutil.rmtree(out / CHECKPOINT_DIR, ignore_errors=True)
    return SolveResult(
        out_dir=out,
        keys=keys,
        exposure=state.exposure,
        parameters=dict(zip(names, state.params.tolist())),
        cost_history=ck["q"],
        iterations=ck["iteration"],
        tiles=[r["tile"] for r in tile_reports],
        report=report,
    )
