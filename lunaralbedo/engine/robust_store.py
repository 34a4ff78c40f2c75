"""Where a reweight pass keeps a block's effective weights, and how the passes read them back.

Generation ``g`` of a block ``block_<i>`` lives in its tile's cache entry, ``robust_<g>/``:

* ``block_<i>.npy``, the effective weight of every observation (float32), when many differ from the cached
  weights (the robust loss where three or more images overlap);
* else ``block_<i>.changed.npy``: the block's observation count, then the observations whose weight differs
  (int64), and ``block_<i>.value.npy`` their weights (float32).  The spatial test alone changes a few per cent
  (the rejected outliers; none on clean images): a few bytes instead of 4 per observation, which a reweight pass
  otherwise wrote for every observation (1.6-11 ns per observation on this machine's disk, by how many dirty
  pages the solve's cache already has).

Generation 1 of a block the prepare step ran the spatial test on (:func:`.robust.in_prepare`) is not a file: the
block holds the observations it rejected (``rejected``), :func:`rejected`.

Both are written atomically; the checkpoint names the generation only after the pass wrote every block.  No
numerical difference: the weights read back are the same float32 values.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.atomic import atomic_path
from ..io.cache import map_npy

#: Above this fraction of changed observations a block's weights are stored whole (8 bytes a changed one
#: against 4 an observation).
SPARSE_MAX_FRACTION = 0.25


def folder(block: Path, gen: int) -> Path:
    """The folder of generation ``gen`` of the weights of a block's tile."""
    return block.parent / f"robust_{gen}"


def save(block: Path, gen: int, cached: np.ndarray, weights: np.ndarray) -> None:
    """Store generation ``gen`` of a block's effective ``weights`` (float32; ``cached``: the weights prepared)."""
    where = folder(block, gen)
    changed = np.flatnonzero(weights != cached)
    parts = {".npy": weights} if len(changed) > SPARSE_MAX_FRACTION * len(weights) else \
        {".changed.npy": np.concatenate([[len(weights)], changed]).astype(np.int64), ".value.npy": weights[changed]}
    for suffix, array in parts.items():
        with atomic_path(where / f"{block.name}{suffix}") as tmp:
            with open(tmp, "wb") as f:
                np.save(f, np.ascontiguousarray(array), allow_pickle=False)


def rejected(cached: np.ndarray, index: np.ndarray) -> np.ndarray:
    """The weights ``cached`` (the weights prepared) with the observations ``index`` rejected (0): as they are when
    none is, else a float32 copy."""
    if not len(index):
        return cached
    w = np.array(cached, np.float32)
    w[np.asarray(index)] = 0.0
    return w


def load(block: Path, cached: np.ndarray, gen: int) -> np.ndarray:
    """Generation ``gen`` of a block's effective weights (``cached``: the weights prepared; returned as they are when
    the generation changed none, else a patched copy, or the whole stored array memory-mapped)."""
    where = folder(block, gen)
    whole = where / f"{block.name}.npy"
    if whole.exists():
        w = map_npy(whole)
    else:
        changed = np.load(where / f"{block.name}.changed.npy")
        if int(changed[0]) != len(cached):
            raise FileNotFoundError(f"{block}: robust weights of another preparation; run without --resume")
        if len(changed) == 1:
            return cached
        w = np.array(cached, np.float32)
        w[changed[1:]] = np.load(where / f"{block.name}.value.npy")
        return w
    if len(w) != len(cached):
        raise FileNotFoundError(f"{block}: robust weights of another preparation; run without --resume")
    return w
