"""Settings of worker processes, shared by every way of starting them (local, PBS_NODEFILE, batch jobs)."""
from __future__ import annotations

import logging
import os

from ..errors import LunarAlbedoError

#: Dask settings of the scheduler, nannies and workers.  Dask's defaults serve its dashboard,
#: which these runs do not start: a statistical profiler sampling every worker's task thread
#: every 10 ms, an event-loop tick every 20 ms and a system monitor every 0.5 s in every server,
#: and each worker's memory checked every 0.1 s.  Measured on a local cluster of 2 workers idle
#: for 20 s: 1.0 s of CPU in the solving process and 1.7 s in the workers with the defaults,
#: 0.2 s and 0.2 s with these (docs/performance-history.md, section 0b).  The memory limit is still
#: enforced, checked once a second (a tile task's memory is bounded by blocks of rows).
DASK_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}


def _env_name(key: str) -> str:
    """The environment variable Dask reads for config ``key`` (``a.b-c`` -> ``DASK_A__B_C``)."""
    return "DASK_" + "__".join(part.upper().replace("-", "_") for part in key.split("."))


#: glibc malloc settings of the processes that run tile tasks.  A tile task allocates and
#: frees NumPy and numba arrays of 1-60 MB; with glibc's defaults many of them are fresh
#: mmaps, and Dask's nanny sets MALLOC_TRIM_THRESHOLD_ to 64 KiB, which freezes glibc's
#: mmap threshold at 128 KiB and hands freed heap memory back at once: each array is then
#: page-faulted in anew, at ~2.5 µs per 4 KiB page on this project's machine (measured:
#: 150 000 faults and 0.3-0.4 s of kernel time in preparing the strip scene of
#: docs/performance-history.md, 15 000 with these).  Arrays up to 64 MiB come from the heap, and up to
#: 256 MiB of freed memory at its top is kept for the next block or tile: the peak resident
#: memory changes little (what is kept was in use just before; measured +28 MB on the strip,
#: docs/performance-history.md section 0c).  One arena: a Dask worker runs its tasks in a thread, and
#: glibc gives other threads than the main one arenas of at most 64 MiB heaps, so a task
#: holding several arrays of tens of MB at once got new heaps mapped and unmapped under it
#: whatever the thresholds (the 50-image scene's prepare stage: 1 085 000 faults and 8.5 s of
#: kernel time in 2 workers, 88 000 and 5.8 s with one arena; docs/performance-history.md, section 0e).
MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": 64 * 2**20, "MALLOC_TRIM_THRESHOLD_": 256 * 2**20, "MALLOC_ARENA_MAX": 1}

#: NumPy settings of the processes that run tile tasks: no ``madvise(MADV_HUGEPAGE)`` on NumPy's
#: large arrays.  With the kernel's usual transparent-huge-page setting (``defrag`` = madvise) a
#: page fault in such an array compacts and zeroes a 2 MiB page synchronously: measured on the
#: strip of ``make bench`` item 6, the prepare stage of a fresh one-CPU solve took 2.80-3.38 s with
#: NumPy's default and 2.45-2.47 s without (system time 0.90-1.34 -> 0.55-0.59 s), the iterations
#: and finalise unchanged (docs/performance-history.md, section 0j).
NUMPY_ENV = {"NUMPY_MADVISE_HUGEPAGE": "0"}

#: Environment of worker processes: :data:`MALLOC_ENV` (it overrides the nanny's own
#: MALLOC_TRIM_THRESHOLD_), :data:`NUMPY_ENV` and the :data:`DASK_CONFIG` settings as Dask's environment
#: variables, for workers started by batch jobs or ``dask worker`` on PBS_NODEFILE nodes.
WORKER_ENV = {**MALLOC_ENV, **NUMPY_ENV, **{_env_name(k): v for k, v in DASK_CONFIG.items()}}

#: mallopt(3) parameter numbers of glibc's <malloc.h>.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8


