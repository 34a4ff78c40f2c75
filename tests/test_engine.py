"""The Dask tile engine: identical bytes for any worker count, resume after kill -9, bounded memory."""
from __future__ import annotations

from lunaralbedo.runtime import Runtime
import filecmp
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lunaralbedo.engine.solve import solve
from lunaralbedo.simulate import SceneSpec, render_scene

RESULT_FILES = ("exposure.csv", "phase.csv")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("engine_scene")
    render_scene(d, SceneSpec(n_images=8, image_px=100, tile_size=0.25, max_num_iter=6, seed=13))
    return d


def same_results(a: Path, b: Path) -> None:
    names = sorted(p.relative_to(a) for p in (a / "albedo").rglob("*.tif"))
    assert names, "no albedo tiles"
    assert names == sorted(p.relative_to(b) for p in (b / "albedo").rglob("*.tif"))
    for sub in ("albedo", "error", "DEM", "weightsSum", "outliers"):
        assert sorted(p.name for p in (a / sub).glob("*.tif")) == sorted(p.name for p in (b / sub).glob("*.tif")), sub
        for p in sorted((a / sub).glob("*.tif")):
            assert filecmp.cmp(p, b / sub / p.name, shallow=False), f"{sub}/{p.name} differs"
    for f in RESULT_FILES:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f"{f} differs"


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "out"
    solve(scene / "settings.txt", out=out, workers=1, plots=False)
    return out


@pytest.mark.parametrize("workers", [2, 4])
def test_local_cluster_matches_single_worker_byte_for_byte(scene, reference, tmp_path, workers):
    out = tmp_path / "out"
    res = solve(scene / "settings.txt", out=out, workers=workers, plots=False)
    assert res.report["executor"] == f"local cluster ({workers} processes)"
    same_results(reference, out)


def test_blocks_are_cached_in_runs_and_read_as_they_are_over_the_memory_budget(scene, reference, tmp_path, monkeypatch):
    """The cache holds the iteration's order, so a block over the stack budget is read memory-mapped as it
    is (no reordering every pass) and gives the bytes of a run that keeps its stacks in memory; a cache
    of another layout (no ``layout`` in its meta) is prepared again, not misread; a finished tile's blocks
    are deleted by its finalise task."""
    import numpy as np

    from lunaralbedo.engine import prepare, runs, tilework
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.io.cache import load_stack, mapped
    from lunaralbedo.settings import load_settings

    sc = build_scene(load_settings(scene / "settings.txt"))
    cache = tmp_path / "cache"
    cache.mkdir()
    t = max(range(len(sc.tiles)), key=lambda t: len(sc.tile_images[t]))
    assert prepare.prepare_tile(t, scene=sc, cache_root=cache)["reused"] is False
    folder = cache / sc.tiles[t].name
    arrays, _ = load_stack(folder / "block_0000")
    start, pixel = np.asarray(arrays["run_start"]), np.asarray(arrays["run_pixel"])
    assert len(arrays["chunks"]) >= 2 and np.all(np.diff(start) > 0) and start[-1] == len(arrays["image"])
    assert np.diff(start).mean() > 20  # runs are rows of the images' footprints, not single pixels
    pix, img = runs.observation_pixels(arrays), runs.observation_images(arrays).astype(np.int64)
    key = pix * len(arrays["index"]) + img
    assert len(np.unique(key)) == len(key) and (np.bincount(pix) > 1).any()  # each observation once; pixels under several images
    for c in range(len(arrays["chunks"]) - 1):  # each chunk image by image in tile order, then by pixel
        o = slice(start[arrays["chunks"][c]], start[arrays["chunks"][c + 1]])
        assert np.all(np.diff(img[o] * (pix.max() + 1) + pix[o]) > 0)
    angles = np.asarray(arrays["alpha"])[np.asarray(arrays["weight"]) > 0]  # the block's phase-angle range, stored
    assert tuple(arrays["alpha_range"]) == (np.nanmin(angles), np.nanmax(angles))
    meta = json.loads((folder / "meta.json").read_text())
    assert prepare.prepare_tile(t, scene=sc, cache_root=cache)["reused"] is True
    (folder / "meta.json").write_text(json.dumps({k: v for k, v in meta.items() if k != "layout"}))
    assert prepare.prepare_tile(t, scene=sc, cache_root=cache)["reused"] is False
    assert json.loads((folder / "meta.json").read_text())["layout"] == tilework.CACHE_LAYOUT

    monkeypatch.setattr(tilework.STACKS, "budget", 0)
    tilework.STACKS.clear()
    got = tilework.pixel_stack(folder / "block_0000", cache)
    assert mapped(got["image"]) and tilework.STACKS.nbytes == 0
    out = tmp_path / "out"
    solve(scene / "settings.txt", out=out, workers=1, plots=False)
    assert tilework.STACKS.nbytes == 0
    same_results(reference, out)

    # a finished tile drops its cached blocks (not its meta); a task run again reports the tile as done
    state = tilework.SolveState(np.ones(len(sc.images)), sc.settings.initial_params.copy())
    first = tilework.finalize_tile(t, scene=sc, cache_root=cache, out_dir=tmp_path / "tiles", state=state)
    assert first["reused"] is False and first["valid_pixels"] > 0
    assert not list(folder.glob("block_*")) and (folder / "meta.json").is_file()
    again = tilework.finalize_tile(t, scene=sc, cache_root=cache, out_dir=tmp_path / "tiles", state=state)
    assert again == {**first, "reused": True}


