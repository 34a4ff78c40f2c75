"""ISIS3 pixels through rasterio/GDAL (driver ISIS3), with special pixels masked.

ISIS reserves the lowest values of each pixel type for special pixels (NULL, LRS,
LIS, HIS, HRS); they become NaN here.  Stored values are then scaled to physical
ones with the label's ``Base + Multiplier * stored``.

DEM cubes: some (e.g. GLD100) hold planetary **radius** in metres (~1.737e6)
rather than height; :func:`read_dem_cube` detects this and returns height in
metres above the 1737.4 km sphere.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from rasterio.errors import RasterioIOError

from ..errors import IsisError
from ..io.guard import open_quietly
from ..model.geometry import radius_to_height
from .labels import IsisLabel, read_label, value_of

#: Special-pixel ranges (inclusive) of each ISIS pixel type, as stored values.
_SPECIAL = {
    "Real": (-np.inf, float(np.frombuffer(np.uint32(0xFF7FFFFA).tobytes(), "<f4")[0])),
    "SignedWord": (-32768, -32764),
    "UnsignedWord": (0, 2),  # NULL=0, LRS=1, LIS=2 (HIS/HRS at the top, see below)
    "UnsignedByte": (0, 0),
}
_SPECIAL_HIGH = {"UnsignedWord": 65534, "UnsignedByte": 255}



def special_mask(stored: np.ndarray, pixel_type: str) -> np.ndarray:
    """True where ``stored`` (raw cube values) is an ISIS special pixel (or not finite)."""
    lo, hi = _SPECIAL.get(pixel_type, (-np.inf, -np.inf))
    a = np.asarray(stored)
    mask = (a >= lo) & (a <= hi)
    if pixel_type == "Real":
        mask |= ~np.isfinite(a) | (a <= hi)
    if pixel_type in _SPECIAL_HIGH:
        mask |= a >= _SPECIAL_HIGH[pixel_type]
    return mask


def read_band(label: IsisLabel | str | Path, band: int = 1) -> np.ndarray:
    """Band ``band`` (1-based) of a cube as float64 physical values, NaN at special pixels."""
    return read_rows(label, None, None, band)


def read_rows(label: IsisLabel | str | Path, start: int | None, stop: int | None, band: int = 1) -> np.ndarray:
    """Lines ``[start, stop)`` (0-based; None: all) of band ``band`` as in :func:`read_band`, read by a window."""
    from rasterio.windows import Window

    if not isinstance(label, IsisLabel):
        label = read_label(label)
    data_path = label.data_path
    if data_path is None:
        raise IsisError(f"{label.path}: label only, the cube has no pixels to read")
    with open_quietly(data_path, "the cube's pixels", IsisError) as ds:
        if not 1 <= band <= ds.count:
            raise IsisError(f"{data_path}: band {band} out of range 1..{ds.count}")
        window = None if start is None and stop is None else \
            Window(0, start or 0, ds.width, (ds.height if stop is None else stop) - (start or 0))
        try:
            stored = ds.read(band, window=window, masked=False)
        except RasterioIOError as exc:
            raise IsisError(f"{data_path}: cannot read the cube's pixels: {_read_failure(label, data_path, exc)}") from None
    base, mult = label.base_multiplier
    out = base + mult * stored.astype(np.float64)
    out[special_mask(stored, label.pixel_type)] = np.nan
    return out


_PIXEL_BYTES = {"Real": 4, "SignedWord": 2, "UnsignedWord": 2, "UnsignedByte": 1}


def _read_failure(label: IsisLabel, data_path: Path, exc: Exception) -> str:
    """What GDAL's failure means: a file shorter than its label says (truncated), or GDAL's own words."""
    try:
        core = label.cube["Core"]
        start = int(value_of(core.get("StartByte", 1))) - 1
        bands, lines, samples = label.shape
        need = start + bands * lines * samples * _PIXEL_BYTES[label.pixel_type]
        size = data_path.stat().st_size
        if size < need:
            return f"the file is truncated ({size:,} bytes, its label needs {need:,})"
    except (KeyError, TypeError, ValueError, OSError):
        pass
    text = str(exc).replace("See previous exception for details.", "").strip().rstrip(".")
    return f"GDAL: {text or type(exc).__name__} (truncated or corrupt file?)"


def cube_georeference(path: str | Path):
    """``(transform, crs)`` GDAL derives from a map-projected cube's Mapping group."""
    with open_quietly(path, "cube", IsisError) as ds:
        return ds.transform, ds.crs


def read_dem_cube(path: str | Path, mode: str = "auto"):
    """A DEM cube as ``(heights_m float64 with NaN, transform, crs, was_radius)``."""
    label = read_label(path)
    if not label.is_map_projected:
        raise IsisError(f"{path}: a DEM cube must be map-projected (no Mapping group)")
    values = read_band(label, 1)
    heights, was_radius = radius_to_height(values, mode)
    transform, crs = cube_georeference(label.data_path)
    return heights, transform, crs, was_radius