def tune_malloc() -> bool:
    """Apply :data:`MALLOC_ENV` to this process (``mallopt``) for tile tasks run in it; False where
    the C library has no ``mallopt`` (not glibc) or the user set one of its variables: nothing
    changes then.

    Called where the run's :class:`~lunaralbedo.runtime.Runtime` asks for it: in worker processes
    (``tune_workers``: the forkserver of local workers, :mod:`.worker_server`; spawned and remote
    workers get :data:`MALLOC_ENV` in their environment, which glibc reads at start) and in this
    process (``tune_process``, for one-worker runs and thread pools; the command line's choice:
    process-wide, a notebook that ran a solve would keep up to 256 MiB of freed memory for reuse).
    Whether the user set malloc variables of their own is the caller's to check.
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):  # no mallopt (macOS), no CDLL(None) (Windows)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    trimmed = mallopt(_M_TRIM_THRESHOLD, MALLOC_ENV["MALLOC_TRIM_THRESHOLD_"])
    mapped = mallopt(_M_MMAP_THRESHOLD, MALLOC_ENV["MALLOC_MMAP_THRESHOLD_"]) or mallopt(_M_MMAP_THRESHOLD, 32 * 2**20)
    arenas = mallopt(_M_ARENA_MAX, MALLOC_ENV["MALLOC_ARENA_MAX"])  # threads started from now on share the main arena
    return bool(trimmed and mapped and arenas)  # 32 MiB: the most older glibc versions accept


def tune_numpy() -> bool:
    """Apply :data:`NUMPY_ENV` to this process for tile tasks run in it (NumPy reads the variable only
    when imported); False where this NumPy has no such switch.  Process-wide, like :func:`tune_malloc`
    (whose callers also decide whether the user's own ``NUMPY_MADVISE_HUGEPAGE`` stands)."""
    import numpy as np

    core = getattr(np, "_core", None) or getattr(np, "core", None)  # NumPy 2 / 1
    switch = getattr(getattr(core, "multiarray", None), "_set_madvise_hugepage", None)
    if switch is None:
        return False
    switch(NUMPY_ENV["NUMPY_MADVISE_HUGEPAGE"] != "0")
    return True


def trim_malloc() -> bool:
    """Hand the free memory of glibc's heap back to the system (``malloc_trim(0)``); False where there is none.

    :data:`MALLOC_ENV` keeps up to 256 MiB of freed heap for the next block; at the end of a stage
    whose arrays are all freed (a one-process run's prepare step), that memory would stay resident
    under the next stage's own (make bench item 10: peaks of 857, 909, 945 MB in three runs without
    the trim, 846, 858, 872 MB with it).
    """
    import ctypes

    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError, TypeError):  # not glibc
        return False
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return bool(trim(0))


def worker_env(tuned: bool = True) -> dict:
    """Environment variables of worker processes: :data:`WORKER_ENV`, or only Dask's settings when the
    workers are not to be tuned (the user's own malloc and NumPy variables then reach them unchanged)."""
    return dict(WORKER_ENV) if tuned else {k: v for k, v in WORKER_ENV.items() if k not in {**MALLOC_ENV, **NUMPY_ENV}}


def worker_config(tuned: bool = True):
    """A ``dask.config.set`` context for starting a scheduler and nanny-started workers: :data:`DASK_CONFIG`
    (a nanny hands its configuration to its worker) and :func:`worker_env` in the workers' environment."""
    import dask

    return dask.config.set({**DASK_CONFIG, **{f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in worker_env(tuned).items()}})


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the system has one, else the CPU count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no sched_getaffinity (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def local_workers(requested: int | None, default: int | None = None) -> int:
    """Worker count on this machine: ``requested``, else ``default`` capped at the CPU count, else all CPUs."""
    if requested is not None:
        return max(1, int(requested))
    cpus = os.cpu_count() or 1
    return max(1, min(default, cpus)) if default is not None else cpus


class WorkerLogFilter(logging.Filter):
    """Leaves out of a Dask worker's log what only repeats, or follows from, the command's own one-line report.

    * the "Compute Failed" record (the task, its exception and a traceback) of a task whose exception is
      one of ours (:class:`~lunaralbedo.errors.LunarAlbedoError`): the client raises it and the command
      prints it on one line (the records of any other failure, a bug, are kept);
    * on a local cluster (``local``), "Failed to communicate with scheduler during heartbeat": its
      scheduler lives in the command's own process, so it is gone only when the command ends (a worker's
      heartbeat racing the cluster's close after an error).

    Installed on the ``distributed.worker`` logger of a worker process: by :func:`dask_setup` as a local
    worker starts, by :func:`~.executor.run_task` when a task first fails with a typed error.
    """

    LOGGER = "distributed.worker"
    HEARTBEAT = "Failed to communicate with scheduler during heartbeat"

    def __init__(self, local: bool = False):
        super().__init__()
        self.local = local

    @classmethod
    def install(cls, local: bool = False) -> None:
        logger = logging.getLogger(cls.LOGGER)
        for f in logger.filters:
            if isinstance(f, cls):
                f.local = f.local or local
                return
        logger.addFilter(cls(local))

    def filter(self, record: logging.LogRecord) -> bool:
        msg = str(record.msg)
        if self.local and msg.startswith(self.HEARTBEAT):
            return False
        args = record.args if isinstance(record.args, tuple) else ()
        if not (msg.startswith("Compute Failed") and len(args) > 3):
            return True
        name = str(args[3]).split("(", 1)[0]  # the exception's repr: Name('message')
        return name not in _typed_error_names()


def dask_setup(worker) -> None:
    """Dask's preload hook, run in each worker of a local cluster as it starts (:func:`.clusters.local_cluster`)."""
    WorkerLogFilter.install(local=True)


def _typed_error_names() -> set[str]:
    """The class names of :class:`~lunaralbedo.errors.LunarAlbedoError` and all its subclasses."""
    names, todo = set(), [LunarAlbedoError]
    while todo:
        cls = todo.pop()
        names.add(cls.__name__)
        todo.extend(cls.__subclasses__())
    return names
