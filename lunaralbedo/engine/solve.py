"""The solve driver: passes over tiles, global reductions, checkpoints, outputs.

Passes (each a map of tile tasks, see :mod:`.prepare` and :mod:`.tilework`):

1. *prepare*: read inputs once per tile, cache the observation stack in
   ``OUTDIR/checkpoint/cache``; reduce the initialisation sums (seed exposure, overlap log-ratios);
2. *iterate* (up to MAX_NUM_ITER times): albedo (eq. 3/6), cost Q (eq. 1), sums for
   the exposure (eq. 4) and phase (eq. 5) updates; reduce in tile order; update;
3. *finalise*: write albedo/error/DEM/weightsSum tiles with the final unknowns into
   ``OUTDIR/checkpoint/tiles``; they move into ``OUTDIR`` once all are written.

After every reduction the global state is checkpointed (``OUTDIR/checkpoint/state.json``,
atomic), so ``resume=True`` continues a killed run and produces the same bytes.  Until a
run succeeds, ``OUTDIR`` holds only its marker and ``checkpoint/`` (deleted at the end):
never a partial set of result tiles.  A run stopped by bad input removes an OUTDIR it
created; one stopped by the infrastructure (worker lost, disk full) or Ctrl-C keeps the
checkpoint for ``--resume`` (docs/errors.md).
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np

from ..errors import ResumeError, SettingsError, SolverError, typed_error
from ..io import outputs
from ..io.atomic import remove_stale_temporaries, remove_tree
from ..io.guard import check_output_dir
from ..settings import Settings, load_settings
from ..parallel import local_workers, make_executor
from ..parallel.progress import ROWS
from ..parallel.workers import trim_malloc
from ..runtime import Runtime
from ..response.solve_hook import check_resume, given_exposures, lut_digest, resolve_response
from .observations import ROW_PIXEL_BYTES, block_budget
from .response_pass import response_observations
from .options import DEFAULT_TOLERANCE, METHODS
from .tiles import budget_warning
from .run_report import (CACHE_DIR, CHECKPOINT_DIR, MARKER, OUTPUT_DIRS, REFINE_DIRS, RESPONSE_DIR, RESULT_FILES,
                         STATE_FILE, TILES_DIR, SolveResult, stage_costs, write_run_outputs)
from .scene import Scene, build_scene
from .prepare import WRITER, prepare_tile
from . import robust
from .pass_update import haze_step_taken, prepare_pairs, reduce_init, reduce_iteration, update
from .tilework import SolveState, finalize_tile, iterate_tile

#: Modules local workers import as they start (the tile tasks' own, with NumPy, numba, rasterio).
WORKER_PRELOAD = ("lunaralbedo.engine.prepare", "lunaralbedo.engine.tilework", "lunaralbedo.engine.robust")
#: A tile task's fixed cost in observations (~2 ms of a worker's time at ~9 ns per observation),
#: for sharing the tiles' iterations evenly among workers (:meth:`~lunaralbedo.parallel.DaskExecutor.place`).
TASK_OBSERVATIONS = 250_000


def default_out_dir(settings: Settings) -> Path:
    """``albedo_<settings file stem>`` in the current folder."""
    stem = settings.source.stem if settings.source else "run"
    return Path.cwd() / f"albedo_{stem}"


def _check_out_dir(out: Path, settings: Settings) -> bool:
    """Validate OUTDIR; return True when this call creates it."""
    for d in (settings.drg_dir, settings.dem_dir):
        if d is not None and (out == d.resolve() or d.resolve() in out.parents):
            raise SettingsError(f"{out}: output folder must not be inside the input folder {d}")
    check_output_dir(out)
    if not out.exists():
        return True
    if any(out.iterdir()) and not (out / MARKER).exists():
        raise SolverError(f"{out}: folder exists, is not empty and is not a lunaralbedo output; choose another -o")
    return False


def _clear_previous_run(out: Path) -> None:
    """Remove an earlier run's outputs and checkpoint (called once the inputs are known to be good)."""
    for name in (*OUTPUT_DIRS, CHECKPOINT_DIR, *REFINE_DIRS):
        shutil.rmtree(out / name, ignore_errors=True)
    for name in RESULT_FILES:
        (out / name).unlink(missing_ok=True)


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
    response: str | Path | None = None,
    exposure_times: str | Path | None = None,
    runtime: Runtime | None = None,
    warn=None,
) -> SolveResult:
    r"""Solve for the albedo, the exposures and the photometric model's parameters.

    Minimises the cost of eq. 1 of the PhotometryTK manual (section 7), :math:`Q = \sum_k \sum_{ij}
    (I^k_{ij} - T^k A_{ij} R^k_{ij} - H^k)^2 S^k_{ij} w^k_{ij}`, by the albedo update of eqs. 3/6, the
    exposure update of eq. 4 and the phase-parameter step of eq. 5, over tiles in a fixed order
    (identical bytes for any number of workers), with the terms the settings turn on: robust weights
    (``REJECT_OUTLIERS``, ``ROBUST_LOSS``), a haze per image (``FLOAT_HAZE``), image-to-DEM registration
    (``REGISTER_IMAGES``), refined heights (``REFINE_DEM``) and the exposure mode (``EXPOSURE_MODE``);
    docs/solver.md and docs/sfs.md give the math.

    Parameters
    ----------
    settings : Settings or str or Path
        The run's settings, or the path of a legacy settings file or a TOML file.
    out : str or Path, optional
        Output folder (default ``albedo_<settings stem>`` in the current folder); nothing is written
        to the input folders.
    method : {"overlap", "seed"}
        ``overlap`` initialises the exposures from the images' overlaps and damps the phase step;
        ``seed`` runs the manual's plain updates.
    workers : int, optional
        Local worker processes (default NUM_PROCESSES capped at the CPU count; 1: in-process).
    scheduler : str, optional
        Address ``tcp://host:port`` of an existing Dask scheduler to run on.
    cluster : {"pbs", "slurm"}, optional
        Start the workers as batch jobs (dask-jobqueue).
    cluster_options : dict, optional
        Options of the batch jobs (queue, cores, memory, walltime, jobs, account).
    resume : bool
        Continue an interrupted run in ``out`` (same settings and inputs): the same bytes as an
        uninterrupted run.
    skip_missing : bool
        Leave out DRGs without a Sun/spacecraft position (listed in the report) instead of failing.
    tolerance : float
        Stop once :math:`|Q_n - Q_{n-1}| \le` ``tolerance`` :math:`Q_n` (0: run MAX_NUM_ITER passes).
    max_iter : int, optional
        Passes at most (default: the settings' MAX_NUM_ITER).
    progress : bool
        Show progress bars (tiles and rows).
    plots : bool
        Write ``exposure.png`` and ``cost.png`` (and the response's plots).
    response : str or Path, optional
        Camera response (Kim et al.): None for linear DN, ``"estimate"`` to fit g with the albedo, or a
        ``response.csv`` to apply.
    exposure_times : str or Path, optional
        ``key,exposure`` CSV that fixes the exposures (as ``EXPOSURE_MODE fixed`` with that file).
    runtime : Runtime, optional
        How the run uses the machine (:class:`lunaralbedo.runtime.Runtime`: memory budgets, how workers
        start, a node file); no value of it changes a result.
    warn : callable, optional
        ``warn(message)``, called once the tiles are known when one needs more than the memory budget.

    Returns
    -------
    SolveResult
        The output folder, image keys, exposures (per image, in key order), the fitted parameters by
        name, the cost history, the number of passes, the tile names, and ``report`` (``report.json``).

    Raises
    ------
    SettingsError, InputError
        Exit 2: bad settings or inputs (named); nothing is left in a folder the run created.
    InfrastructureError, ClusterError
        Exit 3: a worker lost, the disk full, a cluster that cannot start; the checkpoint is kept for
        ``resume=True``.
    """
    settings = settings if isinstance(settings, Settings) else load_settings(settings)
    if method not in METHODS:
        raise SettingsError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    out = Path(out).resolve() if out is not None else default_out_dir(settings)
    max_iter = settings.max_num_iter if max_iter is None else max_iter
    workers = local_workers(workers, settings.num_processes)
    created = _check_out_dir(out, settings)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    # local workers start while the scene is built (their imports included): ~1.5 s off a 2-worker run
    runtime = runtime or Runtime()
    executor = make_executor(workers, scheduler, cluster, cluster_options, progress, background=True, preload=WORKER_PRELOAD,
                             runtime=runtime)
    try:
        # the DRGs' masks on a thread per CPU in one process (GDAL and the profile kernel release the GIL)
        scene = build_scene(settings, skip_missing,
                            map_fn=lambda f, xs: executor.map(f, xs, "masks", meanwhile=True, threads=_threads(executor)),
                            runtime=runtime)
        timings["scene"] = time.perf_counter() - t0
        big = budget_warning(scene.tiles, block_budget(scene), ROW_PIXEL_BYTES)
        if big and warn is not None:
            warn(big)
        if not resume:
            _clear_previous_run(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / MARKER).write_text("lunaralbedo solve output folder\n")
        remove_stale_temporaries(out)
        if settings.register_images:  # image-to-DEM registration: the images' georeference moved (engine/registration.py)
            from .registration import register_scene

            scene = register_scene(scene, out / CHECKPOINT_DIR, resume, timings)
        if scene.settings.refine_dem:  # shape from shading: rounds of solves and height refinements (engine/refine.py)
            from .refine import refine_solve

            if response is not None or exposure_times is not None:
                raise SettingsError("REFINE_DEM 1: not available with --response or --exposure-times")
            run = lambda sc, folder, extra: _run(sc, folder, method, max_iter, tolerance, executor, resume,  # noqa: E731
                                                 timings if extra is not None else {}, plots and extra is not None, extra=extra)
            return refine_solve(scene, out, run, executor, resume)
        return _run(scene, out, method, max_iter, tolerance, executor, resume, timings, plots, (response, exposure_times))
    except (Exception, KeyboardInterrupt) as exc:
        typed = typed_error(exc)
        resumable = any((out / d).exists() for d in (CHECKPOINT_DIR, "sfs")) and not (typed is not None and typed.exit_code == 2)
        if created and not resume and not resumable:
            remove_tree(out)  # bad input (or nothing to resume): leave nothing behind
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