def test_a_tile_prepared_again_is_iterated_with_its_new_meta(scene, tmp_path, monkeypatch):
    """The iterations read a tile's meta once per process; a tile prepared again (other blocks, a new
    ``meta.json``) in the same process is iterated with its new blocks, not the ones remembered."""
    import numpy as np

    from lunaralbedo.engine import prepare, tilework
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.settings import load_settings

    sc = build_scene(load_settings(scene / "settings.txt"), False, map_fn=lambda f, xs: list(map(f, xs)))
    t = max(range(len(sc.tiles)), key=lambda i: len(sc.tile_images[i]))
    state = tilework.SolveState(np.ones(len(sc.images)), sc.settings.initial_params.copy())
    sums = {}
    for rows in ("1000", "7"):
        sc.runtime = Runtime(block_rows=int(rows))
        shutil.rmtree(tmp_path / "cache", ignore_errors=True)
        meta = prepare.prepare_tile(t, scene=sc, cache_root=tmp_path / "cache")
        sums[rows] = (len(meta["blocks"]), tilework.iterate_tile(t, scene=sc, cache_root=tmp_path / "cache", state=state,
                                                                 want_phase=True))
    (one, whole), (many, blocks) = sums["1000"], sums["7"]
    assert one == 1 and many > 3
    assert blocks.n_obs == whole.n_obs > 0
    np.testing.assert_allclose(blocks.q, whole.q, rtol=1e-9)
    np.testing.assert_allclose(blocks.exp_num, whole.exp_num, rtol=1e-9)


def _start(scene: Path, out: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "lunaralbedo.cli", "solve", str(scene / "settings.txt"), "-o", str(out), "--workers", "1", "--quiet", *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _kill_when(proc: subprocess.Popen, ready, timeout: float = 60.0) -> None:
    t0 = time.monotonic()
    while not ready():
        assert proc.poll() is None, "the run finished before it could be killed: " + proc.stderr.read().decode()
        assert time.monotonic() - t0 < timeout, "marker never appeared"
        time.sleep(0.002)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()


def _state(out: Path) -> dict:
    try:
        return json.loads((out / "checkpoint" / "state.json").read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}


@pytest.mark.parametrize("stage", ["prepare", "iterate", "finalise"])
def test_resume_after_kill_9_gives_identical_results(scene, reference, tmp_path, stage):
    out = tmp_path / "out"
    markers = {
        "prepare": lambda: len(list((out / "checkpoint" / "cache").glob("tile_*"))) >= 3,
        "iterate": lambda: _state(out).get("iteration", 0) >= 2,
        "finalise": lambda: len(list((out / "checkpoint" / "tiles" / "weightsSum").glob("tile_*.tif"))) >= 2,
    }
    proc = _start(scene, out)
    _kill_when(proc, markers[stage])
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "report.json").exists(), "killed too late"
    res = subprocess.run(
        [sys.executable, "-m", "lunaralbedo.cli", "solve", str(scene / "settings.txt"), "-o", str(out), "--workers", "1", "--quiet", "--resume"],
        capture_output=True, text=True,
    )
    assert res.returncode == 0, res.stderr
    same_results(reference, out)
    resumed = json.loads((out / "report.json").read_text())["resumed"]
    assert resumed is not None
    if stage == "prepare":
        assert resumed["tiles_prepared_before"] >= 3
    if stage == "iterate":
        assert resumed["iterations_done_before"] >= 2
    if stage == "finalise":
        assert resumed["tiles_written_before"] >= 2
    assert not list(out.rglob(".tmp-*")), "temporary files left behind"


