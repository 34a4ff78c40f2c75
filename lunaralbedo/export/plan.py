"""The one plan of an export: the albedo tiles, their stretch, the data grid and its tile pyramid.

``export-kml`` and ``export-web`` draw the same pyramid with the same 8-bit albedo stretch;
both ask :func:`plan_export` for it and then only choose what each tile is written as
(KML + PNG, web map PNGs).  Steps, as dask tasks on the caller's executor:

1. one task per albedo tile samples its valid values and bounds (:func:`.extent.scan_tile`)
   -> the shared percentile stretch (``value_range`` replaces it);
2. the native grid cropped to the data extent (:mod:`.extent`; legacy results keep
   PhotometryTK's whole tiles);
3. the quadtree over that grid (:func:`.pyramid.plan_pyramid`), the tiles that hold data
   (:func:`.pyramid.present_nodes`), their written children and the finest level's resampling.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import dask
import numpy as np
from rasterio.enums import Resampling

from ..errors import InputError
from ..model.grid import Bounds, Grid
from .extent import clip, crop_grid, scan_tile, simulation_box, union
from .pyramid import Node, Pyramid, plan_pyramid, present_nodes
from .sources import Source, find_sources, native_grid
from .stretch import Stretch, stretch_from_range, stretch_from_values
from .tiling import compute_tasks, level_resampling, pyramid_children

SAMPLE_BUDGET = 20_000_000  # at most about this many albedo values enter the percentiles


def check_pixel_size(sources: Sequence[Source], folder: Path) -> None:
    """InputError unless all tiles of ``folder`` share one pixel size (degrees)."""
    rx, ry = sources[0].res
    for s in sources[1:]:
        if abs(s.res[0] - rx) > 1e-6 * rx or abs(s.res[1] - ry) > 1e-6 * ry:
            raise InputError(
                f"{folder}: tiles must share one pixel size; {sources[0].path.name} has {rx:g} x {ry:g} "
                f"degrees but {s.path.name} has {s.res[0]:g} x {s.res[1]:g}"
            )


def albedo_sources(results_dir: Path) -> list[Source]:
    """The albedo tiles of ``results_dir/albedo`` (InputError when there are none or they differ in pixel size)."""
    sources = find_sources(results_dir / "albedo", "albedo")
    check_pixel_size(sources, results_dir / "albedo")
    return sources


def scan_sources(sources: Sequence[Source], folder: Path, executor, percentiles=(2.0, 98.0), value_range=None,
                 what: str = "albedo"):
    """One task per tile: its valid-data bounds and a sample of its values -> ``(stretch, scans)``.

    The stretch is the one 8-bit stretch of all tiles: ``value_range`` when given, else the
    percentiles of the valid values (at most about :data:`SAMPLE_BUDGET` of them).
    ``scans`` are :func:`.extent.scan_tile`'s ``(values, bounds)`` per tile, in order.
    """
    budget = 0 if value_range is not None else max(10_000, SAMPLE_BUDGET // len(sources))  # values per tile
    scans = compute_tasks([dask.delayed(scan_tile, pure=False)(s, budget) for s in sources], executor)
    if all(b is None for _, b in scans):
        raise InputError(f"{folder}: the {what} tiles hold no valid pixel (all no-data); nothing to export")
    if value_range is not None:
        return stretch_from_range(*value_range), scans
    return stretch_from_values(np.concatenate([v for v, _ in scans]), tuple(percentiles)), scans


def data_grid(results_dir: Path, sources: Sequence[Source], scans) -> tuple[Grid, list[Source], tuple]:
    """The native grid cropped to the data extent (see :mod:`.extent`), the tiles holding data, the extent.

    Legacy (uint8 + alpha) results keep PhotometryTK's whole-tile bounds.
    """
    grid = native_grid(sources)
    if any(s.legacy for s in sources):
        return grid, list(sources), grid.bounds
    extent = union([b for _, b in scans if b is not None])
    box = simulation_box(results_dir, extent[0])
    if box is not None:
        extent = clip(extent, box) or extent
    grid = crop_grid(grid, extent)
    kept = [s for s, (_, b) in zip(sources, scans) if b is not None and clip(s.bounds, grid.bounds) is not None]
    return grid, kept, grid.bounds


@dataclass(frozen=True)
class ExportPlan:
    """What :func:`plan_export` decided: the same for every product drawn on the pyramid."""

    stretch: Stretch  #: the 8-bit albedo stretch of every tile
    grid: Grid  #: the native grid cropped to the data extent (degrees, continuous longitudes)
    sources: list[Source]  #: the albedo tiles that hold data inside ``grid``
    extent: Bounds  #: the data extent (west, south, east, north), degrees
    pyramid: Pyramid
    present: dict[int, list[Node]]  #: per level, the tiles that are written
    children: dict[tuple[int, int, int], list[Node]]  #: per written tile, its written children
    resampling: Resampling  #: of the finest level: nearest when it is at least as fine as ``grid``, else average


def plan_export(results_dir: Path, sources: Sequence[Source], executor, *, levels: int | None = None,
                tile_size: int = 256, stretch: tuple[float, float] = (2.0, 98.0),
                value_range: tuple[float, float] | None = None) -> ExportPlan:
    """The stretch, data grid and pyramid of the albedo ``sources`` of ``results_dir`` (module notes)."""
    st, scans = scan_sources(sources, results_dir / "albedo", executor, stretch, value_range)
    grid, kept, extent = data_grid(results_dir, sources, scans)
    pyr = plan_pyramid(grid.bounds, grid.shape, tile_size, levels)
    present = present_nodes(pyr, [clip(s.bounds, grid.bounds) for s in kept])
    return ExportPlan(st, grid, kept, extent, pyr, present, pyramid_children(pyr, present),
                      level_resampling(pyr, pyr.levels - 1, grid))
