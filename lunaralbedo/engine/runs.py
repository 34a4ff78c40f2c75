"""A block's compact observations in runs: chunks of pixels, each image's observations of a chunk in runs of consecutive pixels.

The prepare step gathers observations image by image (:mod:`.observations`): image ``k``
owns ``start[k]:start[k+1]``, in increasing pixel order (``pix``, the flat index in the
block).  The iterations (:func:`.kernels.iterate_runs`) and finalise
(:func:`.finalise_kernels.finalise_runs`) take them chunk by chunk: the block's pixels are cut into
chunks of ``chunk_px`` consecutive pixels, and within a chunk the observations stay image by
image in tile order, then pixel by pixel.  Each image's observations of a chunk fall into
**runs** of consecutive pixels (a row of its footprint, or several rows where it covers the
whole width), so that

* a run has one image: its exposure is one number (no gather), its exposure sums are
  contiguous sums (no scatter);
* a run's pixels are consecutive: its terms add into the chunk's per-pixel sums, and its
  pixels' albedo is read back, as contiguous slices (vectorised), in tile order of the
  images for every pixel (the order of the NumPy oracle of eq. 3, ``tests/oracles.albedo``).

:func:`chunk_runs` reorders a block once, before it is cached (each image's pieces of the
chunks, sorted by chunk, images staying in tile order), so the cache holds the iterations' order: ~16 bytes per observation (value, weight,
two layers) and 12 bytes per run.
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: Observations a chunk holds on average (:func:`chunk_pixels`): the kernels' float32 work
#: rows of a chunk (~8 of them, 4 bytes an observation) then stay in the core's L1/L2 caches.
#: Measured (iterate kernel, ns per observation): the strip of ``make bench`` item 6 (0.63
#: observations per pixel) 5.4-5.8 with chunks of 1024 px, 5.2-5.7 with 2048, 5.6-5.8 with 4096;
#: the 50-image scene of item 1 (2.0 per pixel) 6.0 with 128 px, 5.0 with 512, 5.3 with 1024.
CHUNK_OBSERVATIONS = 1024
#: Bounds of a chunk's length in pixels (its per-pixel float64 sums: 16 bytes a pixel).
MIN_CHUNK_PX, MAX_CHUNK_PX = 64, 4096


def chunk_pixels(n_obs: int, npix: int) -> int:
    """The chunk length of a block of ``npix`` pixels and ``n_obs`` observations: a power of two
    near :data:`CHUNK_OBSERVATIONS` observations a chunk at the block's mean density."""
    density = max(n_obs, 1) / max(npix, 1)
    px = 1 << max(0, int(np.round(np.log2(CHUNK_OBSERVATIONS / density))))
    return int(min(MAX_CHUNK_PX, max(MIN_CHUNK_PX, px)))


