"""A DRG read whole into memory at a reduced resolution, for the image-to-DEM registration.

The registration (:mod:`lunaralbedo.engine.registration`) samples every image at sub-pixel
ground shifts many times; it holds each image once, on its own grid, block-averaged by an
integer ``factor`` so that a scene of real size fits in memory.  Read a strip of rows at a
time: the full-resolution pixels of a strip are the only ones held at once.
"""
from __future__ import annotations

import numpy as np
from rasterio.transform import Affine
from rasterio.windows import Window

from .guard import raster_errors
from .opened import open_raster
from .rasters import RasterInfo

#: Rows of decimated output read per strip.
_STRIP = 256


def read_drg_decimated(info: RasterInfo, factor: int, lit_threshold: float | None = None,
                       saturation: float | None = None) -> tuple[np.ndarray, np.ndarray, Affine]:
    """``(value, usable, transform)`` of a DRG averaged over ``factor`` x ``factor`` blocks of its pixels.

    ``value`` (float32) is the mean of each block's pixels, ``usable`` (bool) True where every
    pixel of the block is valid (alpha > 0, not nodata, finite), lit (DN >= ``lit_threshold``,
    shadow type 1) and below ``saturation`` (:func:`lunaralbedo.model.shadows.window_pixels`);
    ``transform`` maps the decimated pixels to the DRG's CRS (its stated georeference).  Edge
    blocks that the image does not fill are not usable.
    """
    from ..model.shadows import window_pixels

    f = int(factor)
    h, w = -(-info.height // f), -(-info.width // f)
    value = np.zeros((h, w), np.float32)
    usable = np.zeros((h, w), bool)
    with raster_errors(info.path), open_raster(info.path) as ds:
        for o0 in range(0, h, _STRIP):
            o1 = min(h, o0 + _STRIP)
            r0, r1 = o0 * f, min(info.height, o1 * f)
            bands = ds.read((1, 2) if info.has_alpha else (1,), window=Window(0, r0, info.width, r1 - r0))
            val, valid, use = window_pixels(bands[0], bands[1] if info.has_alpha else None, info.nodata, None,
                                            lit_threshold, saturation)
            use = valid if use is None else use
            pad = ((0, (o1 - o0) * f - (r1 - r0)), (0, w * f - info.width))
            val = np.pad(val.astype(np.float64), pad).reshape(o1 - o0, f, w, f)
            use = np.pad(use, pad).reshape(o1 - o0, f, w, f)
            value[o0:o1] = val.mean(axis=(1, 3))
            usable[o0:o1] = use.all(axis=(1, 3))
    return value, usable, info.transform @ Affine.scale(f)


def write_moved(path, transform: Affine) -> None:
    """Give the raster at ``path`` the georeference ``transform`` (its pixels unchanged), atomically: a copy with the
    new transform replaces the file (a registered DRG, :func:`lunaralbedo.engine.registration.register_workdir`)."""
    import shutil

    import rasterio

    from .atomic import atomic_path

    with raster_errors(path), atomic_path(path) as tmp:
        shutil.copyfile(path, tmp)
        with rasterio.open(tmp, "r+") as ds:
            ds.transform = transform
