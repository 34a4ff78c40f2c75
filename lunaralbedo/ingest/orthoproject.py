"""Orthoprojection (replaces ASP ``orthoproject``): image values on a DEM-aligned lon/lat grid.

Level 1 (camera model): for every output pixel, the DEM point (body-fixed km) is
projected into the cube with the camera model and the image is sampled
bilinearly; points outside the image, behind the camera or on slopes facing
away from the spacecraft (cos e <= 0) get NaN.
Level 2 (map-projected cube): the cube is warped onto the grid with rasterio.
"""
from __future__ import annotations

import warnings

import numpy as np
from rasterio.errors import NotGeoreferencedWarning
from rasterio.warp import Resampling, reproject
from rasterio.warp import transform as warp_transform

from ..io.rasters import MOON_CRS
from ..isis.labels import IsisLabel
from ..isis.pixels import cube_georeference, read_band
from ..model.geometry import lonlat_height
from .approx import exact_coordinates, image_coordinates
from ..model.grid import Grid
from .sampling import sample_visible


def orthoproject(camera, image: np.ndarray, grid: Grid, heights_m: np.ndarray, block_rows: int = 256,
                 exact: bool = False) -> np.ndarray:
    """Image values (float64, NaN where not seen) on ``grid`` with DEM ``heights_m`` (metres) on that grid.

    Cube coordinates come from :func:`.approx.image_coordinates` (exact projection on a
    coarse grid, interpolation checked to 0.125 px and refined where exceeded);
    ``exact=True`` projects every pixel with the camera model instead (slow: a line
    scanner searches the exposure line of every point); cameras whose ground map is not
    smooth (``smooth_ground_map = False``: the LRO WAC's framelets) are always projected exactly.
    """
    exact = exact or not getattr(camera, "smooth_ground_map", True)
    h = grid.shape[0]
    out = np.full(grid.shape, np.nan)
    center_pos = camera.positions[len(camera.positions) // 2]
    lon1 = grid.transform.c + grid.transform.a * (np.arange(grid.shape[1]) + 0.5)
    heights_m = np.asarray(heights_m, dtype=np.float64)
    # every row of heights_m has its latitude: a DEM one row longer than the grid gives its last row's normal
    lat1 = grid.transform.f + grid.transform.e * (np.arange(max(h, heights_m.shape[0])) + 0.5)
    for r0 in range(0, h, block_rows):
        r1 = min(h, r0 + block_rows)
        if exact:
            rows, cols = np.indices((r1 - r0, grid.shape[1]))
            s, l = exact_coordinates(camera, grid.transform, r0 + rows, cols, heights_m[r0:r1])
        else:
            s, l, _ = image_coordinates(camera, grid.transform, r0, heights_m[r0:r1])
        sample_visible(image, s, l, lon1, lat1, heights_m, r0, center_pos, out[r0:r1])
    return out


def footprint(camera, height_fn, n: int = 24):
    """Lon/lat (degrees) of the cube's border as seen on the DEM; ``(lon, lat)`` arrays, NaN where off the Moon."""
    from ..camera.intersect import ray_dem

    ls, ss = camera.lines, camera.samples
    t = np.linspace(0.0, 1.0, n)
    samples = np.concatenate([0.5 + t * ss, np.full(n, ss + 0.5), 0.5 + t[::-1] * ss, np.full(n, 0.5)])
    lines = np.concatenate([np.full(n, 0.5), 0.5 + t * ls, np.full(n, ls + 0.5), 0.5 + t[::-1] * ls])
    samples = np.clip(samples, 0.5001, ss + 0.4999)
    lines = np.clip(lines, 0.5001, ls + 0.4999)
    origins, dirs = camera.rays(samples, lines)

    def h(lon, lat):
        v = height_fn(lon, lat)
        return np.where(np.isfinite(v), v, 0.0)

    pts = ray_dem(origins, dirs, h)
    lon, lat, _ = lonlat_height(pts)
    return lon, lat


def level2_bounds(label: IsisLabel):
    """Lon/lat (degrees) of the border of a map-projected cube."""
    transform, crs = cube_georeference(label.data_path)
    _b, lines, samples = label.shape
    t = np.linspace(0, 1, 16)
    cols = np.concatenate([t * samples, np.full(16, samples), t * samples, np.zeros(16)])
    rows = np.concatenate([np.zeros(16), t * lines, np.full(16, lines), t * lines])
    xs = transform.a * cols + transform.b * rows + transform.c
    ys = transform.d * cols + transform.e * rows + transform.f
    if crs is None or crs.is_geographic:
        return np.asarray(xs), np.asarray(ys)
    lon, lat = warp_transform(crs, MOON_CRS, list(np.ravel(xs)), list(np.ravel(ys)))
    return np.asarray(lon), np.asarray(lat)


def warp_level2(label: IsisLabel, grid: Grid, band: int = 1) -> np.ndarray:
    """A map-projected cube's band warped (bilinear) onto ``grid``; NaN where no data."""
    data = read_band(label, band).astype(np.float32)
    transform, crs = cube_georeference(label.data_path)
    out = np.full(grid.shape, np.nan, dtype=np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        reproject(source=data, destination=out, src_transform=transform, src_crs=crs or MOON_CRS,
                  src_nodata=np.nan, dst_transform=grid.transform, dst_crs=MOON_CRS, dst_nodata=np.nan,
                  resampling=Resampling.bilinear)
    return out.astype(np.float64)
