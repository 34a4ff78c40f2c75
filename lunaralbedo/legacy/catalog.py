"""Legacy inputs: the DRG/DEM indexes, the image selection and the tile lists.

* Every ``*.tif`` of DRG_DIR is indexed in lexicographic order with its corners
  (centres of the first and last pixels, float32).  The legacy program cached
  this index as ``DRG_DIR/index.txt``; we never write into input folders and
  keep the cache in ``OUTDIR/cache/``.
* The images used are those whose corners overlap the SIMULATION_BOX (strict
  inequalities): ``imagesList.txt``.
* The tile grid takes its pixel size from the *first* DRG of the folder (even if
  that image is not selected) and covers every tile touched by a selected image.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, SolverError
from ..io.positions import lookup, read_positions
from ..io.rasters import lookup_keys
from ..settings import Settings
from .legacy_io import format_list_line, list_tifs, read_drg, read_header, write_lines
from .tilesolve import Image
from .vwgeo import LegacyTile, boxes_overlap, legacy_box, tiles_for_images
from .weights import center_lines


@dataclass
class Inputs:
    """Everything the passes read, gathered once."""

    images: list[Image]
    skipped: list[str]
    tiles: list[LegacyTile]
    ref_path: Path
    crs: object
    dems: list  # (heights, Geo, corners, nodata) per DEM file, in index order
    dem_nodata: float


def _index(files: list[Path]) -> list[tuple[Path, object]]:
    return [(p, read_header(p)) for p in files]


def gather(settings: Settings, kind: int, cache_dir: Path) -> Inputs:
    """Index the inputs, select the images, build the tile grid (reads headers and selected DRGs)."""
    drg_files = list_tifs(settings.drg_dir, "DRG")
    drg_index = _index(drg_files)
    write_lines(cache_dir / "drg_index.txt", [format_list_line(str(p), h.geo.corners()) for p, h in drg_index])
    box = legacy_box(settings.simulation_box)
    selected = []
    for (p, h), key in zip(drg_index, lookup_keys([p for p, _ in drg_index])):
        if boxes_overlap(h.geo.corners(), box):
            selected.append((p, h, key))
    skipped = [p.name for p, h in drg_index if not boxes_overlap(h.geo.corners(), box)]
    if not selected:
        raise SolverError(f"{settings.drg_dir}: no DRG overlaps SIMULATION_BOX {settings.simulation_box}")
    sun = sc = None
    if kind != 0:
        sun = read_positions(settings.sun_position_file)
        sc = read_positions(settings.spacecraft_position_file)
    images = []
    for p, h, key in selected:
        values, valid = read_drg(p)
        s = lookup(sun, key, settings.sun_position_file) if sun is not None else None
        c = lookup(sc, key, settings.spacecraft_position_file) if sc is not None else None
        images.append(Image(key, str(p), h.geo, values, valid, center_lines(valid), s, c))
    ref_path, ref = drg_index[0][0], drg_index[0][1]
    if ref.dtype != "uint8":
        raise InputError(f"{ref_path}: the legacy program requires uint8 DRG images, this one is {ref.dtype}")
    tiles = tiles_for_images([im.corners for im in images], settings.tile_size, ref.geo)
    dems, nodata = [], float(np.float32(settings.no_dem_data_val))
    if kind != 0:
        dems, nodata = _dems(settings, cache_dir)
    return Inputs(images, skipped, tiles, ref_path, ref.crs, dems, nodata)


def _dems(settings: Settings, cache_dir: Path):
    from .legacy_io import read_dem

    files = list_tifs(settings.dem_dir, "DEM")
    index = _index(files)
    write_lines(cache_dir / "dem_index.txt", [format_list_line(str(p), h.geo.corners()) for p, h in index])
    dems = []
    for p, h in index:
        heights, nd = read_dem(p, settings.no_dem_data_val)
        dems.append((heights, h.geo, h.geo.corners(), nd))
    return dems, dems[0][3] if dems else float(np.float32(settings.no_dem_data_val))


def write_lists(out: Path, label: str, inputs: Inputs) -> None:
    """``imagesList.txt``, ``tilesList.txt`` (blank tiles), ``DEMTilesList.txt``, ``albedoTilesList.txt``."""
    write_lines(out / "imagesList.txt", [format_list_line(im.path, im.corners) for im in inputs.images])
    for fname, sub in (("tilesList.txt", "blank_tiles"), ("DEMTilesList.txt", "DEM"), ("albedoTilesList.txt", "albedo")):
        write_lines(out / fname, [format_list_line(f"{label}/{sub}/{t.name}.tif", t.corners) for t in inputs.tiles])
