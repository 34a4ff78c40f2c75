"""KML superoverlay documents (simplekml) and the KML tile writer (rendering: :mod:`.tiling`).

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
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import simplekml

from ..constants import MOON_RADIUS_M
from ..io.atomic import atomic_write_text
from .pyramid import Node
from .stretch import Stretch, to_rgba
from .tiling import write_png

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


@dataclass(frozen=True)
class KmlTileWriter:
    """The tile writer of the KML pyramid: the RGBA PNG of the stretched values and the tile's KML."""

    stretch: Stretch
    name: str = "albedo"

    def __call__(self, out_dir: Path, node: Node, children: Sequence[Node], values: np.ndarray) -> None:
        write_png(out_dir / png_relpath(*node.key), to_rgba(values, self.stretch), node.grid.transform)
        atomic_write_text(out_dir / kml_relpath(*node.key), node_kml(node, children, self.name))