def test_resume_refuses_a_checkpoint_of_other_settings(scene, tmp_path):
    out = tmp_path / "out"
    proc = _start(scene, out)
    _kill_when(proc, lambda: _state(out).get("iteration", 0) >= 1)
    changed = tmp_path / "s.txt"
    changed.write_text((scene / "settings.txt").read_text().replace("TR_CONST                  1.5", "TR_CONST                  2.5")
                       .replace("DRG_DIR                   DRG", f"DRG_DIR {scene / 'DRG'}")
                       .replace("DEM_DIR                   DEM", f"DEM_DIR {scene / 'DEM'}")
                       .replace("meta/", f"{scene}/meta/"))
    res = subprocess.run([sys.executable, "-m", "lunaralbedo.cli", "solve", str(changed), "-o", str(out), "--resume", "--quiet"],
                         capture_output=True, text=True)
    assert res.returncode == 2 and "checkpoint belongs to other settings" in res.stderr


# Peak resident memory of this process image: VmHWM (ru_maxrss would inherit the
# parent's peak across fork/exec on Linux, and the parent rendered the scene).
PEAK_RSS = """
import sys
from lunaralbedo import Runtime
from lunaralbedo.engine.solve import solve
solve(sys.argv[1], out=sys.argv[2], workers=1, plots=False,
      runtime=Runtime(stack_memory_mb=float(sys.argv[3])) if len(sys.argv) > 3 else None)
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
print(int(hwm.split()[1]) // 1024)
"""


