"""Local worker processes forked from a server that has imported the package once.

Dask starts each local worker as a fresh interpreter by default (``spawn``): every worker then
imports Dask, NumPy, numba, rasterio and the solver's modules itself, ~0.75 s of CPU and ~100 MB
of memory of its own each.  With the ``forkserver`` start method one server process imports them
once, and each worker is a fork of it that shares those pages: ~0.03 s of CPU to start, an idle
worker 108 MB resident instead of 210 MB, and the workers' peaks in a two-worker solve 432-506
instead of 516-593 MB (the strip of ``make bench`` item 6) and 792 instead of 879 MB (item 1's
50-image scene).  On this project's 2-CPU machine, where the workers' imports ran beside the
scene's build, the two-worker solve of that scene took 20.99-22.17 s (median 21.2) in four runs
against 21.00-22.79 s (median 22.3) spawned, back to back (docs/performance-history.md, 0p).

The server gets :data:`~.workers.WORKER_ENV` in its environment when it starts, as a spawned
worker would from its nanny: glibc reads the malloc settings and NumPy its hugepage switch when
the server starts and imports NumPy, and every worker forked from it inherits them.  It lives
as long as this process and serves its later local clusters too, so a worker runs the code this
process first loaded: after editing the package in a notebook, restart the kernel (or set
``LUNARALBEDO_WORKER_START=spawn``, the default where the platform is not Linux or has no
``forkserver``).
"""
from __future__ import annotations

import multiprocessing
import os
import sys
import threading

from ..errors import ClusterError
from .workers import WORKER_ENV

#: Environment variable choosing how local workers start: ``forkserver`` (the default on Linux) or ``spawn``
#: (Dask's default: each worker a fresh interpreter; the default elsewhere).
START_ENV = "LUNARALBEDO_WORKER_START"
START_METHODS = ("forkserver", "spawn")

_LOCK = threading.Lock()
_OURS = False  # this module started the running forkserver (with the package preloaded and WORKER_ENV)


def start_method() -> str:
    """How local workers start: :data:`START_ENV`, by default ``forkserver`` on Linux and ``spawn`` elsewhere (on
    macOS a process that forks without exec may crash in system frameworks, which is why Python spawns there);
    ``spawn`` where there is no forkserver."""
    default = "forkserver" if sys.platform.startswith("linux") else "spawn"
    wanted = os.environ.get(START_ENV, default).strip().lower()
    if wanted not in START_METHODS:
        raise ClusterError(f"{START_ENV} must be one of {', '.join(START_METHODS)}, got {wanted!r}")
    if wanted == "forkserver" and "forkserver" not in multiprocessing.get_all_start_methods():
        return "spawn"
    return wanted


def ready(preload: tuple = ()) -> str:
    """The start method for local workers: with ``forkserver``, this process's server is started now (once per
    process; it imports ``distributed`` and ``preload`` before forking the first worker) with
    :data:`~.workers.WORKER_ENV` in its environment.  ``spawn`` when another part of the process started a
    forkserver first (its environment and imports are not ours).

    Call it from the thread that owns the process's environment (the solver's main thread): the variables are set
    in ``os.environ`` for the ~10 ms the server takes to start, then put back.
    """
    global _OURS
    method = start_method()
    if method != "forkserver":
        return method
    from multiprocessing import forkserver

    with _LOCK:
        if not _OURS and getattr(getattr(forkserver, "_forkserver", None), "_forkserver_pid", None) is not None:
            return "spawn"  # someone else's server
        forkserver.set_forkserver_preload(["distributed", *preload])
        saved = {k: os.environ.get(k) for k in WORKER_ENV}
        os.environ.update({k: str(v) for k, v in WORKER_ENV.items()})
        try:
            forkserver.ensure_running()  # started once; started again (the same way) only if it has died
            _OURS = True
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    return method
