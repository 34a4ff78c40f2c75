"""The data extent of a result: what the exported products cover (pure functions + one tile task).

Solver tiles are whole ``TILE_SIZE`` squares, but the data rarely fills them: the
exports cover the union of the *valid* albedo pixels, cut to ``SIMULATION_BOX``
(from ``report.json``) when that is smaller, snapped outward to whole native pixels.
Legacy (uint8 + alpha, PhotometryTK) results keep their whole-tile bounds.
Bounds are ``(west, south, east, north)`` in degrees, continuous longitudes (see
:mod:`.sources`).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np
import rasterio

from ..io.guard import raster_errors
from ..io.rasters import written_windows
from ..model.grid import Bounds, Grid
from .sources import Source, read_masked


def scan_tile(src: Source, max_values: int) -> tuple[np.ndarray, Bounds | None]:
    """Task: up to about ``max_values`` valid values of one tile (for the stretch; none with 0)
    and the bounds of its valid pixels (None when it holds none).

    The sample is every ``step``-th pixel of every ``step``-th row of the whole tile; the tile
    is read a written window at a time (:func:`~lunaralbedo.io.rasters.written_windows`), so a
    tile far bigger than its data costs what its data costs.
    """
    step = max(1, math.ceil(math.sqrt(src.width * src.height / max_values))) if max_values > 0 else 0
    r_lo = c_lo = math.inf
    r_hi = c_hi = -1
    samples = []
    with raster_errors(src.path), rasterio.open(src.path) as ds:
        for win in written_windows(ds):
            vals = read_masked(ds, win, src.legacy)
            ok = np.isfinite(vals)
            rows, cols = np.flatnonzero(ok.any(axis=1)), np.flatnonzero(ok.any(axis=0))
            if not rows.size:
                continue
            r0, c0 = int(win.row_off), int(win.col_off)
            r_lo, r_hi = min(r_lo, r0 + rows[0]), max(r_hi, r0 + rows[-1])
            c_lo, c_hi = min(c_lo, c0 + cols[0]), max(c_hi, c0 + cols[-1])
            if step:
                part = vals[(-r0) % step::step, (-c0) % step::step]
                samples.append(part[np.isfinite(part)])
    if r_hi < 0:
        return np.empty(0, np.float32), None
    t = src.shifted_transform
    west, north = t * (c_lo, r_lo)
    east, south = t * (c_hi + 1, r_hi + 1)
    sample = np.concatenate(samples) if samples else np.empty(0, np.float32)
    return sample, (west, max(south, -90.0), east, min(north, 90.0))


def union(bounds: Sequence[Bounds]) -> Bounds:
    b = np.array(bounds, dtype=np.float64)
    return (float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max()))


def simulation_box(results_dir: Path, near_west: float) -> Bounds | None:
    """SIMULATION_BOX of the run (``report.json``), shifted by 360° to the data's longitudes; None if unknown."""
    try:
        box = json.loads((Path(results_dir) / "report.json").read_text())["settings"]["simulation_box"]
        lon0, lon1, lat0, lat1 = (float(v) for v in box)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    shift = 360.0 * round((near_west - lon0) / 360.0) if lon1 - lon0 < 360.0 else 0.0
    return (lon0 + shift, lat0, lon1 + shift, lat1)


def crop_grid(grid: Grid, extent: Bounds) -> Grid:
    """The part of ``grid`` covering ``extent``, snapped outward to whole pixels of ``grid``."""
    w, s, e, n = grid.bounds
    rx, ry = (e - w) / grid.width, (n - s) / grid.height
    c0 = max(0, math.floor((extent[0] - w) / rx + 1e-6))
    c1 = min(grid.width, math.ceil((extent[2] - w) / rx - 1e-6))
    r0 = max(0, math.floor((n - extent[3]) / ry + 1e-6))
    r1 = min(grid.height, math.ceil((n - extent[1]) / ry - 1e-6))
    if c1 <= c0 or r1 <= r0:
        return grid
    return grid.window(c0, r0, c1 - c0, r1 - r0)


def clip(bounds: Bounds, extent: Bounds) -> Bounds | None:
    """``bounds`` cut to ``extent``; None when they do not overlap."""
    w, s, e, n = max(bounds[0], extent[0]), max(bounds[1], extent[1]), min(bounds[2], extent[2]), min(bounds[3], extent[3])
    return (w, s, e, n) if w < e and s < n else None
