"""Default output resolution and tile size of ``ingest``.

* **Resolution** (as ISIS ``cam2map``'s default ``PIXRES=CAMERA``): the ground size of
  one camera pixel at the image centre, the mean of the sample and line spacings
  (ISIS ``Camera::PixelResolution``), measured by intersecting with the DEM the rays
  through points a quarter pixel either side of the centre.  Several images: the finest.
* **Tile size** (``TILE_SIZE``, degrees): the tile the solver works on should hold one
  block of rows of the solver's memory budget (:data:`TILE_PIXELS` pixels a side for the
  default 384 MiB budget at 96 bytes per pixel, ``engine/observations.py``), rounded down
  to a round number of degrees (:data:`ROUND_MANTISSAS` times a power of ten) so that tile names stay
  readable.
"""
from __future__ import annotations

import math

import numpy as np

from ..constants import MOON_RADIUS_M
from ..model.grid import mpp_to_degrees

#: Pixels on a side of a solver tile that fits the default budget in one block of rows
#: (sqrt(384 MiB / 96 bytes per pixel) = 2048; engine/observations.py BLOCK_BYTES, ROW_PIXEL_BYTES).
TILE_PIXELS = 2048
#: Bytes per tile pixel the solver holds for a tile processed as one block (engine/observations.py ROW_PIXEL_BYTES).
TILE_PIXEL_BYTES = 96
#: The default memory budget of one tile's block (engine/observations.py BLOCK_BYTES).
TILE_BUDGET_BYTES = 384 * 2**20


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


#: Round tile sizes: these times a power of ten (degrees).
ROUND_MANTISSAS = (8, 6, 5, 4, 3, 2.5, 2, 1.5, 1)


def round_down(value: float) -> float:
    """The largest of :data:`ROUND_MANTISSAS` times a power of ten that is <= ``value`` (> 0)."""
    k = math.floor(math.log10(value))
    for m in ROUND_MANTISSAS:
        v = m * 10.0**k
        if v <= value * (1 + 1e-9):
            return float(f"{v:.12g}")
    return float(f"{10.0 ** k:.12g}")


def tile_size_deg(mpp: float, budget_bytes: float = TILE_BUDGET_BYTES) -> float:
    """TILE_SIZE (degrees) for pixels of ``mpp`` metres: at most ``sqrt(budget / 96 bytes)`` pixels a side, rounded down.

    At most 4 degrees (the legacy default), at least one pixel.
    """
    px = math.sqrt(budget_bytes / TILE_PIXEL_BYTES)
    deg = px * mpp_to_degrees(mpp)
    return min(4.0, max(round_down(deg), mpp_to_degrees(mpp)))


def tile_pixels(tile_size: float, res_deg: float) -> int:
    """Pixels on a side of a ``tile_size``-degree tile of ``res_deg``-degree pixels."""
    return max(1, math.ceil(tile_size / res_deg - 1e-6))


def degrees_to_mpp(deg: float) -> float:
    """Metres per pixel on the 1737.4 km sphere for a pixel of ``deg`` degrees of arc."""
    return math.radians(deg) * MOON_RADIUS_M
