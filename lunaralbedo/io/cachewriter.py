"""Cache entries written behind the computation, on one background thread of this process.

The prepare step makes a tile's blocks one after the other and hands each to the writer
(:class:`Entry`), which writes it while the next block (or tile) is computed.  Writing the
cache costs CPU (~0.7 ns per byte into the page cache on this project's machine) and can wait
long: once the page cache holds ~10 % of the RAM in dirty pages, Linux holds a writer back to
the pace of the disk (0.2 s for the strip's 530 MB of cache with few dirty pages, 1.2 s with
1-2 GB of them; docs/performance-history.md, section 0g).  An entry is written into a temporary folder
beside its place, ``meta.json`` last, then renamed, so it is complete or absent, as
:func:`.cache.save_stack` writes one.

Bounded: at most :data:`PENDING` jobs, and at most :data:`PENDING_BYTES` of their arrays (one
job is always let in), wait; the caller blocks beyond that, so the blocks held in memory are
that many bytes plus the one being written.  Small blocks (the narrow strips' ~30-65 MB) then
queue several deep and the computation seldom waits for a slower write; big ones (4000 px
tiles) one at a time.  A failed write is raised, naming the
entry, by the next :meth:`Entry.save`, :meth:`Entry.complete` or :meth:`CacheWriter.flush`;
from then on queued jobs are skipped and every entry not yet complete is removed.
"""
from __future__ import annotations

import queue
import shutil
import threading
from pathlib import Path

import numpy as np

from .cache import move_into_place, save_meta, save_stack, temporary_beside
from .geotiff import GeoTiffRows

#: Jobs that may wait for the writer before :meth:`Entry.save` blocks ...
PENDING = 8
#: ... and the bytes of their arrays (memory bound: the blocks held).  The strip of make bench item 6:
#: the prepare step's waits 0.02-0.09 s with two jobs, 0.001 s with this bound (docs/performance-history.md 0h).
PENDING_BYTES = 256 * 2**20


class CacheWriter:
    """One background writing thread of this process (started on first use)."""

    def __init__(self, pending: int = PENDING, pending_bytes: int = PENDING_BYTES):
        self.pending, self.pending_bytes = int(pending), int(pending_bytes)
        self._jobs: queue.Queue = queue.Queue()  # admission below: _queued jobs of _queued_bytes wait
        self._room = threading.Condition()
        self._queued = self._queued_bytes = 0
        self._thread: threading.Thread | None = None
        self._start_lock = threading.Lock()
        self._error: BaseException | None = None

    def entry(self, folder: str | Path) -> "Entry":
        """Start writing the cache entry ``folder``: its parts go to a temporary folder beside it."""
        self._raise()
        return Entry(self, Path(folder))

    def flush(self) -> None:
        """Wait until every job handed over is done; raise the first failure (then it is forgotten)."""
        self._jobs.join()
        self._raise()

    def drain(self) -> None:
        """Wait until every job handed over is done or skipped, and forget any failure (a run that failed anyway)."""
        self._jobs.join()
        self._error = None

    def _put(self, entry: "Entry", job, nbytes: int = 0) -> None:
        self._raise()
        with self._start_lock:
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._run, name="lunaralbedo-cache-writer", daemon=True)
                self._thread.start()
        with self._room:
            while self._queued and (self._queued >= self.pending or self._queued_bytes + nbytes > self.pending_bytes):
                self._room.wait()
            self._queued += 1
            self._queued_bytes += nbytes
        self._jobs.put((entry, job, nbytes))

    def _run(self) -> None:
        while True:
            entry, job, nbytes = self._jobs.get()
            with self._room:  # taken: the next one may queue
                self._queued -= 1
                self._queued_bytes -= nbytes
                self._room.notify_all()
            try:
                if self._error is None and not entry.abandoned:
                    job()
                else:
                    entry.remove()
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread by _raise
                entry.remove()
                if not entry.abandoned:  # a dropped entry's failure (its folder removed under it) is no news
                    self._error = entry.named(exc)
            finally:
                self._jobs.task_done()

    def _raise(self) -> None:
        err = self._error
        if err is not None:
            self.drain()
            raise err


class Entry:
    """One cache entry being written by a :class:`CacheWriter` (see the module docstring)."""

    def __init__(self, writer: CacheWriter, folder: Path):
        self.writer, self.folder = writer, folder
        self.tmp = temporary_beside(folder)
        self.abandoned = False
        self._rows: dict[str, GeoTiffRows] = {}  # files of save_rows being written (the writer's thread only)

    def save(self, name: str, arrays: dict, meta: dict) -> None:
        """Queue one part (a :func:`.cache.save_stack` entry ``name`` inside this one); ``arrays`` must not change after."""
        self.writer._put(self, lambda: save_stack(self.tmp / name, arrays, meta),
                         sum(int(getattr(a, "nbytes", 0)) for a in arrays.values()))

    def save_rows(self, name: str, rows: np.ndarray, row0: int, shape: tuple[int, int], col0: int = 0,
                  **geotiff) -> None:
        """Queue rows ``row0:row0 + len(rows)`` (columns ``col0:``) of the one-band GeoTIFF ``name`` of ``shape``
        inside this entry (:class:`~.geotiff.GeoTiffRows`, made with ``geotiff`` at its first rows, finished by
        :meth:`complete`); ``rows`` must not change after.  The file's other rows are never held here."""
        self.writer._put(self, lambda: self._file(name, shape, geotiff).write(rows, row0, col0), int(rows.nbytes))

    def skip_rows(self, name: str, n: int, shape: tuple[int, int], **geotiff) -> None:
        """Queue ``n`` rows of :meth:`save_rows`'s file ``name`` left to its fill value (:meth:`.GeoTiffRows.skip`)."""
        self.writer._put(self, lambda: self._file(name, shape, geotiff).skip(n))

    def _file(self, name: str, shape, geotiff: dict) -> GeoTiffRows:
        if name not in self._rows:
            self._rows[name] = GeoTiffRows(self.tmp / name, shape, **geotiff)
        return self._rows[name]

    def complete(self, meta: dict) -> None:
        """Queue ``meta.json`` and the rename that makes the entry appear, complete, at its place."""
        def finish():
            for rows_file in self._take_rows():  # the GeoTIFFs written a block of rows at a time, finished
                rows_file.close()
            save_meta(self.tmp, meta)
            move_into_place(self.tmp, self.folder)
        self.writer._put(self, finish)

    def abandon(self) -> None:
        """Drop the entry (its computation failed): queued parts are skipped and the temporary folder removed."""
        self.abandoned = True
        try:
            self.writer._put(self, lambda: None)  # runs after the parts: removes the folder
        except BaseException:  # noqa: BLE001 - the writer failed already: the caller's own error comes first
            self.remove()

    def remove(self) -> None:
        for rows_file in self._take_rows():
            rows_file.abort()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def _take_rows(self):
        """The :meth:`save_rows` files, each taken once (``popitem`` is atomic: a failed writer's entry may be
        removed by the caller's thread as well)."""
        while True:
            try:
                yield self._rows.popitem()[1]
            except KeyError:
                return

    def named(self, exc: BaseException) -> BaseException:
        """``exc`` naming the entry rather than its temporary folder (as :func:`.cache.save_stack` names it)."""
        if isinstance(exc, OSError) and str(self.tmp) in str(exc.filename or ""):
            named = OSError(exc.errno, exc.strerror or str(exc), str(self.folder))
            named.__cause__ = exc
            return named
        return exc
