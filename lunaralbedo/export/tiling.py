"""Rendering a tile pyramid: one task per tile, shared by ``export-kml`` and ``export-web``.

The layout is :mod:`.pyramid` (a power-of-two quadtree over the data).  Each tile
of the finest level resamples the sources onto its grid; each coarser tile is the
2x2 block mean of its children (weighted by how many finest-level pixels each
child pixel stands for), so every level is the block mean of the finest one and
the sources are read once.  What is written for a tile (PNG + KML, PNG only, a
hillshade...) is the ``write`` callable: ``write(out_dir, node, children, values)``
with ``values`` float32, NaN = no data.  It must be picklable for the processes
scheduler (a module-level class or :func:`functools.partial`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

import warnings

import dask
import numpy as np
import rasterio
from rasterio.enums import ColorInterp, Resampling
from rasterio.errors import NotGeoreferencedWarning

from ..io.atomic import atomic_path
from .pyramid import Node, Pyramid
from ..model.grid import Grid
from .sources import Source, intersects, read_region

TileWriter = Callable[[Path, Node, Sequence[Node], np.ndarray], None]


#: zlib level of the pyramid's PNG tiles.  GDAL's default, 6, made the PNG writes ~45 % of an
#: export (50-image scene: 2152 tiles of 256 x 256 px, 13.4 ms each); 3 takes 5.0 ms for files
#: 4 % larger, 1 takes 3.5 ms for files 12 % larger (docs/performance-history.md, section 0g).
PNG_ZLEVEL = 3


def write_png(path: Path, rgba: np.ndarray, transform) -> None:
    """Write a (4, h, w) uint8 array as an RGBA PNG (zlib level :data:`PNG_ZLEVEL`), atomically.

    The georeferencing (given so that GDAL does not warn) would go to a
    ``.aux.xml`` sidecar, which is removed: the KML or the web map places the image.
    """
    with atomic_path(path) as tmp:
        profile = dict(driver="PNG", width=rgba.shape[2], height=rgba.shape[1], count=4, dtype="uint8", transform=transform,
                       zlevel=PNG_ZLEVEL)
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(rgba)
            dst.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]
        aux = tmp.with_name(tmp.name + ".aux.xml")
        if aux.exists():
            aux.unlink()


def render_leaf(
    out_dir: str | Path,
    node: Node,
    sources: Sequence[Source],
    write: TileWriter,
    resampling: Resampling = Resampling.nearest,
) -> tuple[np.ndarray, np.ndarray]:
    """Task for a tile of the finest level: resample the sources onto it and write it.

    ``nearest`` when the level is at least as fine as the sources (values copied,
    not blurred), ``average`` when ``--levels`` makes it coarser.  Returns
    ``(mean, count)`` for the parent: the values and how many finest-level pixels
    each one stands for (1 or 0).
    """
    values = read_region(sources, node.grid, resampling)
    write(Path(out_dir), node, [], values)
    return values, np.isfinite(values).astype(np.float32)


def render_parent(
    out_dir: str | Path,
    node: Node,
    children: Sequence[Node],
    child_results: Sequence[tuple[np.ndarray, np.ndarray]],
    write: TileWriter,
) -> tuple[np.ndarray, np.ndarray]:
    """Task for a tile of a coarser level: 2x2 means of its children's pixels, then written.

    Each pixel is the mean of the valid finest-level pixels below it (counts carry
    the weights), so every level is the block mean of the finest one.
    """
    values, counts = merge_children(node, children, child_results)
    write(Path(out_dir), node, children, values)
    return values, counts


def merge_children(
    node: Node, children: Sequence[Node], child_results: Sequence[tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray]:
    """(mean, count) of ``node`` from its children's (pure; missing children hold no data)."""
    total = np.zeros((2 * node.height, 2 * node.width), dtype=np.float64)
    count = np.zeros_like(total)
    r0, c0 = 2 * node.row, 2 * node.col
    for child, (vals, cnt) in zip(children, child_results):
        rs = 0 if child.row == r0 else total.shape[0] - child.height  # the first child is a full tile
        cs = 0 if child.col == c0 else total.shape[1] - child.width
        ok = cnt > 0
        total[rs:rs + child.height, cs:cs + child.width] = np.where(ok, vals, 0.0) * cnt
        count[rs:rs + child.height, cs:cs + child.width] = cnt
    total = total.reshape(node.height, 2, node.width, 2).sum(axis=(1, 3))
    count = count.reshape(node.height, 2, node.width, 2).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
    return mean.astype(np.float32), count.astype(np.float32)


def pyramid_children(pyr: Pyramid, present: dict[int, list[Node]]) -> dict[tuple[int, int, int], list[Node]]:
    """For every written tile, its written children."""
    keys = {n.key for nodes in present.values() for n in nodes}
    return {
        n.key: [pyr.node(*c) for c in pyr.children(n) if c in keys]
        for nodes in present.values()
        for n in nodes
    }


def level_resampling(pyr: Pyramid, level: int, grid: Grid) -> Resampling:
    """``nearest`` for a level at least as fine as the native grid, ``average`` for a coarser one."""
    height, width = pyr.level_shape(level)
    return Resampling.nearest if width >= grid.width and height >= grid.height else Resampling.average


def compute_tasks(tasks: list, executor) -> list:
    """Compute dask.delayed ``tasks`` on ``executor`` (:func:`lunaralbedo.parallel.make_executor`)."""
    if not tasks:
        return []
    with warnings.catch_warnings():
        # rasterio silences this warning for its in-memory arrays with catch_warnings,
        # which is not thread-safe: with threads it leaks out.
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        return executor.compute(tasks)


def covering(sources: Sequence[Source], bounds) -> list[Source]:
    """The sources that overlap ``bounds``."""
    return [s for s in sources if intersects(s.bounds, bounds)]


def pyramid_tasks(out_dir, plan, sources: Sequence[Source], write: TileWriter) -> list:
    """One dask task per written tile of ``plan`` (:class:`.plan.ExportPlan`): finest level from the
    sources, each coarser tile from its children.

    Returns ``[root task]``: every written tile is below the root, so computing the
    root computes all of them, and each tile's arrays are freed once its parent has used them.
    """
    pyr, present, children, resampling = plan.pyramid, plan.present, plan.children, plan.resampling
    task = dask.delayed(pure=False)
    done: dict = {}
    for level in range(pyr.levels - 1, -1, -1):
        for node in present[level]:
            if level == pyr.levels - 1:
                done[node.key] = task(render_leaf)(out_dir, node, covering(sources, node.bounds), write, resampling)
            else:
                kids = children[node.key]
                done[node.key] = task(render_parent)(out_dir, node, kids, [done[k.key] for k in kids], write)
    (root,) = present[0]
    return [done[root.key]]
