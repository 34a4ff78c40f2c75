"""On-disk cache of prepared tile stacks (inside OUTDIR, never in input folders).

A tile's stack is a folder of ``.npy`` arrays written to a temporary folder and
renamed into place, so a cache entry is either complete or absent.  Arrays are
loaded memory-mapped, and a resumed run skips tiles already prepared.  The solver's tiles are
written behind its computation (:mod:`.cachewriter`), in the same way.
:class:`MemoryCache` keeps arrays derived from entries in memory within a byte budget
(the solver's iterations), so that they are not re-read every pass.
"""
from __future__ import annotations

import json
import mmap
import os
import shutil
import tempfile
import threading
from collections import OrderedDict
from contextlib import suppress
from pathlib import Path
from typing import Callable

import numpy as np

from .atomic import move_aside, naming_file


def _ensure_parent(folder: Path) -> None:
    """Create ``folder``'s parent, but not the folders above it: a task still running after its run
    failed and cleaned up (another Dask worker) must not bring the removed output folder back."""
    folder.parent.mkdir(exist_ok=True)


def temporary_beside(folder: Path) -> Path:
    """A new temporary folder next to ``folder``, to fill and then :func:`move_into_place`."""
    _ensure_parent(folder)
    return Path(tempfile.mkdtemp(prefix=".tmp-", dir=folder.parent))


def move_into_place(tmp: Path, folder: Path) -> None:
    """Rename the filled temporary folder ``tmp`` to ``folder``, replacing an older entry there."""
    if folder.exists():
        shutil.rmtree(folder)
    os.replace(tmp, folder)


def save_stack(folder: str | Path, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Write ``arrays`` and ``meta`` (JSON) as a cache entry at ``folder`` (atomic rename)."""
    folder = Path(folder)
    tmp = temporary_beside(folder)
    try:
        for name, arr in arrays.items():
            np.save(tmp / f"{name}.npy", np.ascontiguousarray(arr), allow_pickle=False)
        (tmp / "meta.json").write_text(json.dumps(meta))
        move_into_place(tmp, folder)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise naming_file(exc, folder)  # np.save's write errors name no file


def load_stack(folder: str | Path, mmap: bool = True) -> tuple[dict[str, np.ndarray], dict] | None:
    """Load a cache entry, or None when it does not exist."""
    folder = Path(folder)
    meta_path = folder / "meta.json"
    if not meta_path.is_file():
        return None
    meta = json.loads(meta_path.read_text())
    arrays = {p.stem: _map_npy(p) if mmap else _load_npy(p) for p in sorted(folder.glob("*.npy"))}
    return arrays, meta


#: How many entries' metas :func:`load_meta` keeps parsed (the least recently asked for go first).
META_ENTRIES = 4096
_METAS: OrderedDict[str, tuple] = OrderedDict()
_METAS_LOCK = threading.Lock()


def load_meta(folder: str | Path) -> dict | None:
    """The meta of the cache entry at ``folder`` (None when there is none), parsed once per process while it is
    the same ``meta.json`` (:func:`_stamp`: a re-saved entry is read again).

    The iterations ask for every tile's meta in every pass; parsing it and listing the tile's
    folder each time cost ~0.25 ms per tile and pass.  The dict is shared: callers must not modify it.
    """
    folder = Path(folder)
    key = str(folder)
    stamp = _stamp(folder)
    if stamp is None:
        return None
    with _METAS_LOCK:
        hit = _METAS.get(key)
        if hit is not None and hit[0] == stamp:
            _METAS.move_to_end(key)
            return hit[1]
    try:
        meta = json.loads((folder / "meta.json").read_text())
    except FileNotFoundError:  # replaced or removed since its stamp was taken
        return None
    with _METAS_LOCK:
        _METAS[key] = (stamp, meta)
        _METAS.move_to_end(key)
        while len(_METAS) > META_ENTRIES:
            _METAS.popitem(last=False)
    return meta


#: One ``.npy`` header parsed at a time in a process.  NumPy reads the header with ``ast.literal_eval``, and
#: CPython 3.11's AST constructor is not thread-safe before 3.11.8 (gh-106905: "AST constructor recursion depth
#: mismatch" when threads parse at once): a one-process solve reads its tiles' blocks on several threads.
HEADER_LOCK = threading.Lock()


def _load_npy(path: Path) -> np.ndarray:
    with HEADER_LOCK:
        return np.load(path, allow_pickle=False)


def map_npy(path: Path) -> np.ndarray:
    """Public name of :func:`_map_npy` (read-only memory map of a ``.npy`` file, thread-safe)."""
    return _map_npy(path)


def _map_npy(path: Path) -> np.ndarray:
    """The array of a ``.npy`` file, memory-mapped read-only: a view of an :class:`mmap.mmap` (see :func:`mapped`).

    What ``np.load(path, mmap_mode="r")`` gives, without its path resolution and
    ``np.memmap`` set-up: 0.15 instead of 0.28 ms per file, which the iterations pay for
    every array of every block over the memory budget in every pass (~1.5 ns less per
    observation and iteration on the 50-image benchmark scene; docs/performance-history.md, 0c).
    """
    with open(path, "rb") as f:
        version = np.lib.format.read_magic(f)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        with HEADER_LOCK:  # NumPy parses the header with ast.literal_eval (see HEADER_LOCK)
            shape, fortran, dtype = read_header(f)
        offset = f.tell()
        count = int(np.prod(shape, dtype=np.int64))
        if dtype.hasobject:
            raise ValueError(f"{path}: object arrays are not cached")
        if count == 0 or os.fstat(f.fileno()).st_size < offset + count * dtype.itemsize:
            with HEADER_LOCK:
                a = np.load(path, allow_pickle=False)  # empty (nothing to map), or short: NumPy's own error
            a.flags.writeable = False
            return a
        buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    return np.frombuffer(buf, dtype, count, offset).reshape(shape, order="F" if fortran else "C")


def mapped(a: np.ndarray) -> bool:
    """Whether ``a`` is a view of a memory-mapped file (:func:`_map_npy` or ``np.memmap``), not memory of its own."""
    while isinstance(a, np.ndarray):
        if isinstance(a, np.memmap) and a._mmap is not None:
            return True
        a = a.base
    return isinstance(a.obj if isinstance(a, memoryview) else a, mmap.mmap)


def save_meta(folder: str | Path, meta: dict) -> None:
    """Write ``meta.json`` into an existing cache folder atomically (it marks the entry complete)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".json", dir=folder)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(meta))
        os.replace(tmp, folder / "meta.json")
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        raise naming_file(exc, folder / "meta.json")


