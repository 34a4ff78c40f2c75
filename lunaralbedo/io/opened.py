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

Neighbouring tiles read the same DEM blocks too (their shadow margins, and the blocks that
straddle a tile edge).  Inside :func:`lasting`, the files it names (a run's DEMs) stay open
over all the tiles a thread prepares, so each of their blocks is decoded once while GDAL's
cache holds it: the strip of ``make bench`` item 6, whose DEM blocks of 256 x 256 px straddle
its tiles' edges, read its tiles' terrain in 14.0-14.3 instead of 16.4-17.2 ns per
observation (docs/performance-history.md, section 0m).  Its memory is GDAL's cache, which is
bounded (64 MiB: ``io/rasters.GDAL_CACHE_BYTES``).
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
def lasting(paths):
    """Files of ``paths`` opened by :func:`open_raster` in this thread stay open until the end of the block,
    across :func:`kept_open` blocks too (nested: the outer one); other files are opened as before."""
    if getattr(_LOCAL, "lasting", None) is not None:
        yield
        return
    _LOCAL.lasting = dict.fromkeys(map(str, paths))
    try:
        yield
    finally:
        files, _LOCAL.lasting = _LOCAL.lasting, None
        for ds in files.values():
            if ds is not None:
                ds.close()


@contextmanager
def open_raster(path):
    """The raster ``path`` opened for reading, for the ``with`` block (kept open inside :func:`kept_open`,
    and inside :func:`lasting` when it names the file)."""
    key = str(path)
    long_lived = getattr(_LOCAL, "lasting", None)
    if long_lived is not None and key in long_lived:
        if long_lived[key] is None:
            long_lived[key] = rasterio.open(path)
        yield long_lived[key]
        return
    files = getattr(_LOCAL, "files", None)
    if files is None:
        with rasterio.open(path) as ds:
            yield ds
        return
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
