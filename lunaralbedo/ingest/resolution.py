"""Default output resolution and tile size of ``ingest``.

* **Resolution** (as ISIS ``cam2map``'s default ``PIXRES=CAMERA``): the ground size of
  one camera pixel at the image centre, the mean of the sample and line spacings
  (ISIS ``Camera::PixelResolution``), measured by intersecting with the DEM the rays
  through points a quarter pixel either side of the centre.  Several images: the finest
  (a multi-band push-frame cube: its first band).
* **Tile size** (``TILE_SIZE``, degrees): the tile the solver works on should be one
  block of rows of the solver's memory budget (``engine/observations.py``: 384 MiB at 96
  bytes per pixel, 2048 pixels a side), rounded down to a round number of degrees
  (:func:`lunaralbedo.model.grid.round_down`: tiles of ~1400 to 2048 px a side) so that
  tile names stay readable.
"""
from __future__ import annotations

import numpy as np

from ..engine.observations import BLOCK_BYTES, ROW_PIXEL_BYTES
from ..model.grid import mpp_to_degrees, tile_side_deg


def pixel_resolution_m(camera, height_fn) -> float:
    """Ground size (m) of one pixel at the centre of the image of ``camera`` on the DEM ``height_fn``.

    ``height_fn(lon_deg, lat_deg) -> metres``.  The mean of the sample and line spacings
    at the centre, as ISIS ``Camera::PixelResolution``; where the centre does not meet the
    Moon, the median over a 5 x 5 grid of interior points.  NaN when no point meets it.
    """
    from ..camera.intersect import ray_dem

    fr = np.array([0.5, 0.1, 0.3, 0.7, 0.9])
    s0 = 0.5 + np.round(fr * camera.samples)  # pixel centres (whole numbers): never on a framelet's edge
    l0 = 0.5 + np.round(fr * camera.lines)
    s0, l0 = (np.clip(v, 1.0, n) for v, n in ((s0, camera.samples), (l0, camera.lines)))
    ss, ll = np.meshgrid(s0, l0)
    ss, ll = ss.ravel(), ll.ravel()
    d = 0.25
    samples = np.concatenate([ss - d, ss + d, ss, ss])
    lines = np.concatenate([ll, ll, ll - d, ll + d])
    origins, dirs = camera.rays(samples, lines)

    def h(lon, lat):
        v = height_fn(lon, lat)
        return np.where(np.isfinite(v), v, 0.0)

    pts = ray_dem(origins, dirs, h).reshape(4, -1, 3)
    ds = np.linalg.norm(pts[1] - pts[0], axis=-1) / (2 * d)
    dl = np.linalg.norm(pts[3] - pts[2], axis=-1) / (2 * d)
    res = 1000.0 * (ds + dl) / 2.0  # km -> m
    if np.isfinite(res[0]) and res[0] > 0:
        return float(res[0])
    ok = res[np.isfinite(res) & (res > 0)]
    return float(np.median(ok)) if ok.size else float("nan")


def tile_size_deg(mpp: float) -> float:
    """TILE_SIZE (degrees) for pixels of ``mpp`` metres: tiles that the solver does in one block of rows of its
    default memory budget (:func:`lunaralbedo.model.grid.tile_side_deg`)."""
    return tile_side_deg(mpp_to_degrees(mpp), BLOCK_BYTES, ROW_PIXEL_BYTES)
