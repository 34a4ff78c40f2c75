"""Atomic writes: write to a temporary file beside the target, then rename.

A reader never sees a half-written output, and a crash leaves either the old
file or the new one (plus, at worst, a ``.tmp-*`` file that the next run removes).
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

TMP_PREFIX = ".tmp-"


def make_readable(path: str | Path) -> None:
    """Give a file or folder the mode a plain ``open``/``mkdir`` would (``mkstemp``/``mkdtemp`` leave 0600/0700)."""
    mask = os.umask(0o022)
    os.umask(mask)
    path = Path(path)
    path.chmod((0o777 if path.is_dir() else 0o666) & ~mask)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=TMP_PREFIX, suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        make_readable(tmp_path)
        os.replace(tmp_path, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise naming_file(exc, path)


def naming_file(exc: BaseException, path: str | Path) -> BaseException:
    """``exc`` as an ``OSError`` naming ``path`` when it names no file, else ``exc`` itself.

    Python's (and NumPy's) error for a failed write or close, such as a full disk, names no file:
    a writer re-raises it through this so that the user is told which file could not be written.
    """
    if isinstance(exc, OSError) and exc.filename is None:
        named = OSError(exc.errno, exc.strerror or str(exc), str(path))
        named.__cause__ = exc
        return named
    return exc


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def remove_stale_temporaries(folder: str | Path) -> int:
    """Delete leftover ``.tmp-*`` files and folders below ``folder`` (from a killed run); return how many."""
    n = 0
    for p in sorted(Path(folder).rglob(TMP_PREFIX + "*")):
        with contextlib.suppress(OSError):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
            n += 1
    return n


def move_aside(path: str | Path, folder: str | Path | None = None) -> Path:
    """Rename ``path`` to a new ``.tmp-*`` name in ``folder`` (default: beside it) and return that name;
    ``path`` itself when it cannot be renamed.  A rename is instant: ``path`` is gone at once, and
    whoever still addresses it (a task of a failed run, a reader) finds nothing there."""
    path = Path(path)
    moved = Path(folder if folder is not None else path.parent) / f"{TMP_PREFIX}{path.name}-{os.urandom(4).hex()}"
    try:
        os.rename(path, moved)
    except OSError:
        return path
    return moved


def remove_tree(path: str | Path) -> None:
    """Delete the folder ``path`` of a failed run while tasks of it may still be running (on other Dask workers).

    The folder is first moved aside (:func:`move_aside`), so ``path`` is gone at once: a task
    that writes afterwards addresses the old path and finds nothing there (the cache creates
    only the last level of a path, never its parents).  Deleting in place could race such a task
    (a folder it creates during the walk keeps its parents alive): measured, 3 of 12 failed runs
    on 2 workers left an empty ``checkpoint/cache`` behind.  Where the rename fails, the folder
    is deleted in place.
    """
    shutil.rmtree(move_aside(path), ignore_errors=True)