@njit(cache=True, nogil=True)
def _segments(pix, start, chunk_px):
    """Each image's observations cut at the chunks' borders: ``(chunk, image, first, end)`` of every
    piece, image by image, chunks ascending (an image's pixels ascend: binary searches, no pass over them)."""
    n = 0
    for k in range(start.shape[0] - 1):
        o, e = start[k], start[k + 1]
        while o < e:
            n += 1
            o = o + np.searchsorted(pix[o:e], (pix[o] // chunk_px + 1) * chunk_px)
    seg = np.empty((n, 4), np.int64)
    n = 0
    for k in range(start.shape[0] - 1):
        o, e = start[k], start[k + 1]
        while o < e:
            c = pix[o] // chunk_px
            end = o + np.searchsorted(pix[o:e], (c + 1) * chunk_px)
            seg[n, 0], seg[n, 1], seg[n, 2], seg[n, 3] = c, k, o, end
            n += 1
            o = end
    return seg


@njit(cache=True, nogil=True)
def _copy(src, dst):
    """``dst[:] = src`` as a plain loop (numba's slice assignment checks and broadcasts)."""
    for i in range(src.shape[0]):
        dst[i] = src[i]


@njit(cache=True, nogil=True)
def _breaks(pix, o, e):
    """Runs in ``pix[o:e]``: 1 + the places where the pixels stop being consecutive (vectorised count)."""
    n = 1
    for i in range(o + 1, e):
        n += pix[i] != pix[i - 1] + 1
    return n


@njit(cache=True, nogil=True)
def _order(pix, start, npix, chunk_px, src, dst):
    """Chunk-major order of image-major observations, and the runs of the result; ``src`` ``(n_arrays, m)``
    rows moved into ``dst``.  An image's observations of a chunk are consecutive already (its pixels
    ascend): the pieces (:func:`_segments`) are put in chunk order, images staying in tile order
    within a chunk (a stable counting sort of the pieces), and copied whole.

    Returns ``(chunks, run_start, run_pixel, run_image)``: chunk ``c`` (non-empty ones only)
    owns runs ``chunks[c]:chunks[c+1]``; run ``r`` owns observations
    ``run_start[r]:run_start[r+1]``, of local image ``run_image[r]`` at consecutive pixels from
    ``run_pixel[r]``.
    """
    seg = _segments(pix, start, chunk_px)
    ns = seg.shape[0]
    nch = (npix + chunk_px - 1) // chunk_px
    first = np.zeros(nch + 1, np.int64)  # pieces per chunk, then each chunk's first place in the sorted pieces
    for i in range(ns):
        first[seg[i, 0] + 1] += 1
    for c in range(nch):
        first[c + 1] += first[c]
    order = np.empty(ns, np.int64)
    for i in range(ns):
        c = seg[i, 0]
        order[first[c]] = i
        first[c] += 1
    n_runs, n_chunks = 0, 0
    for j in range(ns):
        i = order[j]
        n_runs += _breaks(pix, seg[i, 2], seg[i, 3])
        n_chunks += j == 0 or seg[i, 0] != seg[order[j - 1], 0]
    chunks = np.empty(n_chunks + 1, np.int32)
    run_start = np.empty(n_runs + 1, np.int32)
    run_pixel = np.empty(n_runs, np.int32)
    run_image = np.empty(n_runs, np.int32)
    q, r, c = 0, 0, 0
    for j in range(ns):
        i = order[j]
        o, e, k = seg[i, 2], seg[i, 3], seg[i, 1]
        if j == 0 or seg[i, 0] != seg[order[j - 1], 0]:
            chunks[c] = r
            c += 1
        for a in range(src.shape[0]):
            _copy(src[a, o:e], dst[a, q:q + e - o])
        run_start[r], run_pixel[r], run_image[r] = q, pix[o], k
        r += 1
        for x in range(o + 1, e):
            if pix[x] != pix[x - 1] + 1:
                run_start[r], run_pixel[r], run_image[r] = q + x - o, pix[x], k
                r += 1
        q += e - o
    run_start[n_runs] = q
    chunks[n_chunks] = n_runs
    return chunks, run_start, run_pixel, run_image


def _rows_of(obs, names):
    """The arrays ``names`` as the rows of one array: the array they are consecutive rows of (no copy), else stacked."""
    base = getattr(obs[names[0]], "base", None) if names else None
    if (isinstance(base, np.ndarray) and base.ndim == 2 and base.shape[0] == len(names) and base.flags.c_contiguous
            and all(obs[n].base is base and obs[n].shape == base[i].shape and obs[n].ctypes.data == base[i].ctypes.data
                    for i, n in enumerate(names))):
        return base
    return np.stack([np.asarray(obs[n]) for n in names]) if names else np.zeros((0, len(obs["pix"])), np.float32)


def chunk_runs(obs, npix: int, names, chunk_px: int | None = None) -> dict:
    """A block's compact observations (image-major, :mod:`.observations`) in chunk-major runs.

    Returns ``chunks``, ``run_start``, ``run_pixel`` (int32, pixels of the block) and
    ``run_image`` (uint16, or int32 beyond 65535 images: the local image of each run), the
    arrays ``names`` reordered (rows of one array of their common type are moved in one
    pass), and ``index``.  ``chunk_px`` defaults to :func:`chunk_pixels`.
    """
    index = np.asarray(obs["index"])
    pix = np.asarray(obs["pix"])
    m = len(pix)
    if m >= 2**31:
        raise ValueError(f"{m} observations in one block: more than int32 offsets hold")
    src = _rows_of(obs, list(names))
    dst = np.empty_like(src)
    chunk_px = chunk_pixels(m, npix) if chunk_px is None else int(chunk_px)
    chunks, run_start, run_pixel, run_image = _order(pix, np.asarray(obs["start"]), npix, chunk_px, src, dst)
    run_image = run_image.astype(np.uint16) if len(index) < 2**16 else run_image
    return {"chunks": chunks, "run_start": run_start, "run_pixel": run_pixel, "run_image": run_image, "index": index,
            **dict(zip(names, dst))}


def observation_pixels(runs) -> np.ndarray:
    """The block pixel of each observation of ``runs`` (int64)."""
    start = np.asarray(runs["run_start"], np.int64)
    lengths = np.diff(start)
    return np.repeat(np.asarray(runs["run_pixel"], np.int64) - start[:-1], lengths) + np.arange(start[-1])


def pixel_extent(runs) -> int:
    """One past the last pixel of the block that has an observation (0: none)."""
    start, pixel = np.asarray(runs["run_start"], np.int64), np.asarray(runs["run_pixel"], np.int64)
    return int((pixel + np.diff(start)).max()) if len(pixel) else 0


def observation_images(runs) -> np.ndarray:
    """The local image of each observation of ``runs``."""
    return np.repeat(np.asarray(runs["run_image"]), np.diff(np.asarray(runs["run_start"], np.int64)))
