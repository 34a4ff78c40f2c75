"""``lrowacphomap``: HapkeLROC with per-pixel parameters from a map, correct and ISIS-compatible modes.

The parameter map is an Equirectangular cube; a ground point (planetocentric latitude,
east longitude, degrees) falls in map pixel ``(int(X + 0.5), int(Y + 0.5))`` with
``X = (x - UpperLeftCornerX) / PixelResolution + 0.5`` (ISIS ``Projection::WorldX``).

Correct mode: the ``Parameters`` group whose ``BandBinCenter`` equals the image band's
centre, and ``r(i_r, e_r, g_r) / r(i, e, g)`` from that one group.
``isis_compat`` reproduces two defects of ISIS (documented in docs/photometry.md):
(1) with one band selected, groups whose centre is not the band's keep ISIS's default
band 1, so every group "matches" and the last one in the file is used; (2) the result
cache keyed only on (i, e, g) gives every matching group the reference value of the
first matching group.  Points outside the map give 0 (ISIS) or NaN (correct mode).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import IsisError
from ..isis.labels import read_label, value_of
from ..isis.pixels import read_band
from ..model.photometry.hapke import HAPKE_LROC_PARAMETERS, hapke_lroc
from .params import HapkeMapParams


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


def isis_group_choice(params: HapkeMapParams, selected_centers, band: int) -> tuple[int, int]:
    """ISIS's ``(group used for the pixel, group giving the reference value)`` for virtual band ``band`` (1-based).

    Each group's band is the last selected band whose centre equals its ``BandBinCenter``,
    else 1; the pixel uses the last group whose band is ``band``, the reference value
    comes from the first (result cache).
    """
    owner = []
    for g in params.groups:
        hits = [j + 1 for j, c in enumerate(selected_centers) if float(c) == g.center]
        owner.append(hits[-1] if hits else 1)
    matching = [k for k, b in enumerate(owner) if b == band]
    if not matching:
        raise IsisError(f"no Parameters group for band {band}")
    return matching[-1], matching[0]


def correct_group(params: HapkeMapParams, center: float) -> int:
    """The group whose ``BandBinCenter`` is the band's centre (nm)."""
    for k, g in enumerate(params.groups):
        if g.center == float(center):
            return k
    raise IsisError(f"no Parameters group for band centre {center} nm "
                    f"(groups: {', '.join(str(g.center) for g in params.groups)})")


def _values(pmap: ParameterMap, group, rows, cols):
    missing = [n for n in HAPKE_LROC_PARAMETERS if n not in group.bands]
    if missing:
        raise IsisError(f"{pmap.path}: the Parameters group for {group.center} nm lacks {', '.join(missing)}")
    return [pmap.data[group.bands[n]][rows, cols] for n in HAPKE_LROC_PARAMETERS]


def hapke_map_correction(params: HapkeMapParams, pmap: ParameterMap, incidence, emission, phase, lat, lon,
                         center: float, isis_compat: bool = False, selected_centers=None, band: int = 1):
    """Multiplicative correction per pixel (NaN where not computable; 0 outside the map in ISIS mode)."""
    rows, cols, inside = pmap.pixel(lat, lon)
    if isis_compat:
        used, ref = isis_group_choice(params, selected_centers if selected_centers is not None else [center], band)
    else:
        used = ref = correct_group(params, center)
    pix = _values(pmap, params.groups[used], rows, cols)
    std = _values(pmap, params.groups[ref], rows, cols)
    i_r, e_r, g_r = params.reference
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = hapke_lroc(i_r, e_r, g_r, *std) / hapke_lroc(incidence, emission, phase, *pix)
    special = np.any(~np.isfinite(np.stack(pix + std)), axis=0)
    corr = np.where(special, np.nan, corr)
    return np.where(inside, corr, 0.0 if isis_compat else np.nan)
