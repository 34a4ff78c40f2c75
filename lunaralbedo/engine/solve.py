"""The solve driver: passes over tiles, global reductions, checkpoints, outputs.

Passes (each a map of tile tasks, see :mod:`.tilework`):

1. *prepare*: read inputs once per tile, cache the observation stack in
   ``OUTDIR/.cache``; reduce the initialisation sums (seed exposure, overlap log-ratios);
2. *iterate* (up to MAX_NUM_ITER times): albedo (eq. 3/6), cost Q (eq. 1), sums for
   the exposure (eq. 4) and phase (eq. 5) updates; reduce in tile order; update;
3. *finalise*: write albedo/error/DEM/weightsSum tiles with the final unknowns.

After every reduction the global state is checkpointed (``OUTDIR/.state.json``,
atomic), so ``resume=True`` continues a killed run and produces the same bytes.
"""
from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import LunarAlbedoError, ResumeError, SettingsError, SolverError
from ..io import outputs
from ..io.atomic import remove_stale_temporaries
from ..model import exposure_init, updates
from ..settings import Settings, load_settings
from ..parallel import local_workers, make_executor
from .scene import Scene, build_scene
from .tilework import SolveState, finalize_tile, iterate_tile, prepare_tile

METHODS = ("overlap", "seed")
#: Early stop: after the first iteration whose Q is within this fraction of the previous Q (docs/solver.md).
DEFAULT_TOLERANCE = 1e-5
STATE_FILE = ".state.json"
MARKER = ".lunaralbedo"  # written first into every OUTDIR: marks it as ours
CACHE_DIR = ".cache"
_OUTPUT_DIRS = ("albedo", "error", "DEM", "weightsSum", "weight")


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


def default_out_dir(settings: Settings) -> Path:
    """``albedo_<settings file stem>`` in the current folder."""
    stem = settings.source.stem if settings.source else "run"
    return Path.cwd() / f"albedo_{stem}"


def _check_out_dir(out: Path, settings: Settings, resume: bool) -> bool:
    """Validate OUTDIR; return True when this call creates it."""
    for d in (settings.drg_dir, settings.dem_dir):
        if d is not None and (out == d.resolve() or d.resolve() in out.parents):
            raise SettingsError(f"{out}: output folder must not be inside the input folder {d}")
    if not out.exists():
        return True
    if not out.is_dir():
        raise SolverError(f"{out}: exists and is not a folder")
    if any(out.iterdir()) and not (out / MARKER).exists():
        raise SolverError(f"{out}: folder exists, is not empty and is not a lunaralbedo output; choose another -o")
    return False


def _clear_previous_run(out: Path) -> None:
    """Remove an earlier run's outputs and checkpoint (called once the inputs are known to be good)."""
    for name in (*_OUTPUT_DIRS, CACHE_DIR):
        shutil.rmtree(out / name, ignore_errors=True)
    for name in (STATE_FILE, "report.json"):
        (out / name).unlink(missing_ok=True)


def _reduce_init(scene: Scene, metas: list[dict], method: str) -> np.ndarray:
    n = len(scene.images)
    r_sum, r_cnt = np.zeros(n), np.zeros(n)
    pairs: dict = {}
    for meta in metas:  # fixed tile order
        idx = np.asarray(meta["index"], dtype=int)
        np.add.at(r_sum, idx, meta["r_sum"])
        np.add.at(r_cnt, idx, meta["r_count"])
        exposure_init.merge_pair_sums(pairs, {(j, k): (nn, d) for j, k, nn, d in meta["pairs"]})
    t_seed = exposure_init.seed_exposure(scene.settings.tr_const, r_sum, r_cnt)
    if method == "seed":
        return t_seed
    return exposure_init.overlap_exposure(pairs, np.log(t_seed))


def _reduce_iteration(n_images: int, n_params: int, parts) -> updates.PassSums:
    total = updates.PassSums(n_images, n_params)
    for p in parts:  # fixed tile order: identical sums for any number of workers
        total.add(p)
    return total


def _update(state: SolveState, sums: updates.PassSums, method: str, model, t_ref: np.ndarray) -> SolveState:
    t = updates.exposure_update(state.exposure, sums.exp_num, sums.exp_den)
    c = state.params
    if model.parameters and sums.n_obs:
        if method == "seed":
            c = updates.phase_update_seed(c, sums.jtj, sums.jtr)
        else:
            c = updates.phase_update_damped(c, sums.jtj, sums.jtr, (sums.alpha_min, sums.alpha_max), model.phase_curve)
    if method != "seed":
        # A*T leaves one global scale free: pin the geometric mean of T to the initial one.
        t = t * np.exp(np.mean(np.log(t_ref)) - np.mean(np.log(t)))
    return SolveState(np.asarray(t, dtype=np.float64), np.asarray(c, dtype=np.float64))