def _peak_mb(settings: Path, out: Path, stack_memory_mb: int | None = None) -> int:
    budget = [str(stack_memory_mb)] if stack_memory_mb is not None else []
    res = subprocess.run([sys.executable, "-c", PEAK_RSS, str(settings), str(out), *budget], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return int(res.stdout.split()[-1])


def test_memory_depends_on_the_tile_not_on_the_number_of_images(tmp_path):
    """A 4x longer strip (4x the images, 4x the observations) must not need more memory than the
    stacks kept in memory between iterations (here a budget of 8 MB, below the ~100 MB they take)."""
    budget = 8
    peaks, obs = {}, {}
    px = 500
    for n in (6, 24):
        d = tmp_path / f"s{n}"
        render_scene(d, SceneSpec(n_images=n, image_px=px, res_deg=0.0025, tile_size=0.5, max_num_iter=2, seed=n))
        peaks[n] = _peak_mb(d / "settings.txt", tmp_path / f"o{n}", budget)
        # what holding every observation in memory would take: image, weight, mask, geometry, alpha
        # (4 + 4 + 1 + 4 + 4 bytes per observation), as a whole-scene implementation must
        obs[n] = n * px * px * 17 / 2**20
    # flat: the long strip needs at most 20 MB (+ the budget) more, while a whole-scene stack would need ~80 MB more
    assert obs[24] - obs[6] > 70  # MB
    assert peaks[24] - peaks[6] < 20 + budget, (peaks, obs)
    assert peaks[24] < peaks[6] + 0.25 * (obs[24] - obs[6]), (peaks, obs)


def test_pbs_nodefile_starts_workers_on_every_listed_node(scene, reference, tmp_path, monkeypatch):
    """PBS lists a host once per core; workers start on each distinct host (here: a stand-in remote shell) when
    the node file is given; a set PBS_NODEFILE alone starts nothing remote (the library reads no environment)."""
    nodefile = tmp_path / "nodes"
    nodefile.write_text("localhost\nlocalhost\nnode-b\nnode-b\n")
    # like ssh, the launcher gets HOST and a command line to run there; this one runs it here
    rt = Runtime(nodefile=str(nodefile), remote_shell="sh -c 'shift; eval \"exec $*\"' launcher")
    out = tmp_path / "out"
    res = solve(scene / "settings.txt", out=out, workers=1, plots=False, runtime=rt)
    assert res.report["executor"] == "PBS_NODEFILE (2 nodes x 1 processes)"
    same_results(reference, out)
    monkeypatch.setenv("PBS_NODEFILE", str(nodefile))
    res = solve(scene / "settings.txt", out=tmp_path / "plain", workers=1, plots=False)
    assert res.report["executor"] == "in-process (1 worker)", res.report["executor"]


def test_ingest_cubes_in_parallel_match_serial(tmp_path):
    """Ingest's per-cube tasks on a local Dask cluster write the same DRGs and positions as one process."""
    from lunaralbedo.ingest.run import ingest

    repo = Path(__file__).resolve().parents[1]
    cubes = sorted((repo / "sample_data" / "cubes").glob("*.cub"))
    serial = ingest(cubes, [repo / "sample_data" / "dem"], tmp_path / "w1")
    parallel = ingest(cubes, [repo / "sample_data" / "dem"], tmp_path / "w2", workers=2)
    assert [r.key for r in serial.done] == [r.key for r in parallel.done] and len(serial.done) == len(cubes)
    for p in sorted((tmp_path / "w1" / "DRG").glob("*.tif")):
        assert filecmp.cmp(p, tmp_path / "w2" / "DRG" / p.name, shallow=False), p.name
    for f in ("meta/sunpos.txt", "meta/spacecraftpos.txt", "settings.txt"):
        assert (tmp_path / "w1" / f).read_text().replace("w1", "") == (tmp_path / "w2" / f).read_text().replace("w2", "")


@pytest.mark.parametrize(
    "kind, expect",
    [
        ("slurm", ["#SBATCH -p normal", "#SBATCH -A lunar", "#SBATCH -t 04:00:00", "--nworkers 4", "--nthreads 1",
                   "export MALLOC_MMAP_THRESHOLD_=67108864", "export MALLOC_TRIM_THRESHOLD_=268435456",
                   "export MALLOC_ARENA_MAX=1", "export DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False"]),
        ("pbs", ["#PBS -q normal", "#PBS -l walltime=04:00:00", "ncpus=4", "--nworkers 4", "--nthreads 1",
                 "export MALLOC_MMAP_THRESHOLD_=67108864", "export MALLOC_TRIM_THRESHOLD_=268435456",
                 "export MALLOC_ARENA_MAX=1", "export DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL=1s"]),
    ],
)
def test_batch_cluster_job_scripts(kind, expect):
    """--cluster pbs|slurm: dask-jobqueue job scripts carry the queue, account, walltime and single-threaded workers."""
    from lunaralbedo.parallel import jobqueue_cluster

    opts = dict(queue="normal", cores=4, memory="16GB", walltime="04:00:00", account="lunar", jobs=2)
    cluster = jobqueue_cluster(kind, opts)
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    for e in expect:
        assert e in script, script


#: Minor page faults of allocating, filling and freeing a 2 MiB NumPy array ten times (512 pages of 4 KiB; NumPy
#: asks for huge pages from 4 MiB on, which would hide the count).
FAULTS_OF_REUSE = """
import resource, numpy as np
def faults_of_reuse():
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(10):
        a = np.empty(2**18)
        a[:] = 1.0
        del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0
"""


def cli_runtime_of(extra: dict):
    """The command line's runtime with ``extra`` variables in its environment."""
    import unittest.mock

    from lunaralbedo.cli._common import cli_runtime

    with unittest.mock.patch.dict(os.environ, extra):
        return cli_runtime()


#: Minor page faults of holding four arrays of 20-56 MB at once and freeing them, ten times, as a tile task's
#: blocks do: over the 64 MiB heaps glibc gives threads other than the main one, whatever the thresholds.
FAULTS_OF_ARRAYS_HELD_TOGETHER = """
import resource, numpy as np
def faults_of_arrays_held_together(item=None):
    f0 = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    for _ in range(10):
        held = []
        for n in (3_000_000, 5_000_000, 7_000_000, 2_500_000):
            held.append(np.empty(n))
            held[-1][:] = 1.0
        del held
    return resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - f0
"""

#: The faults of FAULTS_OF_ARRAYS_HELD_TOGETHER in a new thread, after tune_malloc() or not, once the main thread
#: ran it (as the solving process's main thread runs tasks before a thread pool's).
IN_A_THREAD = FAULTS_OF_ARRAYS_HELD_TOGETHER + """
import sys, threading
from lunaralbedo.parallel.workers import tune_malloc
if sys.argv[1] == "tuned":
    assert tune_malloc()
faults_of_arrays_held_together()
seen = []
t = threading.Thread(target=lambda: seen.extend([faults_of_arrays_held_together(), faults_of_arrays_held_together()]))
t.start(); t.join()
print(seen[1])
"""


def test_tasks_in_threads_reuse_arrays_held_together_after_tune_malloc():
    """A thread (a Dask worker's task thread, a thread pool's) holding several arrays of tens of MB faults
    them in anew every round in glibc's default per-thread arenas (thousands of faults), and reuses them
    (none) once tune_malloc() has capped the arenas at one."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    faults = {}
    for how in ("default", "tuned"):
        out = subprocess.run([sys.executable, "-c", IN_A_THREAD, how], env=env, capture_output=True, text=True, check=True)
        faults[how] = int(out.stdout)
    assert faults["default"] >= 2000 and faults["tuned"] <= 200, faults

def test_tune_malloc_lets_freed_arrays_be_reused():
    """In the state Dask's nanny leaves glibc in (MALLOC_TRIM_THRESHOLD_=65536: trim threshold 64 KiB, mmap
    threshold frozen at 128 KiB) every freed array goes back to the kernel and the next one is page-faulted
    in anew; after tune_malloc() the heap keeps it for the next.  Where the user set a MALLOC_* variable of
    their own, the command line does not tune (the library tunes its own processes only when asked)."""
    code = FAULTS_OF_REUSE + """