_DELETER = None
_DELETER_LOCK = threading.Lock()


def _deleter():
    """This process's one background thread that deletes discarded entries (created on first use)."""
    global _DELETER
    with _DELETER_LOCK:
        if _DELETER is None:
            from concurrent.futures import ThreadPoolExecutor

            _DELETER = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lunaralbedo-delete")
        return _DELETER


def discard(folders, trash: str | Path) -> None:
    """Remove cache entries without waiting for it: each folder is renamed into ``trash`` (created
    if its parent exists; a rename is instant) and deleted by a background thread of this process.

    Deleting a file whose pages the kernel is still writing to disk waits for that write: on
    the 50-image benchmark scene the workers' finalise tasks spent 5.7 s each blocked so
    (docs/performance-history.md, section 0b).  In the background the wait overlaps the next task.
    An entry that cannot be renamed (no parent for ``trash``, another file system) is deleted
    here and now.  Whatever is left goes with the run's checkpoint folder.
    """
    trash = Path(trash)
    for folder in map(Path, folders):
        if not folder.exists():
            continue
        with suppress(OSError):
            trash.mkdir(exist_ok=True)
        gone = move_aside(folder, trash) if trash.is_dir() else folder
        if gone == folder:
            shutil.rmtree(folder, ignore_errors=True)
        else:
            _deleter().submit(shutil.rmtree, gone, ignore_errors=True)


def _stamp(folder: str | Path):
    """Identity of a cache entry on disk (a re-saved entry is a new folder and ``meta.json``), or None."""
    try:
        st, sf = os.stat(os.path.join(folder, "meta.json")), os.stat(folder)
    except FileNotFoundError:
        return None
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, sf.st_ino, sf.st_ctime_ns


#: File systems whose pages :class:`MemoryCache` keeps as they are mapped (local disks and memory):
#: a kept entry's pages stay in the page cache, where the prepare step has just written them.
#: On any other (NFS, Lustre, GPFS, ...) a kept entry is copied into the process's memory, so that
#: the iterations never wait for the network.
LOCAL_FILESYSTEMS = frozenset({"ext2", "ext3", "ext4", "xfs", "btrfs", "zfs", "f2fs", "bcachefs", "tmpfs", "ramfs",
                               "overlay", "apfs", "hfs"})


def filesystem_type(path: str | Path) -> str | None:
    """The type of the file system that holds ``path`` (``/proc/self/mountinfo``: the mount with the
    longest matching mount point), or None where that is not known (no such file: not Linux)."""
    target = os.path.realpath(path)
    best, kind = -1, None
    try:
        with open("/proc/self/mountinfo") as f:
            for line in f:
                fields = line.split()
                if " - " not in line or len(fields) < 5:
                    continue
                point = fields[4].replace("\\040", " ").replace("\\011", "\t").replace("\\134", "\\")
                inside = target == point or target.startswith(point.rstrip("/") + "/")
                if inside and len(point) > best:
                    best, kind = len(point), line.split(" - ", 1)[1].split()[0]
    except OSError:
        return None
    return kind


