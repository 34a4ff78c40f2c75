"""The data files of the web map: script files (``*.js``) that a page loads with ``<script>``.

Browsers refuse ``fetch``/XHR of ``file://`` URLs, but load scripts; so every
datum is a script that assigns a global or calls a callback:

* ``data/meta.js``       ``LUNARALBEDO_META = {...}`` (pyramid, layers, stretches, tiles present);
* ``data/report.js``     ``LUNARALBEDO_REPORT = <report.json verbatim>``,
  ``LUNARALBEDO_EXPOSURES = [{key, exposure, initial_exposure}, ...]`` (``exposure.csv``) and
  ``LUNARALBEDO_TABLES = {haze: [{key, haze}, ...], image_offsets: [{key, east_m, north_m, east_se_m,
  north_se_m}, ...]}`` (``haze.csv``, ``image_offsets.csv``; empty lists when the run wrote none);
* ``data/footprints.js`` ``LUNARALBEDO_FOOTPRINTS = <GeoJSON FeatureCollection>``: per image,
  its valid pixels as polygons (lon/lat degrees, longitudes shifted like the tiles);
* ``data/values/<col>/<row>.js`` ``LUNARALBEDO_VALUES(col, row, {...})``: albedo and error (and, when the
  run wrote them, the outliers' lost weight fraction and the DEM's height change) of one finest-level tile
  as little-endian float32, base64 (NaN = no data), loaded on click.
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


def read_key_table(path: Path, columns: Sequence[str]) -> list[dict]:
    """Rows of a ``key,...`` CSV table of the results (``exposure.csv``, ``haze.csv``, ``image_offsets.csv``):
    ``key`` as text, every other cell a float (an empty cell, a value not determined: None); [] when the file
    is absent.  :class:`InputError` naming the file when a row lacks one of ``columns`` or a cell is not a number.
    """
    if not path.is_file():
        return []
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    out = []
    for r in rows:
        try:
            if any(r[c] is None for c in columns):
                raise KeyError
            out.append({"key": r["key"], **{k: float(v) if v.strip() else None for k, v in r.items() if k != "key"}})
        except (KeyError, ValueError, AttributeError):
            raise InputError(f"{path}: not a table of {','.join(columns)}") from None
    return out


def read_exposures(path: Path) -> list[dict]:
    """Rows of ``exposure.csv`` (numbers as floats); [] when the file is absent."""
    return read_key_table(path, ("key", "exposure", "initial_exposure"))


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


def image_footprint(info: RasterInfo, centre_lon: float, offset_m: tuple[float, float] | None = None) -> dict | None:
    """GeoJSON MultiPolygon (lon/lat degrees) of the valid pixels of one DRG, or None when it has none.

    The mask is read at most :data:`FOOTPRINT_SIDE` pixels a side (nearest), so edges are
    exact to one such pixel; longitudes are shifted by a multiple of 360 deg to lie nearest ``centre_lon``.
    ``offset_m`` (metres east, north; ``image_offsets.csv`` of ``REGISTER_IMAGES 1``) moves the
    georeference as the solver moved the image (:func:`lunaralbedo.engine.offsets.shifted_scene`).
    """
    scale = max(1.0, max(info.width, info.height) / FOOTPRINT_SIDE)
    shape = (max(1, math.ceil(info.height / scale)), max(1, math.ceil(info.width / scale)))
    with rasterio.open(info.path) as ds:
        ok = _valid_mask(ds, shape)
    if not ok.any():
        return None
    transform = info.transform
    if offset_m is not None:
        from ..engine.offsets import metres_to_map

        dx, dy = metres_to_map(info) @ np.asarray(offset_m, float)
        transform = Affine.translation(dx, dy) @ transform
    transform = transform @ Affine.scale(info.width / shape[1], info.height / shape[0])
    polys = [geom["coordinates"] for geom, _ in features.shapes(ok.astype(np.uint8), mask=ok, transform=transform)]
    geom = {"type": "MultiPolygon", "coordinates": polys}
    if info.crs is not None and not info.crs.is_geographic:
        geom = transform_geom(info.crs, geographic_crs(info.crs), geom)
    w, _, e, _ = info.lonlat_bounds
    d = 360.0 * round((centre_lon - (w + e) / 2) / 360.0)
    return {"type": geom["type"], "coordinates": _shift_coords(geom["coordinates"], d)}


def footprints(drg_dir: Path, exposures: Sequence[dict], centre_lon: float, offsets: Sequence[dict] = ()) -> dict:
    """FeatureCollection of the DRG footprints with key, file, exposure (and the image's offset, where the
    footprint is drawn moved by it: ``offsets`` are ``image_offsets.csv``'s rows); empty when the DRGs are gone."""
    by_key = {r["key"]: r for r in exposures}
    moved = {r["key"]: r for r in offsets}
    feats = []
    if drg_dir.is_dir() and any(drg_dir.iterdir()):
        for info in catalog_drgs(drg_dir):
            off = moved.get(info.key)
            geom = image_footprint(info, centre_lon, None if off is None else (off["east_m"], off["north_m"]))
            if geom is None:
                continue
            props = {"key": info.key, "file": info.path.name, **{k: v for k, v in by_key.get(info.key, {}).items() if k != "key"}}
            if off is not None:
                props.update(east_m=off["east_m"], north_m=off["north_m"])
            feats.append({"type": "Feature", "properties": props, "geometry": geom})
    return {"type": "FeatureCollection", "features": feats}
