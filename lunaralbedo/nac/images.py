"""Read one image band (GeoTIFF or ISIS3 cube) as float64 with NaN where there is no data."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError


def read_image(path: str | Path) -> np.ndarray:
    """Band 1 of ``path``: ISIS special pixels and GDAL nodata become NaN (InputError when unreadable)."""
    from ..io.guard import open_quietly

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: image not found")
    if path.suffix.lower() == ".cub":
        from ..isis.pixels import read_band

        return read_band(path, 1)
    with open_quietly(path, "image") as ds:
        return ds.read(1, masked=True).astype(np.float64).filled(np.nan)
