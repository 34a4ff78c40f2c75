"""A tile's compact observations in pixel-major order: each pixel's observations together, images in tile order.

The prepare step gathers observations image by image (:mod:`.observations`); the iterations
(:func:`.kernels.iterate_pixels`) and finalise (:func:`.kernels.finalise_pixels`) take them
pixel by pixel.  :func:`pixel_major` reorders a block once, before it is cached, with a stable
counting sort (:func:`by_pixel`), so the cache holds the iterations' order.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def by_pixel(pix, start, npix, image_of, src, dst):
    """Pixel-major order of image-major observations (counting sort, stable: images stay in tile order).

    ``src`` ``(n_arrays, m)``: the observations' arrays, image-major; each observation's
    values go to its place in the same rows of ``dst``, and ``image_of`` gets the local image
    of each place, in one pass.  Returns ``(offsets, pixels)``: pixel ``pixels[j]`` owns
    places ``offsets[j]:offsets[j+1]``.
    """
    nxt = np.zeros(npix, np.int32)  # counts, then each pixel's next free place
    for o in range(pix.shape[0]):
        nxt[pix[o]] += 1
    m = 0
    for p in range(npix):
        m += nxt[p] != 0
    pixels = np.empty(m, np.int32)
    offsets = np.empty(m + 1, np.int32)
    j = 0
    pos = 0
    for p in range(npix):
        c = nxt[p]
        nxt[p] = pos
        if c != 0:
            pixels[j] = p
            offsets[j] = pos
            pos += c
            j += 1
    offsets[m] = pos
    for k in range(start.shape[0] - 1):
        for o in range(start[k], start[k + 1]):
            q = nxt[pix[o]]
            nxt[pix[o]] = q + 1
            image_of[q] = k
            for a in range(src.shape[0]):
                dst[a, q] = src[a, o]
    return offsets, pixels


def _rows_of(obs, names):
    """The arrays ``names`` as the rows of one array: the array they are consecutive rows of (no copy), else stacked."""
    base = getattr(obs[names[0]], "base", None) if names else None
    if (isinstance(base, np.ndarray) and base.ndim == 2 and base.shape[0] == len(names) and base.flags.c_contiguous
            and all(obs[n].base is base and obs[n].shape == base[i].shape and obs[n].ctypes.data == base[i].ctypes.data
                    for i, n in enumerate(names))):
        return base
    return np.stack([np.asarray(obs[n]) for n in names]) if names else np.zeros((0, len(obs["pix"])), np.float32)


def pixel_major(obs, npix: int, names) -> dict:
    """A tile's compact observations (image-major, :mod:`.observations`) in pixel-major order.

    ``offsets``/``pixels`` (int32) per pixel with observations, ``image_of`` (uint16, or int32
    beyond 65535 images) the local image of each observation, the arrays ``names`` permuted
    (rows of one array of their common type: :func:`by_pixel` moves them in one pass), and
    ``index``.  ~18 bytes per observation for value, weight and two layers.
    """
    index = np.asarray(obs["index"])
    m = len(obs["pix"])
    if m >= 2**31:
        raise ValueError(f"{m} observations in one tile: more than int32 offsets hold")
    image_of = np.empty(m, np.uint16 if len(index) < 2**16 else np.int32)
    src = _rows_of(obs, list(names))
    dst = np.empty_like(src)
    offsets, pixels = by_pixel(np.asarray(obs["pix"]), np.asarray(obs["start"]), npix, image_of, src, dst)
    return {"offsets": offsets, "pixels": pixels, "image_of": image_of, "index": index, **dict(zip(names, dst))}
