"""Work done a few items ahead on helper threads of this process, for a task that has CPUs to spare.

A one-worker solve runs its tasks in this process and would leave the other CPUs of the
machine idle but for its cache writer (:mod:`lunaralbedo.io.cachewriter`) and GDAL's
compression.  :func:`ahead` lets such a task have its next items made on a pool of helper
threads (GDAL decodes and numba kernels declared ``nogil`` release the GIL) while it uses the
current one, in the order of the items: results are the same as a plain loop's.  Workers of a
cluster have one CPU per task and do not use it (``pool=None``: the plain loop).
"""
from __future__ import annotations

import threading
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, Iterator

_POOLS: dict = {}
_LOCK = threading.Lock()


def helper(name: str, threads: int = 1) -> ThreadPoolExecutor:
    """This process's pool of helper threads ``name`` with ``threads`` threads (started on first use)."""
    with _LOCK:
        if (name, threads) not in _POOLS:
            _POOLS[(name, threads)] = ThreadPoolExecutor(threads, thread_name_prefix=f"lunaralbedo-{name}-ahead")
        return _POOLS[(name, threads)]


def ahead(fn: Callable, items: Iterable, pool: ThreadPoolExecutor | None, depth: int = 1,
          here: Callable | None = None) -> Iterator:
    """``fn(item)`` for each item, in order, ``depth`` items computed ahead on ``pool`` (None: one after another).

    ``here(item)`` true: that item is computed in the caller's thread once the items before it
    are yielded (a big item, whose result should not be held beside another's).  The caller
    holds at most ``depth + 1`` results at once.  A failure is raised when its item's turn
    comes; if the caller stops early (an error of its own), the items not yet started are
    dropped and the one running is waited for, so nothing of the task runs on.
    """
    if pool is None:
        for item in items:
            result, item = fn(item), None
            yield result
            del result
        return
    queued: deque = deque()
    try:
        for item in items:
            if here is not None and here(item):
                while queued:
                    yield queued.popleft().result()
                result, item = fn(item), None  # the item is not held while the caller uses its result
                yield result
                del result
                continue
            queued.append(pool.submit(fn, item))
            item = None  # ... nor while the next one is made
            if len(queued) > depth:
                yield queued.popleft().result()
        while queued:
            yield queued.popleft().result()
    finally:
        for f in queued:
            f.cancel()
        for f in queued:
            if not f.cancelled():
                f.exception()  # wait; its failure is not news once the caller failed