import ctypes
from lunaralbedo.parallel.workers import tune_malloc
mallopt = ctypes.CDLL(None).mallopt
assert mallopt(-1, 65536) and mallopt(-3, 128 * 1024)  # M_TRIM_THRESHOLD, M_MMAP_THRESHOLD: the nanny's state
before = faults_of_reuse()
ok = tune_malloc()
faults_of_reuse()  # the first array after the change may still fault in
print(before, ok, faults_of_reuse())
"""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    before, ok, after = out.stdout.split()
    assert ok == "True"
    assert int(before) >= 8 * 512, out.stdout  # every array faulted in again
    assert int(after) <= 512, out.stdout  # reused: at most one array's pages in ten rounds
    assert not cli_runtime_of({"MALLOC_TRIM_THRESHOLD_": "65536"}).tune_process  # the user's setting stays in force


def test_tune_numpy_turns_off_hugepage_advice_unless_the_user_set_it():
    """tune_numpy() stops NumPy's madvise(MADV_HUGEPAGE) on large arrays in this process (NUMPY_ENV); a user's
    own NUMPY_MADVISE_HUGEPAGE stays in force."""
    code = ("from numpy._core.multiarray import _get_madvise_hugepage as get; "
            "from lunaralbedo.parallel.workers import tune_numpy; "
            "before = get(); ok = tune_numpy(); print(before, ok, get())")
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True", "False"]
    assert not cli_runtime_of({"NUMPY_MADVISE_HUGEPAGE": "1"}).tune_workers


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="workers are forked from a server on Linux")
def test_local_workers_are_forked_from_one_server_that_imported_the_package(monkeypatch):
    """Local workers are forks of one server process that imported distributed and the preloaded modules once
    (parallel/forkserver.py), not fresh interpreters that each import them again; the server was tuned
    (parallel/worker_server.py) without this process's environment being touched.
    ``Runtime(worker_start="spawn")`` gives Dask's fresh interpreters (children of this process, where the nannies
    run); any other value is a SettingsError before anything starts."""
    import os
    import sys

    from lunaralbedo.errors import SettingsError
    from lunaralbedo.parallel.executor import make_executor

    env_before = dict(os.environ)

    def parents(preload=(), runtime=None):
        ex = make_executor(2, preload=preload, runtime=runtime)
        try:
            return ex.client.run(lambda: (os.getppid(), "lunaralbedo.engine.tilework" in sys.modules,
                                          "lunaralbedo.parallel.worker_server" in sys.modules))
        finally:
            ex.close()

    forked = parents(("lunaralbedo.engine.tilework",))
    servers = {p for p, _, _ in forked.values()}
    assert len(forked) == 2 and len(servers) == 1 and os.getpid() not in servers
    assert all(loaded and tuned for _, loaded, tuned in forked.values())
    assert servers == {p for p, _, _ in parents().values()}  # the same server serves the next cluster
    assert dict(os.environ) == env_before
    assert {p for p, _, _ in parents(runtime=Runtime(worker_start="spawn")).values()} == {os.getpid()}
    with pytest.raises(SettingsError, match="LUNARALBEDO_WORKER_START must be one of forkserver, spawn"):
        make_executor(2, runtime=Runtime(worker_start="fork"))


def test_local_workers_run_without_dashboard_monitors():
    """A local cluster's workers and scheduler get DASK_CONFIG (no task profiler, slow ticks) and the tuning of
    WORKER_ENV, whose malloc settings take effect (the workers reuse freed arrays instead of faulting them in again), and
    so does its NumPy setting (no hugepage advice)."""
    import os

    import dask

    from lunaralbedo.parallel.executor import make_executor
    from lunaralbedo.parallel.workers import DASK_CONFIG

    ex = make_executor(2)
    try:
        seen = ex.client.run(lambda: {k: dask.config.get(k) for k in DASK_CONFIG})
        hugepage = ex.client.run(lambda: __import__("numpy")._core.multiarray._get_madvise_hugepage())
        scope: dict = {}
        exec(FAULTS_OF_REUSE, scope)
        ex.client.run(scope["faults_of_reuse"])  # the first array may fault in
        faults = ex.client.run(scope["faults_of_reuse"])
        exec(FAULTS_OF_ARRAYS_HELD_TOGETHER, scope)
        ex.client.run(scope["faults_of_arrays_held_together"])  # the workers' main threads fill the heap once
        held = ex.map(scope["faults_of_arrays_held_together"], [0, 1, 2, 3])  # their task threads reuse it
        tick_ms = ex.client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.periodic_callbacks["tick"].callback_time)
        assert ex.map(abs, [-3, 2, -1]) == [3, 2, 1]  # results in the order of the items
    finally:
        ex.close()
    assert len(seen) == 2 and len(faults) == 2
    for config in seen.values():  # the malloc settings are checked by their effect: the faults below
        assert config == DASK_CONFIG
    assert all(f <= 512 for f in faults.values()), faults
    # one arena for every thread: 5700-10300 faults a task with one per thread; here at most the heap's growth
    # by a few MB on a worker's first task, in 4 KiB pages (NUMPY_ENV: no huge pages), and ~none after
    assert all(f <= 2000 for f in held) and max(sorted(held)[:2]) <= 100, held
    assert tick_ms == 1000  # the scheduler's event-loop tick, 20 ms by Dask's default
    assert set(hugepage.values()) == {False}  # NUMPY_ENV's setting: no hugepage advice in the workers


#: The address of the worker running a task, after ``pause`` seconds (defined by value: workers cannot import tests).
ADDRESS_OF_WORKER = """
def address_of_worker(item, pause=0.0):
    import time
    from distributed import get_worker
    time.sleep(pause)
    return get_worker().address
