"""Image offsets (``REGISTER_IMAGES``) as data: the shifts of the images in metres on the ground, the images moved
by them, and ``image_offsets.csv``.

A shift ``(east_m, north_m)`` is what is added to an image's stated ground position to put it on the DEM (an image
whose features appear 300 m east of where they are gets ``east_m = -300``); metres on the 1737.4 km sphere at the
image's centre.  The shifts are found by :mod:`lunaralbedo.engine.registration`; the web report
(:mod:`lunaralbedo.web.data`) and ``ingest --register`` use them through this module alone.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rasterio.transform import Affine

from ..constants import MOON_RADIUS_KM
from ..io.atomic import atomic_write_text
from ..io.rasters import bounds_in, geographic_crs
from .scene import Scene, overlaps_per_box

#: Metres of one degree of latitude on the Moon's sphere.
M_PER_DEG = math.radians(1.0) * MOON_RADIUS_KM * 1000.0


@dataclass
class Registration:
    """Per image (scene order): ``offsets_m`` and ``se_m`` ``(K, 2)`` (east, north, metres), ``pixel_m``
    (the image's pixel, metres), ``factor`` (pixels averaged at the finest level), ``levels`` (per level:
    its pixel factor, iterations, cost evaluations, observations, mean squared residual, seconds)."""

    keys: list[str]
    offsets_m: np.ndarray
    se_m: np.ndarray
    pixel_m: np.ndarray
    factor: int
    levels: list[dict]

    def to_dict(self) -> dict:
        return {"keys": self.keys, "offsets_m": self.offsets_m.tolist(), "se_m": np.nan_to_num(self.se_m, nan=-1).tolist(),
                "pixel_m": self.pixel_m.tolist(), "factor": self.factor, "levels": self.levels}

    @classmethod
    def from_dict(cls, d: dict) -> "Registration":
        se = np.array(d["se_m"], float)
        return cls(d["keys"], np.array(d["offsets_m"], float), np.where(se < 0, np.nan, se), np.array(d["pixel_m"], float),
                   int(d["factor"]), d["levels"])


def metres_to_map(info) -> np.ndarray:
    """2x2 matrix: the DRG's map units per metre east (column 0) and north (column 1) at its centre."""
    w, s, e, n = info.lonlat_bounds
    lon, lat = (w + e) / 2, (s + n) / 2
    if info.crs is None or info.crs.is_geographic:
        return np.array([[1.0 / (M_PER_DEG * math.cos(math.radians(lat))), 0.0], [0.0, 1.0 / M_PER_DEG]])
    from rasterio.warp import transform

    d = 1e-3  # degrees
    xs, ys = transform(geographic_crs(info.crs), info.crs, [lon, lon + d, lon], [lat, lat, lat + d])
    east_m, north_m = d * M_PER_DEG * math.cos(math.radians(lat)), d * M_PER_DEG
    return np.array([[(xs[1] - xs[0]) / east_m, (xs[2] - xs[0]) / north_m], [(ys[1] - ys[0]) / east_m, (ys[2] - ys[0]) / north_m]])


def pixel_metres(info) -> float:
    """The ground size of one pixel of ``info`` (metres: the square root of its area)."""
    t = info.transform
    return math.sqrt(abs(t.a * t.e - t.b * t.d) / abs(np.linalg.det(metres_to_map(info))))


def shifted_scene(scene: Scene, offsets_m: np.ndarray) -> Scene:
    """``scene`` with each image's georeference moved by its offset (metres east, north), and the images of every
    tile found again for the moved footprints."""
    images = []
    for info, off in zip(scene.images, offsets_m):
        dx, dy = metres_to_map(info) @ np.asarray(off, float)
        t = Affine.translation(dx, dy) @ info.transform
        w, s, e, n = info.bounds
        bounds = (w + dx, s + dy, e + dx, n + dy)
        geo = None if info.geo_bounds is None else bounds_in(info.crs, geographic_crs(info.crs), bounds)
        images.append(dataclasses.replace(info, transform=t, bounds=bounds, geo_bounds=geo))
    padded = [t.padded_bounds for t in scene.tiles]
    tile_images = overlaps_per_box([im.lonlat_bounds for im in images], padded)
    return dataclasses.replace(scene, images=images, tile_images=tile_images)


def write_offsets_csv(path: Path, r: Registration) -> None:
    """``key,east_m,north_m,east_se_m,north_se_m``: the shift added to each image's stated ground position to put it on
    the DEM, and its standard errors (metres; empty where not determined), atomically."""
    fmt = lambda v: "" if not np.isfinite(v) else f"{v:.6g}"  # noqa: E731
    lines = ["key,east_m,north_m,east_se_m,north_se_m"]
    lines += [f"{k},{o[0]:.6g},{o[1]:.6g},{fmt(e[0])},{fmt(e[1])}" for k, o, e in zip(r.keys, r.offsets_m, r.se_m)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_offsets_csv(path: Path) -> dict[str, tuple[float, float]]:
    """``{key: (east_m, north_m)}`` from an ``image_offsets.csv``."""
    rows = Path(path).read_text().splitlines()[1:]
    return {r.split(",")[0]: (float(r.split(",")[1]), float(r.split(",")[2])) for r in rows if r.strip()}
