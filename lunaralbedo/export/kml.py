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


def render_node(
    out_dir: str | Path,
    node: Node,
    children: Sequence[Node],
    sources: Sequence[Source],
    stretch: Stretch,
    name: str = "albedo",
    resampling: Resampling = Resampling.average,
) -> dict:
    """One task of the pyramid: resample the albedo onto the tile, write its PNG and KML.

    Independent of every other tile (each level is read from the albedo tiles
    directly), so all tiles of all levels can run at once.  Levels at about the
    native resolution use ``nearest`` (values are copied, not blurred), coarser
    levels ``average`` (each PNG pixel is the mean of the albedo pixels it covers).
    """
    out_dir = Path(out_dir)
    values = read_region(sources, node.grid, resampling)
    write_png(out_dir / png_relpath(*node.key), to_rgba(values, stretch), node.grid.transform)
    atomic_write_text(out_dir / kml_relpath(*node.key), node_kml(node, children, name))
    return {"key": node.key, "valid": int(np.isfinite(values).sum())}


def pyramid_children(pyr: Pyramid, present: dict[int, list[Node]]) -> dict[tuple[int, int, int], list[Node]]:
    """For every written tile, its written children."""
    keys = {n.key for nodes in present.values() for n in nodes}
    return {
        n.key: [pyr.node(*c) for c in pyr.children(n) if c in keys]
        for nodes in present.values()
        for n in nodes
    }