"""


def test_tasks_with_a_home_run_again_on_the_worker_that_ran_them_first():
    """The solver's tile tasks carry ``home="tiles"``: a tile's iterations and finalise go to the worker that
    prepared it, where its blocks are held in memory (per process) and freed.  Without the label, quick
    tasks go wherever a worker is free (2 to the power 8 ways for 8 items)."""
    from lunaralbedo.parallel.executor import make_executor

    scope: dict = {}
    exec(ADDRESS_OF_WORKER, scope)
    items = [f"tile_{i}" for i in range(8)]
    ex = make_executor(2)
    try:
        first = ex.map(scope["address_of_worker"], items, home="tiles", pause=0.1)  # placed as the workers come free
        again = [ex.map(scope["address_of_worker"], items, home="tiles") for _ in range(3)]
        workers = set(ex.client.scheduler_info()["workers"])
    finally:
        ex.close()
    assert set(first) == workers and len(workers) == 2  # both workers took tiles
    assert all(a == first for a in again), (first, again)


def test_placed_homes_share_the_work_evenly_and_are_kept():
    """``place`` gives each worker about the same total cost (longest first, to the least loaded
    worker), and later maps with the label run every item on the worker it was given."""
    from lunaralbedo.parallel.executor import make_executor

    scope: dict = {}
    exec(ADDRESS_OF_WORKER, scope)
    costs = {f"tile_{i}": float(c) for i, c in enumerate([1, 8, 3, 6, 2, 7, 5, 4])}  # 36 in all
    ex = make_executor(2)
    try:
        ex.place("tiles", costs)
        ran = [ex.map(scope["address_of_worker"], list(costs), home="tiles") for _ in range(2)]
        workers = sorted(ex.client.scheduler_info()["workers"])
    finally:
        ex.close()
    assert ran[0] == ran[1]
    load = {w: sum(c for item, c in costs.items() if ran[0][list(costs).index(item)] == w) for w in workers}
    assert sorted(load.values()) == [18.0, 18.0], load  # LPT: 8+5+4+1 and 7+6+3+2
    assert ran[0][list(costs).index("tile_1")] == workers[0]  # the costliest item goes to the first address


#: The item, the worker and the Dask task that ran it (defined by value, as above).
ITEM_WORKER_TASK = """
def item_worker_task(item):
    from distributed import get_worker
    from distributed.worker import thread_state
    return item, get_worker().address, thread_state.key
