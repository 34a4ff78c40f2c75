"""Raster files kept open across many window reads (one thread's block of work).

The prepare step reads the DEM of a tile (with the cast-shadow margin) in chunks of rows, to
bound its temporaries.  Opening the file for each chunk threw away GDAL's cache of the blocks
it had decoded, so a compressed block under two chunks was decoded twice (the strip scene of
docs/performance-history.md: its DEM reads took 0.41 s, one decode of the whole DEM 0.16 s).  Inside
:func:`kept_open`, :func:`open_raster` gives the file opened before in this thread's block, up
to :data:`MAX_KEPT` files (the least recently used one not in use is closed beyond), and closes
them all at its end; outside, it opens and closes as ``rasterio.open`` does.

Keep such blocks short: an open file's decoded blocks stay in GDAL's cache (up to
GDAL_CACHEMAX, 5 % of the RAM by default) until it is closed.  Keeping the DRGs open over a
whole tile as well raised the peak memory of a 4000 x 4000 px tile under 16 images from 832 to
931 MB (docs/performance-history.md, section 0f), so only the DEM reads use it.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from contextlib import contextmanager

import rasterio

#: Most files :func:`kept_open` keeps open at once (file handles are a bounded resource).
MAX_KEPT = 64

_LOCAL = threading.local()


@contextmanager
def kept_open():
    """Files opened by :func:`open_raster` in this thread stay open until the end of the block (nested: the outer one)."""
    if getattr(_LOCAL, "files", None) is not None:
        yield
        return
    _LOCAL.files, _LOCAL.busy = OrderedDict(), {}
    try:
        yield
    finally:
        files, _LOCAL.files = _LOCAL.files, None
        for ds in files.values():
            ds.close()


@contextmanager
def open_raster(path):
    """The raster ``path`` opened for reading, for the ``with`` block (kept open inside :func:`kept_open`)."""
    files = getattr(_LOCAL, "files", None)
    if files is None:
        with rasterio.open(path) as ds:
            yield ds
        return
    key = str(path)
    if key in files:
        files.move_to_end(key)
    else:
        for old in [k for k in files if not _LOCAL.busy.get(k)][:max(0, len(files) + 1 - MAX_KEPT)]:
            files.pop(old).close()
        files[key] = rasterio.open(path)
    _LOCAL.busy[key] = _LOCAL.busy.get(key, 0) + 1
    try:
        yield files[key]
    finally:
        _LOCAL.busy[key] -= 1