class MemoryCache:
    """Arrays derived from cache entries (``build(arrays, meta) -> dict of arrays``), kept in memory
    within ``budget`` bytes, per process.

    An entry is served only while the folder's ``meta.json`` is the same file (a re-prepared
    or resumed run's entry is rebuilt, never served stale).  A new entry that does not fit
    first drops entries of other cache roots and entries no longer on disk, least recently
    used first; if it still does not fit it is not kept: the tiles of one solve come back in
    a cycle, where evicting the oldest would drop every entry just before its reuse.  An entry
    that is not kept is returned as built.  A kept entry's memory-mapped arrays stay mapped on a
    local file system (:data:`LOCAL_FILESYSTEMS`): their pages are in the page cache (the
    prepare step has just written them, or the first pass reads them), counted in the process's
    resident memory like copies, and serving them needs no copy (the strip of ``make bench``
    item 6: the first pass of the iterations 14-35 -> 6.4 ns per observation, the steady passes
    unchanged; docs/performance.md); elsewhere, or with ``copy=True``, they are copied into
    memory.  The returned arrays are shared: callers must not modify them.
    """

    def __init__(self, budget: int, copy: bool | None = None):
        self.budget = int(budget)
        self.copy = copy  # None: copy unless the entry is on a local file system
        self._entries: OrderedDict[str, tuple] = OrderedDict()  # folder -> (stamp, arrays, nbytes)
        self._bytes = 0  # the entries' nbytes, kept as they come and go
        self._changes = 0  # how many times an entry came or went
        self._no_room = None  # (root, _changes) of the last search for room that ended without enough
        self._lock = threading.Lock()
        self._local: dict[Path, bool] = {}  # cache root -> on a local file system

    def _copies(self, root: Path) -> bool:
        if self.copy is not None:
            return self.copy
        if root not in self._local:
            self._local[root] = filesystem_type(root) in LOCAL_FILESYSTEMS
        return not self._local[root]

    @property
    def nbytes(self) -> int:
        return self._bytes

    def _drop(self, key: str) -> None:
        old = self._entries.pop(key, None)
        if old is not None:
            self._bytes -= old[2]
            self._changes += 1

    def get(self, folder: str | Path, build: Callable[[dict, dict], dict], group: str | Path | None = None) -> dict | None:
        """The arrays built from the entry at ``folder`` (None when it does not exist).

        ``group``: the cache root the entry belongs to (default: ``folder``'s parent); entries of
        other groups are the first to go when room is needed.
        """
        folder = Path(os.path.abspath(folder))
        key = str(folder)
        stamp = _stamp(folder)
        with self._lock:
            hit = self._entries.get(key)
            if hit is not None and hit[0] == stamp:
                self._entries.move_to_end(key)
                return hit[1]
            self._drop(key)
        loaded = load_stack(folder)
        if loaded is None or stamp is None:
            return None
        arrays = build(*loaded)
        size = sum(a.nbytes for a in arrays.values() if isinstance(a, np.ndarray))
        root = Path(os.path.abspath(group)) if group is not None else folder.parent
        with self._lock:
            self._make_room(size, root)
            keep = self.nbytes + size <= self.budget and _stamp(folder) == stamp
        if not keep:
            return arrays
        if self._copies(root):
            arrays = {k: np.array(v) if mapped(v) else v for k, v in arrays.items()}  # read into memory
        with self._lock:
            self._make_room(size, root)
            if self.nbytes + size <= self.budget:
                self._drop(key)
                self._entries[key] = (stamp, arrays, size)
                self._bytes += size
                self._changes += 1
        return arrays

    def _make_room(self, size: int, root: Path) -> None:
        """Drop entries of other roots and entries no longer on disk, least recently used first, until ``size`` more
        bytes fit (or none is left to drop).

        Every block over the budget asks, in every pass, so each entry is tested by a string prefix and, for the
        entries of ``root``, its stamp; and a search that ended without enough room is not run again for the same
        root until an entry comes or goes (an entry whose files went away meanwhile goes when it is asked for,
        which each pass over the tiles does).  A path's parents, a sum over the entries and two ``stat`` calls for
        every entry had cost the 50-image scene's iterations ~0.6 ms per block (docs/performance-history.md, 0l)."""
        if self._bytes + size <= self.budget or self._no_room == (root, self._changes):
            return
        prefix = os.path.join(str(root), "")  # keys are absolute, normalised paths
        for key in list(self._entries):
            if self._bytes + size <= self.budget:
                return
            if not key.startswith(prefix) or _stamp(key) != self._entries[key][0]:
                self._drop(key)
        if self._bytes + size > self.budget:
            self._no_room = (root, self._changes)

    def discard(self, folder: str | Path) -> None:
        """Forget the entry of ``folder`` (its last use in a run)."""
        with self._lock:
            self._drop(os.path.abspath(folder))

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()
            self._bytes = 0
            self._changes += 1