"""


def test_a_map_with_homes_runs_in_a_few_batches_per_worker_and_returns_results_in_item_order():
    """With homes, each worker's items go to it in at most ``BATCHES_PER_WORKER`` Dask tasks (not one per
    item), and the results still come back one per item, in the order of the items given."""
    from lunaralbedo.parallel.executor import BATCHES_PER_WORKER, make_executor

    scope: dict = {}
    exec(ITEM_WORKER_TASK, scope)
    items = [f"tile_{i}" for i in range(30)]
    ex = make_executor(2)
    try:
        ex.place("tiles", {t: float(i % 7 + 1) for i, t in enumerate(items)})
        homes = dict(ex._homes["tiles"])
        order = items[::-1]  # a map may list the items in any order
        ran = ex.map(scope["item_worker_task"], order, home="tiles")
    finally:
        ex.close()
    assert [r[0] for r in ran] == order
    assert all(worker == homes[item] for item, worker, _ in ran)
    tasks: dict = {}
    for item, worker, key in ran:
        tasks.setdefault((worker, key), []).append(item)
    for worker in set(homes.values()):
        n = sum(1 for w in homes.values() if w == worker)  # its items, split in near-equal batches
        sizes = sorted(len(v) for (w, _), v in tasks.items() if w == worker)
        assert len(sizes) == BATCHES_PER_WORKER and sum(sizes) == n and sizes[-1] - sizes[0] <= 1, (worker, sizes)


def test_a_one_process_map_on_threads_keeps_the_items_order_and_stops_at_a_failure():
    """``SerialExecutor.map(threads=n)`` (a one-worker solve's iterations and finalise): the tasks run on n threads
    at once, the results come back in the order of the items; a failure is raised (the first in the items' order)
    once the running tasks end, and the items not started are dropped."""
    import threading

    from lunaralbedo.parallel.executor import SerialExecutor

    ex, started, running, most = SerialExecutor(), [], [0], [0]
    lock = threading.Lock()

    def task(x, fail=None):
        with lock:
            started.append(x)
            running[0] += 1
            most[0] = max(most[0], running[0])
        time.sleep(0.02 if x % 2 else 0.005)  # items end out of order
        with lock:
            running[0] -= 1
        if x == fail:
            raise ValueError(f"item {x} failed")
        return x * 10

    assert ex.map(task, range(12), threads=3) == [x * 10 for x in range(12)]
    assert most[0] == 3 and sorted(started) == list(range(12))
    assert ex.map(task, range(3), threads=1) == [0, 10, 20]
    started.clear()
    with pytest.raises(ValueError, match="item 2 failed"):
        ex.map(task, range(40), threads=2, fail=2)
    assert 3 <= len(started) < 40 and sorted(started) == list(range(len(started)))


#: The process and the modules already imported where a task runs (defined by value, as above).
PID_AND_MODULES = """
def pid_and_modules(item, names=()):
    import os, sys
    return os.getpid(), [n for n in names if n in sys.modules]
"""


def test_a_cluster_started_in_the_background_runs_early_work_here_and_the_rest_on_its_workers():
    """``background=True``: the local cluster starts in a thread; a ``meanwhile`` map issued at once runs in
    this process, a plain map waits for the workers, which imported the ``preload`` modules as they started."""
    from lunaralbedo.parallel.executor import make_executor

    scope: dict = {}
    exec(PID_AND_MODULES, scope)
    fn, module, other = scope["pid_and_modules"], "lunaralbedo.model.exposure_init", "lunaralbedo.response.fit"
    t0 = time.perf_counter()
    ex = make_executor(2, background=True, preload=(module,))
    returned_after = time.perf_counter() - t0
    try:
        early = ex.map(fn, [0, 1], meanwhile=True)
        later = ex.map(fn, [0, 1, 2, 3], names=(module, other))
        late_meanwhile = ex.map(fn, [0], meanwhile=True)
    finally:
        ex.close()
    assert returned_after < 0.5  # the start itself takes ~1-2 s
    assert {pid for pid, _ in early} == {os.getpid()}
    assert os.getpid() not in {pid for pid, _ in later} and all(mods == [module] for _, mods in later)  # preloaded, not the other
    assert late_meanwhile[0][0] != os.getpid()  # once the workers are up, meanwhile maps go to them too


def test_a_cluster_that_fails_to_start_in_the_background_is_a_cluster_error_at_first_use():
    from lunaralbedo.errors import ClusterError
    from lunaralbedo.parallel.executor import make_executor

    ex = make_executor(2, memory_limit="a lot", background=True)
    try:
        with pytest.raises(ClusterError, match="local cluster of 2 processes"):
            ex.map(abs, [-1])
    finally:
        ex.close()  # nothing to close, no error


def test_each_tile_kind_is_written_with_its_predictor(reference):
    """Eq. 7's error has no smooth rows: its tiles are written with predictor 1 (faster, no bigger); the weight
    sums, smooth or constant, with horizontal differencing (faster, as small); albedo and DEM keep ZSTD with
    the floating-point predictor (read back through GDAL)."""
    import rasterio

    seen = {}
    for sub in ("albedo", "error", "DEM", "weightsSum"):
        files = sorted((reference / sub).glob("*.tif"))
        assert files, sub
        for f in files:
            with rasterio.open(f) as ds:
                tags = ds.tags(ns="IMAGE_STRUCTURE")
                seen.setdefault(sub, set()).add((tags.get("COMPRESSION"), tags.get("PREDICTOR", "1")))
    assert seen == {"albedo": {("ZSTD", "3")}, "error": {("ZSTD", "1")}, "DEM": {("ZSTD", "3")},
                    "weightsSum": {("ZSTD", "2")}}, seen


def test_a_one_worker_solve_runs_its_tiles_on_every_cpu_and_writes_the_same_files(scene, reference, tmp_path,
                                                                                   monkeypatch):
    """In-process runs (one worker) iterate and finalise their tiles on as many threads as they have CPUs (the
    kernels release the GIL; the sums are added in tile order), each tile's GeoTIFFs compressed by one thread; a
    run of one tile gives GDAL's compression every CPU instead (NUM_THREADS).  DEM and weight-sum tiles are written
    by the cache writer's thread.  A worker of a cluster or a thread pool uses one CPU per task.  The files are the
    same bytes either way: here against a run confined to one CPU, and in
    ``test_local_cluster_matches_single_worker_byte_for_byte`` against 2 and 4 workers."""
    import threading

    import numpy as np
    from rasterio.transform import Affine

    import lunaralbedo.engine.solve as solve_module
    import lunaralbedo.parallel.executor as executor_module
    from lunaralbedo.engine import tilework
    from lunaralbedo.io.rasters import MOON_CRS
    from lunaralbedo.parallel.executor import DaskExecutor, LocalPoolExecutor, SerialExecutor
    from lunaralbedo.parallel.workers import available_cpus

    cpus = available_cpus()
    assert SerialExecutor().cpus_per_task == cpus == len(os.sched_getaffinity(0))
    assert LocalPoolExecutor(2).cpus_per_task == 1 and DaskExecutor.cpus_per_task == 1
    from lunaralbedo.io import cachewriter
    from lunaralbedo.io.geotiff import GeoTiffRows, write_geotiff

    seen = []
    ran = {"iterate": set(), "finalise": set()}

    class Spy(GeoTiffRows):  # each tile output is one GeoTiffRows, written a block of rows at a time
        def __init__(self, path, *args, threads=1, **kwargs):
            path = Path(path)  # a tile output (albedo/tile_*.tif) or one in a cache entry (DEM.tif)
            seen.append((path.parent.name if path.name.startswith("tile_") else path.stem, threads))
            super().__init__(path, *args, threads=threads, **kwargs)

    def on_thread(stage, fn):
        def task(*args, **kwargs):
            ran[stage].add(threading.get_ident())
            time.sleep(0.01)  # long enough for the other threads to take the next tiles
            return fn(*args, **kwargs)
        return task

    monkeypatch.setattr(tilework, "GeoTiffRows", Spy)
    monkeypatch.setattr(cachewriter, "GeoTiffRows", Spy)
    monkeypatch.setattr(solve_module, "iterate_tile", on_thread("iterate", solve_module.iterate_tile))
    monkeypatch.setattr(solve_module, "finalize_tile", on_thread("finalise", solve_module.finalize_tile))
    out = tmp_path / "out"
    solve(scene / "settings.txt", out=out, workers=1, plots=False)
    n_tiles = len(list((out / "albedo").glob("tile_*.tif")))
    assert n_tiles >= 2
    at_once = min(cpus, n_tiles, solve_module.MAX_THREADS)
    assert len(ran["iterate"]) == len(ran["finalise"]) == at_once, ran
    each = max(1, cpus // at_once)
    assert set(seen) == {("albedo", each), ("error", each), ("outliers", each), ("DEM", 1), ("weightsSum", 1)}, seen
    assert len(seen) == 5 * n_tiles
    same_results(reference, out)
    # finalise within its memory bound (here: one tile's rasters): one tile at a time, GDAL's threads on the CPUs
    monkeypatch.setattr(solve_module, "FINALISE_BYTES", 1)
    seen.clear()
    ran = {"iterate": set(), "finalise": set()}
    solve(scene / "settings.txt", out=tmp_path / "bounded", workers=1, plots=False)
    assert len(ran["iterate"]) == min(cpus, n_tiles, solve_module.MAX_THREADS) and len(ran["finalise"]) == 1, ran
    assert {t for k, t in seen if k in ("albedo", "error")} == {cpus}
    same_results(reference, tmp_path / "bounded")
    # confined to one CPU: one tile at a time, the same bytes
    monkeypatch.setattr(executor_module, "available_cpus", lambda: 1)
    seen.clear()
    ran = {"iterate": set(), "finalise": set()}
    solve(scene / "settings.txt", out=tmp_path / "one_cpu", workers=1, plots=False)
    assert len(ran["iterate"]) == len(ran["finalise"]) == 1 and {t for _, t in seen} == {1}
    same_results(reference, tmp_path / "one_cpu")
    tile = np.random.default_rng(3).normal(size=(700, 900)).astype(np.float32).cumsum(1)  # 12 blocks of 256 px
    for threads in (1, 3):
        write_geotiff(tmp_path / f"t{threads}.tif", tile, Affine(0.01, 0, 0, 0, -0.01, 0), MOON_CRS, threads=threads)
    assert (tmp_path / "t1.tif").read_bytes() == (tmp_path / "t3.tif").read_bytes()
