"""Settings of worker processes, shared by every way of starting them (local, PBS_NODEFILE, batch jobs)."""
from __future__ import annotations

import os

#: Environment of worker processes.  Dask's nanny sets MALLOC_TRIM_THRESHOLD_, which
#: freezes glibc's mmap threshold at 128 KiB: every multi-megabyte NumPy temporary is
#: then a fresh mmap with page faults (measured 1.5-2x slower tile tasks).  A 64 MiB
#: threshold lets temporaries reuse heap memory, as in a plain Python process.
WORKER_ENV = {"MALLOC_MMAP_THRESHOLD_": 64 * 2**20}


def worker_config():
    """A ``dask.config.set`` context that gives nanny-started workers :data:`WORKER_ENV`."""
    import dask

    return dask.config.set({f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in WORKER_ENV.items()})


def local_workers(requested: int | None, default: int | None = None) -> int:
    """Worker count on this machine: ``requested``, else ``default`` capped at the CPU count, else all CPUs."""
    if requested is not None:
        return max(1, int(requested))
    cpus = os.cpu_count() or 1
    return max(1, min(default, cpus)) if default is not None else cpus
