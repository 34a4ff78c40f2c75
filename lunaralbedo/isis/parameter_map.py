"""Equirectangular ISIS parameter cubes (e.g. the Sato et al. WAC Hapke map): read into memory, ground point -> pixel.

A ground point (planetocentric latitude, east longitude, degrees) falls in map pixel
``(int(X + 0.5), int(Y + 0.5))`` with ``X = (x - UpperLeftCornerX) / PixelResolution + 0.5``
(ISIS ``Projection::WorldX``).  Used by the ``photometry`` command (``lrowacphomap``) and by
the solver's Hapke model (per-point parameters).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import IsisError
from .labels import read_label, value_of
from .pixels import read_band


@dataclass
class ParameterMap:
    """Equirectangular parameter cube in memory: ``data`` (bands, lines, samples), NaN at special pixels."""

    path: Path
    data: np.ndarray
    band_names: list[str]
    ulx: float
    uly: float
    resolution: float
    radius: float
    center_lon: float
    center_lat: float
    positive_west: bool

    def pixel(self, lat_deg, lon_deg):
        """0-based ``(row, col)`` of the map pixel holding each point and whether it is inside the map."""
        lon = np.mod(np.asarray(lon_deg, dtype=np.float64), 360.0)
        lon = -lon if self.positive_west else lon
        x = self.radius * math.cos(math.radians(self.center_lat)) * np.radians(lon - self.center_lon)
        y = self.radius * np.radians(np.asarray(lat_deg, dtype=np.float64))
        with np.errstate(invalid="ignore"):
            s = np.trunc((x - self.ulx) / self.resolution + 1.0)
            l = np.trunc((self.uly - y) / self.resolution + 1.0)
        _b, nl, ns = self.data.shape
        inside = (s >= 1) & (s <= ns) & (l >= 1) & (l <= nl)
        return np.where(inside, l - 1, 0).astype(np.int64), np.where(inside, s - 1, 0).astype(np.int64), inside


def read_parameter_map(path: str | Path) -> ParameterMap:
    """Read an Equirectangular parameter cube (e.g. the Sato et al. WAC Hapke map)."""
    label = read_label(path)
    m = label.group("Mapping")
    proj = str(value_of(m.get("ProjectionName", ""))).lower()
    if proj not in ("equirectangular", "simplecylindrical"):
        raise IsisError(f"{path}: parameter map projection {proj!r} is not supported (Equirectangular)")
    names = label.group("BandBin").get("Name")
    if names is None:
        raise IsisError(f"{path}: parameter map has no BandBin/Name keyword")
    bands = label.shape[0]
    data = np.stack([read_band(label, b) for b in range(1, bands + 1)])

    def num(key, default=None):
        v = m.get(key, default)
        if v is None:
            raise IsisError(f"{path}: Mapping group has no {key}")
        return float(value_of(v))

    return ParameterMap(Path(path), data, [str(n) for n in names], num("UpperLeftCornerX"), num("UpperLeftCornerY"),
                        num("PixelResolution"), num("EquatorialRadius"), num("CenterLongitude", 0.0),
                        num("CenterLatitude", 0.0) if proj == "equirectangular" else 0.0,
                        str(value_of(m.get("LongitudeDirection", "PositiveEast"))).lower() == "positivewest")
