"""Settings of worker processes, shared by every way of starting them (local, PBS_NODEFILE, batch jobs)."""
from __future__ import annotations

import os

#: Dask settings of the scheduler, nannies and workers.  Dask's defaults serve its dashboard,
#: which these runs do not start: a statistical profiler sampling every worker's task thread
#: every 10 ms, an event-loop tick every 20 ms and a system monitor every 0.5 s in every server,
#: and each worker's memory checked every 0.1 s.  Measured on a local cluster of 2 workers idle
#: for 20 s: 1.0 s of CPU in the solving process and 1.7 s in the workers with the defaults,
#: 0.2 s and 0.2 s with these (docs/performance.md, section 0b).  The memory limit is still
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


#: Environment of worker processes.  Dask's nanny sets MALLOC_TRIM_THRESHOLD_, which
#: freezes glibc's mmap threshold at 128 KiB: every multi-megabyte NumPy temporary is
#: then a fresh mmap with page faults (measured 1.5-2x slower tile tasks).  A 64 MiB
#: threshold lets temporaries reuse heap memory, as in a plain Python process.  The
#: :data:`DASK_CONFIG` settings go along as Dask's environment variables, for workers
#: started by batch jobs or ``dask worker`` on PBS_NODEFILE nodes.
WORKER_ENV = {"MALLOC_MMAP_THRESHOLD_": 64 * 2**20, **{_env_name(k): v for k, v in DASK_CONFIG.items()}}


def worker_config():
    """A ``dask.config.set`` context for starting a scheduler and nanny-started workers: :data:`DASK_CONFIG`
    (a nanny hands its configuration to its worker) and :data:`WORKER_ENV` in the workers' environment."""
    import dask

    return dask.config.set({**DASK_CONFIG, **{f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in WORKER_ENV.items()}})


def local_workers(requested: int | None, default: int | None = None) -> int:
    """Worker count on this machine: ``requested``, else ``default`` capped at the CPU count, else all CPUs."""
    if requested is not None:
        return max(1, int(requested))
    cpus = os.cpu_count() or 1
    return max(1, min(default, cpus)) if default is not None else cpus
