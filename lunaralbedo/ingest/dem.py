"""DEM inputs (GeoTIFF tiles or ISIS DEM cubes) as heights in metres above the 1737.4 km sphere.

ISIS DEM cubes holding radius (e.g. GLD100, ~1.737e6 m) are converted; ``mode``
forces the interpretation (``auto``, ``radius`` or ``height``).  Sources may be
geographic or projected; lookups go through lon/lat (degrees).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from rasterio.crs import CRS
from rasterio.transform import Affine
from rasterio.warp import transform as warp_transform

from ..errors import InputError
from ..io.guard import open_quietly
from ..io.rasters import MOON_CRS
from ..isis.pixels import read_dem_cube
from ..model.geometry import merge_dem_layers, radius_to_height
from ..model.grid import Grid, aligned_grid, bilinear

DEM_SUFFIXES = (".tif", ".tiff", ".cub", ".vrt", ".img")


@dataclass
class DemSource:
    """One DEM raster in memory: heights (m, NaN = no data) and georeference."""

    path: Path
    heights: np.ndarray
    transform: Affine
    crs: CRS | None
    was_radius: bool

    @property
    def geographic(self) -> bool:
        return self.crs is None or self.crs.is_geographic

    def lon_range(self) -> tuple[float, float]:
        w = self.transform.c
        return w, w + self.transform.a * self.heights.shape[1]

    def sample(self, lon, lat) -> np.ndarray:
        """Bilinear heights (m) at lon/lat (degrees); NaN outside."""
        lon = np.asarray(lon, dtype=np.float64)
        lat = np.asarray(lat, dtype=np.float64)
        if self.geographic:
            w = self.lon_range()[0]
            x = w + np.mod(lon - w, 360.0)  # any longitude (e.g. 185 or -175) onto the DEM's own range
            y = lat
        else:
            xs, ys = warp_transform(MOON_CRS, self.crs, lon.ravel().tolist(), lat.ravel().tolist())
            x, y = np.reshape(xs, lon.shape), np.reshape(ys, lat.shape)
        inv = ~self.transform
        with np.errstate(invalid="ignore"):  # points the projection cannot map (inf) fall outside: NaN
            col = inv.a * np.asarray(x) + inv.b * np.asarray(y) + inv.c
            row = inv.d * np.asarray(x) + inv.e * np.asarray(y) + inv.f
        return bilinear(self.heights, np.asarray(col) - 0.5, np.asarray(row) - 0.5)

    def native_res_deg(self) -> tuple[float, float]:
        if self.geographic:
            return abs(self.transform.a), abs(self.transform.e)
        deg = np.degrees(1.0 / 1737400.0)
        return abs(self.transform.a) * deg, abs(self.transform.e) * deg


def _read_geotiff(path: Path, mode: str) -> DemSource:
    with open_quietly(path, "DEM") as ds:
        arr = ds.read(1, masked=True).astype(np.float64).filled(np.nan)
        transform, crs = ds.transform, ds.crs
    heights, was_radius = radius_to_height(arr, mode)
    return DemSource(path, heights, transform, crs, was_radius)


def load_dems(paths: Sequence[str | Path], mode: str = "auto") -> list[DemSource]:
    """Read DEM files or folders of DEM files (sorted by name)."""
    files: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            files.extend(sorted(f for f in p.iterdir() if f.suffix.lower() in DEM_SUFFIXES))
        elif p.is_file():
            files.append(p)
        else:
            raise InputError(f"{p}: DEM file or folder not found")
    if not files:
        raise InputError(f"no DEM rasters in {', '.join(map(str, paths))}")
    out = []
    for f in files:
        src = read_dem_cube(f, mode) if f.suffix.lower() == ".cub" else None
        out.append(DemSource(f, *src) if src is not None else _read_geotiff(f, mode))
        if out[-1].transform == Affine.identity():
            raise InputError(f"{f}: DEM has no georeferencing")
        if not np.isfinite(out[-1].heights).any():
            raise InputError(f"{f}: DEM has no valid heights")
    return out


class DemMosaic:
    """Several DEM sources looked up as one: where they overlap, their heights are averaged.

    The overlap rule is :func:`lunaralbedo.model.geometry.merge_dem_layers` (the PhotometryTK manual,
    section 6), the one ``solve`` applies to the work dir's DEM tiles too.
    """

    def __init__(self, sources: Sequence[DemSource]):
        self.sources = list(sources)

    def height(self, lon, lat) -> np.ndarray:
        """Heights (m above 1737.4 km) at lon/lat degrees; NaN where no source has data."""
        lon, lat = np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
        return merge_dem_layers((s.sample(lon, lat) for s in self.sources), lon.shape)

    def base_grid(self, box: tuple[float, float, float, float], mpp_deg: float | None = None) -> Grid:
        """Grid covering ``box`` (west, south, east, north): the first DEM's pixels, or ``mpp_deg`` pixels."""
        first = self.sources[0]
        if mpp_deg is not None:
            return aligned_grid((mpp_deg, mpp_deg), box)
        origin = (first.transform.c, first.transform.f) if first.geographic else (0.0, 0.0)
        return aligned_grid(first.native_res_deg(), box, origin)

    def onto(self, grid: Grid) -> np.ndarray:
        """Heights (m) bilinearly resampled onto ``grid``."""
        lon, lat = grid.lonlat()
        return self.height(np.array(lon), np.array(lat))

    @property
    def radius_converted(self) -> list[Path]:
        return [s.path for s in self.sources if s.was_radius]