def solve(
    settings: Settings | str | Path,
    out: str | Path | None = None,
    method: str = "overlap",
    workers: int | None = None,
    scheduler: str | None = None,
    cluster: str | None = None,
    cluster_options: dict | None = None,
    resume: bool = False,
    skip_missing: bool = False,
    tolerance: float = DEFAULT_TOLERANCE,
    max_iter: int | None = None,
    progress: bool = False,
    plots: bool = True,
) -> SolveResult:
    """Solve for albedo, exposures and the photometric model's parameters (seed 000 section 7).

    ``method="overlap"`` (default) initialises exposures from image overlaps and damps
    the phase step; ``method="seed"`` runs the plain updates of the manual.  Workers:
    ``workers`` local processes (default NUM_PROCESSES capped at the CPU count),
    ``scheduler`` (tcp://host:port) or ``cluster`` ("pbs"/"slurm").  Outputs go to
    ``out`` (default ``albedo_<settings stem>``); nothing is written to input folders.
    Iterations stop early once ``|Q_n - Q_(n-1)| <= tolerance * Q_n`` (0: run them all).
    """
    settings = settings if isinstance(settings, Settings) else load_settings(settings)
    if method not in METHODS:
        raise SettingsError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    out = Path(out).resolve() if out is not None else default_out_dir(settings)
    max_iter = settings.max_num_iter if max_iter is None else max_iter
    workers = local_workers(workers, settings.num_processes)
    created = _check_out_dir(out, settings, resume)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    executor = make_executor(workers, scheduler, cluster, cluster_options, progress)
    try:
        scene = build_scene(settings, skip_missing, map_fn=lambda f, xs: executor.map(f, xs, "masks"))
        timings["scene"] = time.perf_counter() - t0
        if not resume:
            _clear_previous_run(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / MARKER).write_text("lunaralbedo solve output folder\n")
        remove_stale_temporaries(out)
        return _run(scene, out, method, max_iter, tolerance, executor, resume, timings, plots)
    except LunarAlbedoError:
        if created and not resume:
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        executor.close()


def _load_checkpoint(out: Path, scene: Scene, method: str, resume: bool) -> dict | None:
    path = out / STATE_FILE
    if not (resume and path.exists()):
        return None
    import json

    state = json.loads(path.read_text())
    if state.get("fingerprint") != scene.fingerprint() or state.get("method") != method:
        raise ResumeError(f"{path}: the checkpoint belongs to other settings, inputs or method; run without --resume")
    return state


def _run(scene, out, method, max_iter, tol, executor, resume, timings, plots) -> SolveResult:
    s = scene.settings
    cache = out / CACHE_DIR
    ck = _load_checkpoint(out, scene, method, resume)
    tiles = list(range(len(scene.tiles)))
    t1 = time.perf_counter()
    metas = executor.map(prepare_tile, tiles, "prepare", shared=("scene",), scene=scene, cache_root=cache)
    t_init = _reduce_init(scene, metas, method)
    timings["prepare"] = time.perf_counter() - t1
    if ck is None:
        ck = {
            "fingerprint": scene.fingerprint(),
            "method": method,
            "iteration": 0,
            "exposure": t_init.tolist(),
            "params": s.initial_params.tolist(),
            "q": [],
            "params_history": [s.initial_params.tolist()],
            "done": False,
        }
        outputs.write_json(out / STATE_FILE, ck)
    state = SolveState(np.array(ck["exposure"]), np.array(ck["params"], dtype=np.float64))
    resume_info = {"tiles_prepared_before": sum(bool(m.get("reused")) for m in metas), "iterations_done_before": ck["iteration"]}
    t2 = time.perf_counter()
    want_phase = bool(s.model.parameters)
    while not ck["done"] and ck["iteration"] < max_iter:
        parts = executor.map(iterate_tile, tiles, f"iteration {ck['iteration'] + 1}", shared=("scene",), scene=scene, cache_root=cache, state=state, want_phase=want_phase)
        sums = _reduce_iteration(len(scene.images), len(s.model.parameters), parts)
        q_prev = ck["q"][-1] if ck["q"] else None
        ck["q"].append(sums.q)
        converged = q_prev is not None and abs(q_prev - sums.q) <= tol * max(sums.q, 1e-300)
        if not converged:
            state = _update(state, sums, method, s.model, t_init)
            ck["params_history"].append(state.params.tolist())
        ck.update(iteration=ck["iteration"] + 1, exposure=state.exposure.tolist(), params=state.params.tolist(), done=converged)
        outputs.write_json(out / STATE_FILE, ck)
    timings["iterate"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    skip_done = bool(ck.get("finalising"))
    if not skip_done:
        ck["finalising"] = True  # from here on the state is fixed; finished tiles can be kept
        outputs.write_json(out / STATE_FILE, ck)
    tile_reports = executor.map(
        finalize_tile, tiles, "write tiles", shared=("scene",), scene=scene, cache_root=cache, out_dir=out, state=state, skip_done=skip_done
    )
    resume_info["tiles_written_before"] = sum(bool(r.pop("reused")) for r in tile_reports)
    timings["finalise"] = time.perf_counter() - t3
    return _write_run_outputs(scene, out, method, state, t_init, ck, tile_reports, timings, executor, plots, resume_info)


def _write_run_outputs(scene, out, method, state, t_init, ck, tile_reports, timings, executor, plots, resume_info):
    keys = scene.keys
    outputs.write_exposure_csv(out / "exposure.csv", keys, state.exposure, t_init)
    names = scene.settings.model.parameters
    if names:
        outputs.write_phase_csv(out / "phase.csv", names, ck["params_history"])
    for key, prof in zip(keys, scene.profiles):
        outputs.write_weight_profile(out / "weight" / f"{key}_weight.txt", prof)
    if plots:
        outputs.plot_exposures(out / "exposure.png", keys, state.exposure, t_init)
        if ck["q"]:
            outputs.plot_cost(out / "cost.png", ck["q"])
    report = {
        "settings": scene.settings.to_dict(),
        "method": method,
        "executor": executor.description,
        "iterations": ck["iteration"],
        "converged": ck["done"],
        "cost_q": ck["q"],
        "photometric_model": scene.settings.model.name,
        "parameters": {name: [h[m] for h in ck["params_history"]] for m, name in enumerate(names)},
        "images_used": len(keys),
        "images_skipped": scene.skipped,
        "tiles": tile_reports,
        "resumed": resume_info if any(resume_info.values()) else None,
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    outputs.write_json(out / "report.json", report)
    shutil.rmtree(out / CACHE_DIR, ignore_errors=True)
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
