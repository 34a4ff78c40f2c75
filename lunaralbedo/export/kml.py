"""KML superoverlay documents (simplekml) and the per-tile render task.

Files below ``RESULTS_DIR/kml/``::

    doc.kml                 level 0 (root): Region + GroundOverlay 0/0/0.png + links to level 1
    <level>/<col>/<row>.kml  one tile: Region + GroundOverlay <row>.png + links to its children
    <level>/<col>/<row>.png  RGBA, gray = stretched albedo, alpha 0 outside the data
    stretch.json            the stretch shared by every PNG

Each document carries ``hint="target=moon"`` so Google Earth opens it on the Moon.
Regions use ``minLodPixels=128`` (0 for the root) and ``maxLodPixels=-1``; finer
levels draw on top (``drawOrder`` = level).
"""
from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Sequence

import numpy as np
import rasterio
import simplekml
from rasterio.enums import Resampling

from ..constants import MOON_RADIUS_M
from ..io.atomic import atomic_path, atomic_write_text
from .pyramid import Node, Pyramid
from .sources import Source, read_region
from .stretch import Stretch, to_rgba

ROOT_NAME = "doc.kml"
MIN_LOD_PIXELS = 128
_SIMPLEKML_LOCK = threading.Lock()  # simplekml numbers ids with a global counter


def kml_relpath(level: int, col: int, row: int) -> str:
    """Path of a tile's KML below ``kml/`` (the root is ``doc.kml``)."""
    return ROOT_NAME if level == 0 else f"{level}/{col}/{row}.kml"


def png_relpath(level: int, col: int, row: int) -> str:
    return f"{level}/{col}/{row}.png"


def _region(bounds, min_lod: int) -> simplekml.Region:
    w, s, e, n = bounds
    return simplekml.Region(
        simplekml.LatLonAltBox(north=n, south=s, east=e, west=w),
        simplekml.Lod(minlodpixels=min_lod, maxlodpixels=-1),
    )


def node_kml(node: Node, children: Sequence[Node], name: str = "albedo") -> str:
    """The KML text of one tile (deterministic: ids restart at 0 in every document)."""
    root = node.level == 0
    w, s, e, n = node.bounds
    with _SIMPLEKML_LOCK:
        simplekml.Kml.resetidcounter()
        kml = simplekml.Kml(name=name if root else f"{node.level}/{node.col}/{node.row}")
        kml.hint = "target=moon"
        doc = kml.document
        doc.region = _region(node.bounds, 0 if root else MIN_LOD_PIXELS)
        if root:
            doc.lookat = simplekml.LookAt(
                longitude=(w + e) / 2,
                latitude=(s + n) / 2,
                range=max(e - w, n - s) * math.pi / 180 * MOON_RADIUS_M * 1.5,
            )
        ov = doc.newgroundoverlay(name=png_relpath(*node.key))
        ov.draworder = node.level
        ov.icon.href = png_relpath(*node.key) if root else f"{node.row}.png"
        ov.latlonbox.north, ov.latlonbox.south, ov.latlonbox.east, ov.latlonbox.west = n, s, e, w
        for child in children:
            link = doc.newnetworklink(name=f"{child.level}/{child.col}/{child.row}")
            link.region = _region(child.bounds, MIN_LOD_PIXELS)
            rel = kml_relpath(*child.key)
            link.link.href = rel if root else f"../../{rel}"
            link.link.viewrefreshmode = simplekml.ViewRefreshMode.onregion
        return kml.kml()


def write_png(path: Path, rgba: np.ndarray, transform) -> None:
    """Write a (4, h, w) uint8 array as an RGBA PNG, atomically.

    The georeferencing (given so that GDAL does not warn) would go to a
    ``.aux.xml`` sidecar, which is removed: the KML places the image.
    """
    with atomic_path(path) as tmp:
        profile = dict(driver="PNG", width=rgba.shape[2], height=rgba.shape[1], count=4, dtype="uint8", transform=transform)
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(rgba)
            dst.colorinterp = [
                rasterio.enums.ColorInterp.red,
                rasterio.enums.ColorInterp.green,
                rasterio.enums.ColorInterp.blue,
                rasterio.enums.ColorInterp.alpha,
            ]
        aux = tmp.with_name(tmp.name + ".aux.xml")
        if aux.exists():
            aux.unlink()


def _write_node(out_dir: Path, node: Node, children: Sequence[Node], values: np.ndarray, stretch: Stretch, name: str) -> None:
    write_png(out_dir / png_relpath(*node.key), to_rgba(values, stretch), node.grid.transform)
    atomic_write_text(out_dir / kml_relpath(*node.key), node_kml(node, children, name))


def render_leaf(
    out_dir: str | Path,
    node: Node,
    sources: Sequence[Source],
    stretch: Stretch,
    name: str = "albedo",
    resampling: Resampling = Resampling.nearest,
) -> tuple[np.ndarray, np.ndarray]:
    """Task for a tile of the finest level: resample the albedo onto it, write its PNG and KML.

    ``nearest`` when the level is at least as fine as the albedo (values copied,
    not blurred), ``average`` when ``--levels`` makes it coarser.  Returns
    ``(mean, count)`` for the parent: the values and how many finest-level pixels
    each one stands for (1 or 0).
    """
    values = read_region(sources, node.grid, resampling)
    _write_node(Path(out_dir), node, [], values, stretch, name)
    return values, np.isfinite(values).astype(np.float32)


def render_parent(
    out_dir: str | Path,
    node: Node,
    children: Sequence[Node],
    child_results: Sequence[tuple[np.ndarray, np.ndarray]],
    stretch: Stretch,
    name: str = "albedo",
) -> tuple[np.ndarray, np.ndarray]:
    """Task for a tile of a coarser level: 2x2 means of its children's pixels, PNG and KML.

    Each pixel is the mean of the valid finest-level pixels below it (counts carry
    the weights), so every level is the block mean of the finest one.
    """
    values, counts = merge_children(node, children, child_results)
    _write_node(Path(out_dir), node, children, values, stretch, name)
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