def _run(scene, out, method, max_iter, tol, executor, resume, timings, plots, resp=(None, None), extra=None) -> SolveResult:
    s = scene.settings
    cache = out / CACHE_DIR
    ck = _load_checkpoint(out, scene, method, resume)
    tiles = list(range(len(scene.tiles)))
    t1 = time.perf_counter()
    # camera response (Kim et al.): g for the prepare step, fixed exposures (response/solve_hook.py)
    mode, t_given = given_exposures(s, resp[1], scene.keys)
    t_known = t_given if mode == "fixed" else None
    lut, resp_report = resolve_response(resp[0], lambda: response_observations(scene, executor), scene.keys,
                                        out / RESPONSE_DIR, t_known, ck, plots)
    check_resume(ck, lut, t_known)
    if lut is not None:  # the cached stacks hold g(DN): one cache per response, never a stale one on --resume
        cache = cache / f"g-{lut_digest(lut)}"
    cache.mkdir(parents=True, exist_ok=True)  # tasks create entries inside it, never the run's folders
    rows = sum(t.height for t in scene.tiles)
    def on_tiles(fn, desc, home="tiles", threads=1, **kwargs):  # the scene sent to each worker once; a tile stays on its worker
        if executor.in_process and getattr(executor, "progress", False):
            ROWS.start(desc, rows)  # a bar that moves a block of rows at a time, not only per tile
        try:
            return executor.map(fn, tiles, desc, shared=("scene",), home=home, threads=threads, scene=scene,
                                cache_root=cache, **kwargs)
        finally:
            ROWS.stop()

    metas = _prepare(on_tiles, executor, lut)
    executor.place("tiles", {t: TASK_OBSERVATIONS + sum(m["r_count"]) for t, m in zip(tiles, metas)})
    if mode == "prior" and method == "overlap":  # the overlaps' relative exposures at the prior's overall scale
        t_seed = reduce_init(scene, metas, method)
        t_init = t_seed * np.exp(np.mean(np.log(t_given)) - np.mean(np.log(t_seed)))
    else:
        t_init = reduce_init(scene, metas, method) if t_given is None else t_given
    t_ref = t_given if mode == "prior" else t_init
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
            "response": resp_report,
            "exposure_fixed": t_known is not None,
            "robust": 0,  # generation of the robust weights (engine/robust.py)
            "q_robust": [],  # the generation each Q of "q" was computed with
            "outliers": None,
            "haze": [0.0] * len(scene.images) if s.float_haze else None,  # FLOAT_HAZE: per image, DRG units
        }
        robust.prepared(metas, len(scene.images), ck)  # the spatial test's weights, when the prepare step made them
        outputs.write_json(out / STATE_FILE, ck)
    state = SolveState(np.array(ck["exposure"]), np.array(ck["params"], dtype=np.float64), robust=ck["robust"],
                       haze=None if ck.get("haze") is None else np.array(ck["haze"], np.float64),
                       haze_joint=ck.get("haze_joint", True), exposures_known=t_known is not None)
    resume_info = {"tiles_prepared_before": sum(bool(m.get("reused")) for m in metas), "iterations_done_before": ck["iteration"]}
    n_obs = sum(int(m["observations"]) for m in metas) if all("observations" in m for m in metas) else None
    t2 = time.perf_counter()
    want_phase = bool(scene.model.parameters)
    while not ck["done"] and ck["iteration"] < max_iter:
        reweights = robust.passes(s, ck)
        gen = ck["robust"]
        if gen < len(reweights) and (ck["iteration"] >= reweights[gen] or ck.get("reweight_now")):
            t_rw = time.perf_counter()  # part of the iterate stage; also reported on its own
            state = robust.reweight_pass(on_tiles, _threads(executor), scene, state, ck,
                                         prepare_pairs(metas) if method == "overlap" and t_given is None else None)
            ck.update(haze_joint=True, haze_step=None)  # new weights: the haze settles again
            timings["reweight"] = timings.get("reweight", 0.0) + time.perf_counter() - t_rw
            outputs.write_json(out / STATE_FILE, ck)
            robust.drop_generation(cache, gen)
        parts = on_tiles(iterate_tile, f"iteration {ck['iteration'] + 1}", state=state, want_phase=want_phase,
                         threads=_threads(executor))  # one process: tiles on its CPUs, summed in tile order
        sums = reduce_iteration(len(scene.images), len(scene.model.parameters), parts)
        q_prev = ck["q"][-1] if ck["q"] else None
        ck["q"].append(sums.q)
        converged = q_prev is not None and abs(q_prev - sums.q) <= tol * max(sums.q, 1e-300)
        converged = converged and ck["q_robust"][-1:] == [ck["robust"]]  # a Q of other weights is not comparable
        ck["q_robust"].append(ck["robust"])
        reweights = robust.passes(s, ck)
        if converged and ck["robust"] < len(reweights):  # settled before the last reweight: reweight now, go on
            converged, ck["reweight_now"] = False, True
        before = state
        if not converged:
            state = update(state, sums, method, scene.model, t_ref, fixed=t_known is not None,
                            prior=s.exposure_prior_sigma if mode == "prior" else None)
            ck["params_history"].append(state.params.tolist())
        if sums.haze_parts:  # a joint step: held from the next pass on once it has settled
            haze_step_taken(ck, scene.keys, before, state, sums, converged or ck["iteration"] + 1 >= max_iter,
                            t_known is not None, mode, t_ref, s.exposure_prior_sigma)
        ck.update(iteration=ck["iteration"] + 1, exposure=state.exposure.tolist(), params=state.params.tolist(), done=converged,
                  haze=None if state.haze is None else state.haze.tolist())
        outputs.write_json(out / STATE_FILE, ck)
    timings["iterate"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    skip_done = bool(ck.get("finalising"))
    if not skip_done:
        ck["finalising"] = True  # from here on the state is fixed; finished tiles can be kept
        outputs.write_json(out / STATE_FILE, ck)
    # one process: tiles on its CPUs, at most FINALISE_BYTES of their rows at once; GDAL's threads on the CPUs left
    tile_px = max((min(t.height * t.width, int(block_budget(scene) // ROW_PIXEL_BYTES)) for t in scene.tiles), default=1)
    at_once = max(1, min(_threads(executor), len(tiles), FINALISE_BYTES // (8 * tile_px)))
    tile_reports = on_tiles(finalize_tile, "write tiles", out_dir=out / TILES_DIR, state=state, skip_done=skip_done,
                            write_threads=max(1, executor.cpus_per_task // at_once), threads=at_once)
    resume_info["tiles_written_before"] = sum(bool(r.pop("reused")) for r in tile_reports)
    timings["finalise"] = time.perf_counter() - t3
    costs = stage_costs(timings, n_obs, ck["iteration"] - resume_info["iterations_done_before"])
    return write_run_outputs(scene, out, method, state, t_init, ck, tile_reports, timings, executor, plots, resume_info,
                              costs, extra)


#: Most threads a one-process run gives its tiles (iterations, finalise) and a block's image windows
#: (prepare), however many CPUs it has: memory grows with them (each window in flight, each tile
#: being finalised), the gains flatten beyond (the work is shared with the cache writer, GDAL and
#: the memory bus); more CPUs are for more workers (``--workers N``).
MAX_THREADS = 4
#: Bytes of albedo and error rows (8 per pixel) finalise may hold at once over the tiles it writes on threads
#: (a tile always); each tile holds one block of rows at a time, at most ``block_budget(scene) / ROW_PIXEL_BYTES`` pixels.
FINALISE_BYTES = 256 * 2**20


def _threads(executor) -> int:
    """Threads for the tiles and windows of a run: the executor's CPUs per task, at most :data:`MAX_THREADS`."""
    return max(1, min(executor.cpus_per_task, MAX_THREADS))


def _prepare(on_tiles, executor, lut) -> list:
    """The prepare step over every tile (first come, first served).  In one process the cache is written
    behind the computation of the next tiles and waited for at the end (:mod:`lunaralbedo.io.cachewriter`);
    Dask workers finish writing each tile in its task, so any worker can read it next."""
    if not executor.in_process:
        return on_tiles(prepare_tile, "prepare", home=None, lut=lut)
    try:
        metas = on_tiles(prepare_tile, "prepare", home=None, lut=lut, wait=False, helpers=_threads(executor))
        WRITER.flush()
        robust.release_scratch()  # the spatial test's scratch (engine/robust.py), not kept under the iterations' stacks
        trim_malloc()  # the prepare step's freed heap, not kept resident under the iterations' stacks
    except BaseException:
        WRITER.drain()  # nothing in flight while the run's folder is cleaned up
        raise
    return metas
