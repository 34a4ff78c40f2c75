"""On-disk cache of prepared tile stacks (inside OUTDIR, never in input folders).

A tile's stack is a folder of ``.npy`` arrays written to a temporary folder and
renamed into place, so a cache entry is either complete or absent.  Arrays are
loaded memory-mapped: iterations read them from the page cache without holding
every tile in memory, and a resumed run skips tiles already prepared.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np


def save_stack(folder: str | Path, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Write ``arrays`` and ``meta`` (JSON) as a cache entry at ``folder`` (atomic rename)."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-", dir=folder.parent))
    try:
        for name, arr in arrays.items():
            np.save(tmp / f"{name}.npy", np.ascontiguousarray(arr), allow_pickle=False)
        (tmp / "meta.json").write_text(json.dumps(meta))
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(tmp, folder)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError) and exc.filename is None:  # np.save's write errors name no file
            raise OSError(exc.errno, exc.strerror or str(exc), str(folder)) from exc
        raise


def load_stack(folder: str | Path, mmap: bool = True) -> tuple[dict[str, np.ndarray], dict] | None:
    """Load a cache entry, or None when it does not exist."""
    folder = Path(folder)
    meta_path = folder / "meta.json"
    if not meta_path.is_file():
        return None
    meta = json.loads(meta_path.read_text())
    arrays = {p.stem: np.load(p, mmap_mode="r" if mmap else None, allow_pickle=False) for p in sorted(folder.glob("*.npy"))}
    return arrays, meta


def save_meta(folder: str | Path, meta: dict) -> None:
    """Write ``meta.json`` into an existing cache folder atomically (it marks the entry complete)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".json", dir=folder)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(meta))
        os.replace(tmp, folder / "meta.json")
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def building(folder: str | Path):
    """A temporary folder next to ``folder`` to fill (blocks, ``meta.json``), renamed to ``folder`` on success.

    The entry appears complete or not at all, as with :func:`save_stack`; on error the
    temporary folder is removed.
    """
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-", dir=folder.parent))
    try:
        yield tmp
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(tmp, folder)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError) and str(tmp) in str(exc.filename or ""):  # name the entry, not the temporary
            raise OSError(exc.errno, exc.strerror or str(exc), str(folder)) from exc
        raise
