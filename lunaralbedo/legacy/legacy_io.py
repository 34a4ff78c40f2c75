"""Reading the legacy inputs and writing the legacy output files.

Every reader turns an unreadable or unsuitable file into an
:class:`~lunaralbedo.errors.InputError` naming the file; every writer is atomic.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rasterio.crs import CRS
from rasterio.transform import Affine

from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..io.geotiff import write_geotiff
from ..io.guard import open_quietly
from .vwgeo import Geo

TIF_SUFFIX = ".tif"


@dataclass(frozen=True)
class Header:
    """What the legacy program needed to know about a raster without its pixels."""

    path: Path
    geo: Geo
    crs: CRS | None
    dtype: str
    count: int
    nodata: float | None


def list_tifs(folder: Path, what: str) -> list[Path]:
    """``*.tif`` files of ``folder`` in lexicographic order (the legacy ``ls``/listTifsInDir order)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: {what} folder not found")
    files = sorted((p for p in folder.iterdir() if p.is_file() and p.name.endswith(TIF_SUFFIX)), key=lambda p: str(p))
    if not files:
        raise InputError(f"{folder}: no {what} files (*.tif) in folder")
    return files


def read_header(path: Path) -> Header:
    """Georeference and format of ``path``; InputError if it is not a north-up georeferenced raster."""
    path = Path(path)
    with open_quietly(path) as ds:
        if ds.transform == Affine.identity():
            raise InputError(f"{path}: raster has no georeferencing")
        try:
            geo = Geo.from_gdal(ds.transform, ds.width, ds.height)
        except ValueError as exc:
            raise InputError(f"{path}: {exc}") from None
        return Header(path, geo, ds.crs, ds.dtypes[0], ds.count, ds.nodata)


def read_drg(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(values float32, valid bool)`` of a legacy DRG: uint8 gray, validity from the alpha band.

    The legacy program required uint8 DRGs (it exited otherwise); a second band
    is the alpha mask (0 = invalid), and a nodata value, if any, is invalid too.
    """
    path = Path(path)
    with open_quietly(path) as ds:
        if ds.dtypes[0] != "uint8":
            raise InputError(f"{path}: the legacy program requires uint8 DRG images, this one is {ds.dtypes[0]}")
        data = ds.read(1)
        valid = np.ones(data.shape, dtype=bool)
        if ds.count >= 2:
            valid &= ds.read(2) != 0
        if ds.nodata is not None:
            valid &= data != ds.nodata
    return data.astype(np.float32), valid


def read_dem(path: Path, default_nodata: float) -> tuple[np.ndarray, float]:
    """``(heights float32, nodata)``; the file's own nodata wins over the settings value."""
    path = Path(path)
    with open_quietly(path) as ds:
        if ds.dtypes[0] not in ("int16", "float32", "float64", "int32", "uint16"):
            raise InputError(f"{path}: DEM must be int16 or float, this one is {ds.dtypes[0]}")
        nodata = float(ds.nodata) if ds.nodata is not None else float(default_nodata)
        return ds.read(1).astype(np.float32), float(np.float32(nodata))


def write_uint8_tile(path: Path, value: np.ndarray, valid: np.ndarray, geo: Geo, crs) -> None:
    """A legacy uint8 gray + alpha tile (alpha 255 where valid)."""
    alpha = np.where(valid, 255, 0).astype(np.uint8)
    write_geotiff(path, np.stack([value.astype(np.uint8), alpha]), geo.transform, crs, dtype="uint8")


def write_float_tile(path: Path, value: np.ndarray, geo: Geo, crs, nodata: float | None = None) -> None:
    """A float32 single-band tile (DEM, weightsSum)."""
    write_geotiff(path, value.astype(np.float32), geo.transform, crs, nodata=nodata, dtype="float32")


def write_lines(path: Path, lines: list[str]) -> None:
    """A text file of ``lines`` (each ends with a newline), atomically."""
    atomic_write_text(path, "".join(line + "\n" for line in lines))


def format_list_line(path: str, corners: tuple[float, float, float, float]) -> str:
    """One line of a legacy image/tile list: ``1 path west east south north`` (20 significant digits)."""
    return "1 " + path + " " + " ".join(_g20(v) for v in corners)


def _g20(v: float) -> str:
    """C++ ``ostream`` with precision 20 (``%.20g``)."""
    return f"{v:.20g}"
