"""The legacy output tree: file names, text formats and the uint8 tile conventions.

Text formats (C ``printf``): exposure ``%f``, phase coefficients ``%f %f``,
per-tile phase sums ``%.16g`` x 4, cost function ``%0.16g``, weights ``%d ``.
Albedo tiles are uint8 gray + alpha; values are truncated (not rounded) after
clamping to 0..255, as the legacy ``channel_cast<uint8>`` did.  Error tiles are
``error / 10`` in the same format.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .legacy_io import write_float_tile, write_lines, write_uint8_tile
from .tilesolve import Image, TileResult
from .vwgeo import LegacyTile


def fmt_phase(c1: float, c2: float) -> str:
    return f"{c1:f} {c2:f}"


def fmt_cost(v: float) -> str:
    return f"{v:.16g}"


def reread_float(v: float) -> float:
    """A value as the legacy program read it back from its ``%f`` text file (float32)."""
    return float(np.float32(float(f"{v:f}")))


def append_line(path: Path, line: str) -> None:
    """Append one line (the legacy files grew by one line per pass); rewritten atomically."""
    path = Path(path)
    old = path.read_text() if path.exists() else ""
    write_lines(path, (old.splitlines() if old else []) + [line])


def write_blank(out: Path, tile: LegacyTile, crs) -> None:
    """``blank_tiles/<tile>.tif``: the empty padded template (uint8, alpha 0)."""
    shape = (tile.geo.height, tile.geo.width)
    write_uint8_tile(out / "blank_tiles" / f"{tile.name}.tif", np.zeros(shape), np.zeros(shape, bool), tile.geo, crs)


def write_weights(out: Path, image: Image) -> None:
    write_lines(out / "weight" / f"{image.key}_weight.txt", image.lines.to_lines())


def write_dem(out: Path, tile: LegacyTile, dem: np.ndarray, nodata: float, crs) -> None:
    write_float_tile(out / "DEM" / f"{tile.name}.tif", dem, tile.geo, crs, nodata=nodata)


def write_weights_sum(out: Path, tile: LegacyTile, wsum: np.ndarray, crs) -> None:
    write_float_tile(out / "weightsSum" / f"{tile.name}.tif", wsum, tile.geo, crs)


def write_phase_tile(out: Path, tile: LegacyTile, pcd) -> tuple[float, float, float, float]:
    """``phase/<tile>.txt`` (overwritten each iteration); returns the values as re-read."""
    line = " ".join(f"{v:.16g}" for v in pcd)
    write_lines(out / "phase" / f"{tile.name}.txt", [line])
    return tuple(float(v) for v in line.split())


def to_uint8(value: np.ndarray) -> np.ndarray:
    """Legacy ``channel_cast<uint8>(clamp(v, 0, 255))``: clamp, then truncate."""
    v = np.nan_to_num(np.asarray(value, dtype=np.float64), nan=0.0)
    return np.trunc(np.clip(v, 0.0, 255.0)).astype(np.uint8)


def read_albedo(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """An albedo tile as the legacy program re-read it: ``(values float32, valid)``; None if absent."""
    import rasterio

    path = Path(path)
    if not path.exists():
        return None
    with rasterio.open(path) as ds:
        data = ds.read()
    return data[0].astype(np.float32), (data[1] != 0) if data.shape[0] > 1 else np.ones(data[0].shape, bool)


def write_albedo(out: Path, tile: LegacyTile, res: TileResult, last: bool, c2: float, crs, scale: bool = True) -> bool:
    """Write ``albedo/<tile>.tif`` (and ``error/`` after the error pass); False if the tile is empty.

    On the last pass the albedo is multiplied by ``1 + c2`` (float32; only when a
    reflectance model is used, ``scale``) and the padding is cropped.  A tile
    whose values are all <= 0 is not written; on the last pass an older file is
    removed, before it an older file stays (legacy behaviour).
    """
    value, valid, geo = res.value, res.valid, tile.geo
    err, err_valid = res.error, res.error_valid
    if last and scale:
        factor = np.float32(1) + np.float32(c2)
        value = np.where(valid, (value.astype(np.float64) * float(factor)).astype(np.float32), value)
    if last:
        c0, r0, nc, nr = tile.crop_window
        sl = (slice(r0, r0 + nr), slice(c0, c0 + nc))
        value, valid, geo = value[sl], valid[sl], geo.window(c0, r0, nc, nr)
        if err is not None:
            err, err_valid = err[sl], err_valid[sl]
    if not np.any(value > 0):
        if last:
            (out / "albedo" / f"{tile.name}.tif").unlink(missing_ok=True)
        return False
    write_uint8_tile(out / "albedo" / f"{tile.name}.tif", to_uint8(value), valid, geo, crs)
    if err is not None:
        write_uint8_tile(out / "error" / f"{tile.name}.tif", to_uint8(err.astype(np.float64) / 10.0), err_valid, geo, crs)
    return True


def to_json(summary: dict) -> str:
    return json.dumps(summary, indent=2, default=float) + "\n"
