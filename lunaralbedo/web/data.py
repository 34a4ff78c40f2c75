"""The data files of the web map: script files (``*.js``) that a page loads with ``<script>``.

Browsers refuse ``fetch``/XHR of ``file://`` URLs, but load scripts; so every
datum is a script that assigns a global or calls a callback:

* ``data/meta.js``       ``LUNARALBEDO_META = {...}`` (pyramid, layers, stretches, tiles present);
* ``data/report.js``     ``LUNARALBEDO_REPORT = <report.json verbatim>`` and
  ``LUNARALBEDO_EXPOSURES = [{key, exposure, initial_exposure}, ...]`` (``exposure.csv``);
* ``data/footprints.js`` ``LUNARALBEDO_FOOTPRINTS = <GeoJSON FeatureCollection>``: per image,
  its valid pixels as polygons (lon/lat degrees, longitudes shifted like the tiles);
* ``data/values/<col>/<row>.js`` ``LUNARALBEDO_VALUES(col, row, {...})``: albedo and error of one
  finest-level tile as little-endian float32, base64 (NaN = no data), loaded on click.
"""
from __future__ import annotations

import base64
import csv
import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np
import rasterio
from rasterio import features
from rasterio.enums import Resampling
from rasterio.transform import Affine
from rasterio.warp import transform_geom

from ..errors import InputError
from ..export.pyramid import Node
from ..export.sources import Source, read_region
from ..io.atomic import atomic_write_text
from ..io.rasters import RasterInfo, catalog_drgs, geographic_crs

FOOTPRINT_SIDE = 256  # footprints are traced on the valid mask read at most this many pixels a side


def js_assign(name: str, value) -> str:
    """``window.NAME = <JSON>;`` (NaN and Infinity are valid JavaScript, so Python's JSON is kept)."""
    return f"window.{name} = {json.dumps(value, separators=(',', ':'))};\n"


def values_relpath(col: int, row: int) -> str:
    return f"data/values/{col}/{row}.js"


def _b64(values: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(values, dtype="<f4").tobytes()).decode("ascii")


def write_values(out_dir: Path, node: Node, layers: dict[str, Sequence[Source]], resampling: Resampling) -> int:
    """Task: the values of each layer on one finest-level tile as a script; returns its valid albedo pixels."""
    arrays = {name: read_region(srcs, node.grid, resampling) for name, srcs in layers.items() if srcs}
    payload = {"width": node.width, "height": node.height, **{k: _b64(v) for k, v in arrays.items()}}
    text = f"LUNARALBEDO_VALUES({node.col},{node.row},{json.dumps(payload)});\n"
    atomic_write_text(Path(out_dir) / values_relpath(node.col, node.row), text)
    return int(np.isfinite(arrays["albedo"]).sum())


def read_exposures(path: Path) -> list[dict]:
    """Rows of ``exposure.csv`` (numbers as floats); [] when the file is absent."""
    if not path.is_file():
        return []
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    out = []
    for r in rows:
        try:
            out.append({"key": r["key"], **{k: float(v) for k, v in r.items() if k != "key"}})
        except (KeyError, ValueError):
            raise InputError(f"{path}: not an exposure table (key,exposure,initial_exposure)") from None
    return out


def read_report(path: Path) -> dict:
    """``report.json`` as a dict; :class:`InputError` naming the file when it is missing or broken."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no run report; run `lunaralbedo solve` first") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None


def _valid_mask(ds, shape: tuple[int, int]) -> np.ndarray:
    vals = ds.read(1, out_shape=shape, resampling=Resampling.nearest, out_dtype=np.float32)
    ok = np.isfinite(vals)
    if ds.nodata is not None and not np.isnan(ds.nodata):
        ok &= vals != np.float32(ds.nodata)
    if ds.count >= 2:
        ok &= ds.read(2, out_shape=shape, resampling=Resampling.nearest) > 0
    return ok


def _shift_coords(coords, d: float):
    if isinstance(coords[0], (int, float)):
        return [round(coords[0] + d, 7), round(coords[1], 7)]
    return [_shift_coords(c, d) for c in coords]


def image_footprint(info: RasterInfo, centre_lon: float) -> dict | None:
    """GeoJSON MultiPolygon (lon/lat degrees) of the valid pixels of one DRG, or None when it has none.

    The mask is read at most :data:`FOOTPRINT_SIDE` pixels a side (nearest), so edges are
    exact to one such pixel; longitudes are shifted by a multiple of 360 deg to lie nearest ``centre_lon``.
    """
    scale = max(1.0, max(info.width, info.height) / FOOTPRINT_SIDE)
    shape = (max(1, math.ceil(info.height / scale)), max(1, math.ceil(info.width / scale)))
    with rasterio.open(info.path) as ds:
        ok = _valid_mask(ds, shape)
    if not ok.any():
        return None
    transform = info.transform @ Affine.scale(info.width / shape[1], info.height / shape[0])
    polys = [geom["coordinates"] for geom, _ in features.shapes(ok.astype(np.uint8), mask=ok, transform=transform)]
    geom = {"type": "MultiPolygon", "coordinates": polys}
    if info.crs is not None and not info.crs.is_geographic:
        geom = transform_geom(info.crs, geographic_crs(info.crs), geom)
    w, _, e, _ = info.lonlat_bounds
    d = 360.0 * round((centre_lon - (w + e) / 2) / 360.0)
    return {"type": geom["type"], "coordinates": _shift_coords(geom["coordinates"], d)}


def footprints(drg_dir: Path, exposures: Sequence[dict], centre_lon: float) -> dict:
    """FeatureCollection of the DRG footprints with key, file and exposure; empty when the DRGs are gone."""
    by_key = {r["key"]: r for r in exposures}
    feats = []
    if drg_dir.is_dir() and any(drg_dir.iterdir()):
        for info in catalog_drgs(drg_dir):
            geom = image_footprint(info, centre_lon)
            if geom is None:
                continue
            props = {"key": info.key, "file": info.path.name, **{k: v for k, v in by_key.get(info.key, {}).items() if k != "key"}}
            feats.append({"type": "Feature", "properties": props, "geometry": geom})
    return {"type": "FeatureCollection", "features": feats}
