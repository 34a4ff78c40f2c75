"""The response pass of ``solve --response estimate``: sampled real observations of every tile for the camera-response
fit (:mod:`lunaralbedo.response`), each tile read over its images' footprint (:func:`.observations.footprint`)."""
from __future__ import annotations

import numpy as np
from rasterio.enums import Resampling

from ..constants import MIN_COS_INCIDENCE_MODEL
from ..io.drgs import read_drg_onto_grid
from ..model import geometry, shadows
from ..response.model import Observations
from .observations import footprint, tile_geometry
from .scene import Scene

#: Observations per tile handed to the camera-response fit (a fixed stride over pixels beyond it).
MAX_PIXELS_PER_TILE = 40_000


def response_tile(t: int, *, scene: Scene, max_pixels: int = MAX_PIXELS_PER_TILE) -> dict:
    """Real observations of tile ``t`` (over its :func:`footprint`): flat pixel index, image index, DN, reflectance R
    (Kim et al., eq. 6)."""
    s = scene.settings
    tile = scene.tiles[t].part(footprint(scene, t))
    shape = (tile.height, tile.width)
    geo = tile_geometry(scene, tile) if s.needs_geometry else None
    thresh = s.shadow_thresh if s.shadow_type == shadows.THRESHOLD else None
    step = max(1, int(np.ceil(tile.height * tile.width / max_pixels)))
    pick = np.arange(0, tile.height * tile.width, step)
    where = {}
    if scene.model.needs_location:  # a model with per-point parameters (a Hapke parameter map) needs the ground points
        lon, lat = geometry.lonlat_axes(tile.transform, shape)
        where = dict(lon=np.broadcast_to(lon[None, :], shape), lat=np.broadcast_to(lat[:, None], shape))
    out = {k: [] for k in ("pixel", "image", "dn", "factor")}
    for k in scene.tile_images[t]:
        got = read_drg_onto_grid(scene.images[k], scene.profiles[k], tile.transform, shape, scene.crs, thresh,
                                 resampling=Resampling.nearest)
        if got is None:
            continue
        val, ok, _, use = got
        use = use & (val > 0)
        r = np.ones(shape, np.float32)
        if geo is not None:
            _, pts, normals, bad = geo
            ci, ce, al = geometry.illumination(pts, normals, scene.sun[k], scene.spacecraft[k])
            use &= ~bad & (ci >= MIN_COS_INCIDENCE_MODEL) & (ce > 0)
            r = scene.model.reflectance(ci, ce, al, s.initial_params, **where)
            use &= r > 0
        sel = pick[use.ravel()[pick]]
        out["pixel"].append(sel)
        out["image"].append(np.full(len(sel), k, np.int32))
        out["dn"].append(np.rint(val.ravel()[sel]).astype(np.int16))
        out["factor"].append(np.asarray(r, np.float32).ravel()[sel])
    return {name: (np.concatenate(v) if v else np.zeros(0)) for name, v in out.items()} | {"n_pixels": tile.height * tile.width}


def _response_reduce(scene: Scene, parts: list[dict]) -> Observations:
    base, cols = 0, {k: [] for k in ("pixel", "image", "dn", "factor")}
    for p in parts:  # fixed tile order
        cols["pixel"].append(p["pixel"].astype(np.int64) + base)
        for k in ("image", "dn", "factor"):
            cols[k].append(p[k])
        base += p["n_pixels"]
    c = {k: np.concatenate(v) for k, v in cols.items()}
    return Observations(c["pixel"], c["image"].astype(np.int32), c["dn"].astype(np.int64), base, len(scene.images),
                        c["factor"].astype(np.float64))


def response_observations(scene: Scene, executor) -> Observations:
    """The response pass: :func:`response_tile` over every tile, concatenated in tile order."""
    parts = executor.map(response_tile, list(range(len(scene.tiles))), "response", shared=("scene",), scene=scene)
    return _response_reduce(scene, parts)
