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

The server's first import is :mod:`.worker_server` when the run tunes its workers
(``Runtime.tune_workers``): it applies the malloc and NumPy settings of :mod:`.workers` to the
server, and every worker forked from it inherits them.  The server lives as long as this process
and serves its later local clusters too, so a worker runs the code this process first loaded:
after editing the package in a notebook, restart the kernel (or start workers with
``Runtime(worker_start="spawn")``, the default where the platform is not Linux or has no
``forkserver``).
"""
from __future__ import annotations

import multiprocessing
import sys
import threading

from ..runtime import WORKER_STARTS

SERVER_SETUP = "lunaralbedo.parallel.worker_server"
#: Preloaded first when the run wants full-width vectors in its workers (``Runtime.wide_vectors``).
VECTORS_SETUP = "lunaralbedo.parallel.worker_vectors"

_LOCK = threading.Lock()
_OURS = None  # how the running forkserver was started by this module: (tuned, wide), or None (not by us)


def start_method(wanted: str | None = None) -> str:
    """How local workers start: ``wanted`` (``Runtime.worker_start``), by default ``forkserver`` on Linux and
    ``spawn`` elsewhere (on macOS a process that forks without exec may crash in system frameworks, which is why
    Python spawns there); ``spawn`` where there is no forkserver."""
    wanted = wanted or ("forkserver" if sys.platform.startswith("linux") else "spawn")
    if wanted not in WORKER_STARTS:
        raise ValueError(f"worker start must be one of {', '.join(WORKER_STARTS)}, got {wanted!r}")
    if wanted == "forkserver" and "forkserver" not in multiprocessing.get_all_start_methods():
        return "spawn"
    return wanted


def ready(preload: tuple = (), wanted: str | None = None, tuned: bool = True) -> str:
    """The start method for local workers (``wanted``: see :func:`start_method`): with ``forkserver``, this
    process's server is started now (once per process; it imports :mod:`.worker_vectors` first when ``preload``
    names it, :mod:`.worker_server` when ``tuned``, then
    ``distributed`` and ``preload``, before forking the first worker).  ``spawn`` when another part of the
    process started a forkserver first (its imports are not ours) or ours was started with the other tuning.
    The process's own environment is not touched.
    """
    global _OURS
    method = start_method(wanted)
    if method != "forkserver":
        return method
    from multiprocessing import forkserver

    with _LOCK:
        running = getattr(getattr(forkserver, "_forkserver", None), "_forkserver_pid", None) is not None
        ours = (tuned, VECTORS_SETUP in preload)
        if running and _OURS != ours:
            return "spawn"  # someone else's server, or ours with the other tuning or vector width
        setup = [*((VECTORS_SETUP,) if ours[1] else ()), *((SERVER_SETUP,) if tuned else ())]
        forkserver.set_forkserver_preload([*setup, "distributed", *(m for m in preload if m != VECTORS_SETUP)])
        forkserver.ensure_running()  # started once; started again (the same way) only if it has died
        _OURS = ours
    return method
