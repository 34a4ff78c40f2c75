"""The scene of one solve: images, their positions and weight profiles, DEM files and tiles.

Building a scene reads only headers (and, for images with an alpha band or nodata,
the mask once, strip by strip, to get the compact weight profiles).  A scene is a
small picklable object that every tile task receives.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field

import numpy as np
import rasterio
from rasterio.windows import Window

from ..errors import InputError, SolverError
from ..io.guard import raster_errors
from ..io.positions import read_positions
from ..io.rasters import RasterInfo, catalog_drgs, geographic_crs, list_rasters, raster_info
from ..model.photometry import PhotometricModel
from ..model.weights import WeightProfile, merge_profiles, profile_from_mask
from ..runtime import Runtime
from ..settings import Settings
from .photometry import solver_model
from .tiles import Tile, make_tiles

#: Pixels of padding around each tile while solving (legacy: 5).
PAD = 5
_STRIP_ROWS = 512


@dataclass
class Scene:
    """Everything a tile task needs to know about the run (no pixels)."""

    settings: Settings
    images: list[RasterInfo]
    sun: np.ndarray  # (K, 3) km, body-fixed
    spacecraft: np.ndarray  # (K, 3) km, body-fixed
    profiles: list[WeightProfile]
    dems: list[RasterInfo]
    tiles: list[Tile]
    tile_images: list[np.ndarray]  # per tile: global indices of the images that overlap it
    skipped: dict[str, str] = field(default_factory=dict)  # key -> reason
    #: The photometric model bound to the files its settings name (:func:`.photometry.solver_model`):
    #: the one model the engine uses.  Not pickled: each process binds it again from the settings
    #: (once per process while the files are unchanged), so a Hapke parameter map is not shipped to workers.
    model: PhotometricModel = field(default=None, repr=False, compare=False)
    #: How the run uses the machine (memory budgets); changes no result, so not in :meth:`fingerprint`.
    runtime: Runtime = field(default_factory=Runtime, repr=False, compare=False)

    def __post_init__(self):
        if self.model is None:
            self.model = solver_model(self.settings)

    def __getstate__(self):
        return {**self.__dict__, "model": None}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.model = solver_model(self.settings)

    @property
    def keys(self) -> list[str]:
        return [im.key for im in self.images]

    @property
    def crs(self):
        """The tiles' CRS: geographic degrees of the first DRG's body (each DRG is reprojected to it)."""
        return geographic_crs(self.images[0].crs)

    def fingerprint(self) -> str:
        """Hash of what determines the results (settings, inputs, tiles) — guards ``--resume``."""
        h = hashlib.sha256()
        h.update(json.dumps(self.settings.to_dict(), sort_keys=True).encode())
        for im in self.images:
            st = im.path.stat()
            h.update(f"{im.key}|{im.path}|{st.st_size}|{st.st_mtime_ns}|{tuple(im.transform)}".encode())
        for d in self.dems:
            st = d.path.stat()
            h.update(f"{d.path}|{st.st_size}|{st.st_mtime_ns}".encode())
        h.update(np.ascontiguousarray(self.sun).tobytes() + np.ascontiguousarray(self.spacecraft).tobytes())
        return h.hexdigest()[:16]


def overlaps_per_box(boxes, queries) -> list[np.ndarray]:
    """Per query rectangle, the sorted indices of ``boxes`` overlapping it with positive area.

    Rectangles are ``(west, south, east, north)``, longitudes modulo 360° (a DRG at
    -180..-170 meets a tile at 180..190, as :func:`~lunaralbedo.io.rasters.intersects_lon`).
    A shapely STRtree finds the candidates in O((Q + B) log B) instead of testing every
    pair; the strict test of :func:`~lunaralbedo.io.rasters.intersects` (touching edges do
    not count) then filters them, so the answer is the same as the all-pairs loop.
    """
    import shapely

    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    q0 = np.asarray(queries, dtype=np.float64).reshape(-1, 4)
    if len(b) == 0 or len(q0) == 0:
        return [np.zeros(0, np.int32) for _ in range(len(q0))]
    shifts = np.array([0.0, -360.0, 360.0])
    q = np.concatenate([q0 + [s, 0.0, s, 0.0] for s in shifts])  # each query, also one turn west and east
    tree = shapely.STRtree(shapely.box(b[:, 0], b[:, 1], b[:, 2], b[:, 3]))
    qi, bi = tree.query(shapely.box(q[:, 0], q[:, 1], q[:, 2], q[:, 3]))
    keep = (b[bi, 0] < q[qi, 2]) & (q[qi, 0] < b[bi, 2]) & (b[bi, 1] < q[qi, 3]) & (q[qi, 1] < b[bi, 3])
    pairs = np.unique(np.stack([qi[keep] % len(q0), bi[keep]], axis=1), axis=0).reshape(-1, 2)
    qi, bi = pairs[:, 0], pairs[:, 1].astype(np.int32)
    return np.split(bi, np.searchsorted(qi, np.arange(1, len(q0))))


def weight_profile(info: RasterInfo) -> WeightProfile:
    """Weight profile of one DRG: valid = alpha band > 0 (if any) and value != nodata."""
    if not info.has_alpha and info.nodata is None:
        return WeightProfile.full(info.height, info.width)
    parts = []
    with raster_errors(info.path), rasterio.open(info.path) as ds:
        for r0 in range(0, info.height, _STRIP_ROWS):
            win = Window(0, r0, info.width, min(_STRIP_ROWS, info.height - r0))
            valid = ds.read(2, window=win) > 0 if info.has_alpha else None
            if info.nodata is not None:
                v = ds.read(1, window=win)
                ok = (v != info.nodata) & np.isfinite(v)
                valid = ok if valid is None else valid & ok
            parts.append((r0, profile_from_mask(valid)))
    return merge_profiles(parts, info.height, info.width)


def _positions(settings: Settings, images: list[RasterInfo], skip_missing: bool, skipped: dict):
    if not settings.needs_geometry:
        z = np.zeros((len(images), 3))
        return images, z, z.copy()
    sun_all = read_positions(settings.sun_position_file)
    sc_all = read_positions(settings.spacecraft_position_file)
    kept, sun, sc = [], [], []
    for im in images:
        for table, path in ((sun_all, settings.sun_position_file), (sc_all, settings.spacecraft_position_file)):
            if im.key not in table:
                if not skip_missing:
                    raise InputError(
                        f"{path}: no position line for image key {im.key!r} ({im.path}); "
                        "add it, or pass --skip-missing to leave such images out"
                    )
                skipped[im.key] = f"no position in {path.name}"
                break
        else:
            kept.append(im)
            sun.append(sun_all[im.key])
            sc.append(sc_all[im.key])
    return kept, np.array(sun).reshape(-1, 3), np.array(sc).reshape(-1, 3)


def build_scene(settings: Settings, skip_missing: bool = False, map_fn=map, runtime: Runtime | None = None) -> Scene:
    """Catalogue inputs, read positions, choose the tile grid and the images of every tile.

    ``map_fn`` maps :func:`weight_profile` over images (pass an executor's map to
    read masks in parallel).
    """
    images = catalog_drgs(settings.drg_dir)
    crs0 = geographic_crs(images[0].crs)
    skipped: dict[str, str] = {}
    # Legacy convention: the tile grid takes its pixel spacing from the first DRG.
    tiles = make_tiles(settings.simulation_box, settings.tile_size, images[0].lonlat_res, pad=PAD, exact=True)
    padded = [t.padded_bounds for t in tiles]
    for im, hits in zip(images, overlaps_per_box(padded, [im.lonlat_bounds for im in images])):
        if len(hits) == 0:
            skipped[im.key] = "overlaps no tile of SIMULATION_BOX"
    images = [im for im in images if im.key not in skipped]
    if not images:
        raise SolverError(f"{settings.drg_dir}: no DRG overlaps the tiles of SIMULATION_BOX {settings.simulation_box}")
    for im in images:
        if crs0 is not None and im.crs is not None and geographic_crs(im.crs) != crs0:
            raise InputError(f"{im.path}: its body/datum differs from the first DRG's ({images[0].path})")
    model = solver_model(settings)  # a model's own files (e.g. Hapke's parameters) fail here, before any tile work
    images, sun, sc = _positions(settings, images, skip_missing, skipped)
    if not images:
        raise SolverError("no DRG left after skipping images without positions")
    dems: list[RasterInfo] = []
    if settings.needs_geometry:
        dems = [raster_info(p) for p in list_rasters(settings.dem_dir, "DEM")]
    tile_images = overlaps_per_box([im.lonlat_bounds for im in images], padded)
    used = set(np.concatenate(tile_images).tolist()) if tile_images else set()
    for k, im in enumerate(images):
        if k not in used:
            skipped.setdefault(im.key, "overlaps no tile")
    profiles = list(map_fn(weight_profile, images))
    return Scene(settings, images, sun, sc, profiles, dems, tiles, tile_images, skipped, model, runtime or Runtime())
