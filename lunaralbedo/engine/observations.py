"""Compact observations of one tile: only the pixels where an image has weight, block of rows by block.

The former layout held every image's stack over the whole tile, so a narrow strip
(Apollo Metric, NAC) over a 2000 x 2000 px tile was mostly zeros, and every
iteration streamed those zeros from disk.  Here each image is read, and its
geometry computed, only over its own footprint window inside the tile (plus one
pixel), and only observations with positive weight are kept, as 1-D arrays ordered
by image and then by pixel:

* ``pix`` (int32): flat index ``row * width + col`` into the block (rows ``b0:b1`` of the unpadded tile);
* ``image``, ``weight`` and the photometric model's layers (float32);
* ``index`` (global image ids) and ``start`` (offsets: image ``k`` owns
  ``start[k]:start[k+1]``).

Per block pixel: ``dem`` (float32, every column of the tile) and, over the columns
``cols = (c0, c1)`` that the block's image windows span (none in a block no image meets),
``weights_sum`` (the sum of the blending weights, added in float64 and kept in float32, the
type of the ``weightsSum`` output, which is 0 in the other columns; without
NORMALIZED_COST_FUN also the denominator of eq. 7, whose error tiles are float32), and with
it ``wblend_sum`` (eq. 7's denominator of the normalised weights, likewise).  Memory is
~20-28 bytes per observation plus ~8 bytes per pixel of the block; per-pixel arrays were
half the cache of the strip of docs/performance-history.md with float64 sums (section 0f),
and over whole rows 96 of its 361 MB (its windows span half of its tiles' columns: now 48 of 313).

**Blocks of rows** bound the memory of a worker whatever TILE_SIZE and the number of
images: a tile is processed in blocks of :func:`block_rows` rows, each with the one-row
halo its normals need, and each
block's observations are cached on their own (``prepare.prepare_tile``).  The block
height follows from a budget, :data:`BLOCK_BYTES` (environment variable
``Runtime.block_mb``, default 384 MiB per worker; ``Runtime.block_rows`` forces
a height) and the measured bytes per pixel below: a tile that fits is one block.  Blocks
give the observations and per-pixel arrays of one whole-tile block; only sums that cross
blocks are added in another order (float64 rounding, ``tests/test_scale.py``).  Besides
the block, a worker holds the cast-shadow DEM (4 bytes per pixel with its margin) of the tile,
or of the block's band of rows when the tile's would exceed ``terrain.WHOLE_DEM_BYTES``
(:class:`~.terrain.TileShadows`); the tile outputs are written a block of rows at a time
(:class:`~lunaralbedo.io.geotiff.GeoTiffRows`), so no whole-tile raster is held: the memory
follows the block whatever the tile size (docs/performance.md), and a tile far bigger than its
images is gone through over their footprint only (:func:`footprint`), so that its time follows them too.
"""
from __future__ import annotations


import numpy as np
from numba import njit

from ..constants import MIN_COS_INCIDENCE_MODEL, MOON_RADIUS_KM
from ..io.drgs import pixels_on_grid, read_drg_onto_grid
from ..io.geotiff import BLOCK as OUTPUT_BLOCK
from ..io.rasters import read_dem_onto_grid
from ..model import geometry, shadows
from ..model.longitude import overlap_shifts
from ..parallel.ahead import ahead, helper
from ..runtime import BLOCK_MB
from .scene import Scene
from .terrain import FIRST_MARGIN_PX, WHOLE_DEM_BYTES, TileShadows

#: Default working memory of one block of a tile in the prepare and iterate steps (bytes); ``Runtime.block_mb`` sets it.
BLOCK_BYTES = int(BLOCK_MB * 2**20)
#: Bytes per pixel of a block's full width: DEM (and its reader's temporaries), per-pixel sums ...
#: (measured when the block also held its points and normals, 48 bytes per pixel, which are now computed
#: row by row in :func:`geometry.observe_window`; 48 here made 4000 px tiles' blocks taller and raised
#: make bench item 10's peak from 852 to 887 MB for no time gained, so the margin stays)
ROW_PIXEL_BYTES = 96
#: ... per pixel of every image window in the block: the kept observations (~20 bytes), the window's
#: blending weights, the initialisation sums' and the iteration's temporaries ...
WINDOW_PIXEL_BYTES = 56
#: ... and per pixel of the largest window: one image's bands, blending-weight tents (float64),
#: geometry and model layers, one image at a time ...
READ_PIXEL_BYTES = 200
#: ... and per pixel of the largest window for each more window read and reduced at once on
#: helper threads (``gather_blocks(helpers=...)``): most of a window's 200 bytes are temporaries,
#: and the windows in flight seldom all peak together (counting 200 bytes for each made the
#: 50-image scene's blocks a third shorter and its iterations 2 s slower, for item 10's peak
#: within its spread).
AHEAD_PIXEL_BYTES = 48


def image_window(tile, bounds) -> tuple[int, int, int, int] | None:
    """``(r0, r1, c0, c1)`` of the unpadded tile covering lon/lat ``bounds`` plus one pixel; None if empty.

    Longitudes count modulo 360° (a DRG stored at -180..-179 covers a tile at 180..181);
    a DRG meeting the tile on both sides of it gets the window spanning both.
    """
    shifts = overlap_shifts(bounds, tile.padded_bounds) or [0.0]
    west, south, east, north = bounds
    return tile.grid.pixel_box((west + min(shifts), south, east + max(shifts), north), margin=1)


def tile_windows(scene: Scene, t: int, tile=None) -> list[tuple[int, tuple[int, int, int, int] | None]]:
    """``(k, window)`` of every image of tile ``t``: :func:`image_window`, cut to the DRG's own pixels when it lies
    on the tile's grid (:func:`~lunaralbedo.io.drgs.pixels_on_grid`; read pixel for pixel, no pixel beyond them is
    valid, so the reads need not pad the window with empty pixels); None where nothing is left.  ``tile``: the part
    of tile ``t`` worked on (:meth:`~.tiles.Tile.part`; default the whole tile), whose pixels the windows count."""
    tile = scene.tiles[t] if tile is None else tile
    out = []
    for k in map(int, scene.tile_images[t]):
        win = image_window(tile, scene.images[k].lonlat_bounds)
        box = pixels_on_grid(scene.images[k], tile.transform, (tile.height, tile.width), scene.crs) if win else None
        if box is not None:
            win = (max(win[0], box[0]), min(win[1], box[1]), max(win[2], box[2]), min(win[3], box[3]))
            win = win if win[1] > win[0] and win[3] > win[2] else None
        out.append((k, win))
    return out


def block_budget(scene: Scene) -> float:
    """Bytes of a block's working memory: the run's ``Runtime.block_mb`` (default :data:`BLOCK_BYTES`)."""
    return scene.runtime.block_bytes


#: A tile whose DEM (float32, with the first cast-shadow margin) exceeds this is gone through over its images'
#: footprint only (:func:`footprint`): the size from which its cast-shadow DEM is read in bands
#: (:data:`~.terrain.WHOLE_DEM_BYTES`); smaller tiles are gone through whole, as ever.
FOOTPRINT_TILE_BYTES = WHOLE_DEM_BYTES


def footprint(scene: Scene, t: int) -> tuple[int, int, int, int]:
    """``(r0, r1, c0, c1)``: the rows and columns of tile ``t`` that the prepare step goes through.

    The whole tile when its DEM (float32, with the first cast-shadow margin) fits
    :data:`FOOTPRINT_TILE_BYTES` (~5700 x 5700 px).  A bigger tile, which a TILE_SIZE many times its
    images' extent gives (1 m/px NAC strips in a 4-degree tile: 121 000 x 121 000 px), is worked on only over
    the bounding box of its images' windows, widened to whole :data:`~lunaralbedo.io.geotiff.BLOCK`-px blocks
    of the tile outputs (``(0, 0, 0, 0)`` when no image reaches it): its terrain, geometry and cast-shadow DEM
    are read there (with the shadow margin), and the rest of the tile, where no image has a pixel, keeps the
    outputs' fill values (no-data albedo, error and DEM, zero weight sums) without being computed or read.
    The cost then follows the images' footprint, not the tile's area (docs/scaling.md).
    """
    tile = scene.tiles[t]
    h, w = tile.height, tile.width
    side = 2 * FIRST_MARGIN_PX
    if (h + side) * (w + side) * 4 <= FOOTPRINT_TILE_BYTES:
        return 0, h, 0, w
    wins = [win for _, win in tile_windows(scene, t) if win is not None]
    if not wins:
        return 0, 0, 0, 0
    b = OUTPUT_BLOCK
    r0, c0 = min(x[0] for x in wins) // b * b, min(x[2] for x in wins) // b * b
    r1, c1 = min(h, -(-max(x[1] for x in wins) // b) * b), min(w, -(-max(x[3] for x in wins) // b) * b)
    return r0, r1, c0, c1


def block_rows(scene: Scene, t: int, ahead: int = 0, tile=None) -> int:
    """Rows per block of tile ``t``: the most that fit :data:`BLOCK_BYTES` (see module docstring), with
    ``ahead`` more windows of the largest width being read and reduced at once (helper threads); a tile cut
    into blocks gets a multiple of the tile outputs' 256-row blocks when that many fit (each block of the
    GeoTIFFs is then compressed and written once: :mod:`lunaralbedo.io.geotiff`).  ``tile``: the part of the
    tile worked on (:meth:`~.tiles.Tile.part`; default the whole tile)."""
    forced = scene.runtime.block_rows
    tile = scene.tiles[t] if tile is None else tile
    if forced:
        return max(1, min(tile.height, int(forced)))
    budget = block_budget(scene)
    widths = [win[3] - win[2] for _, win in tile_windows(scene, t, tile) if win is not None]
    per_row = ((tile.width + 2) * ROW_PIXEL_BYTES + sum(widths) * WINDOW_PIXEL_BYTES
               + max(widths, default=0) * (READ_PIXEL_BYTES + AHEAD_PIXEL_BYTES * ahead))
    rows = max(1, min(tile.height, int(budget // per_row)))
    if rows < tile.height and rows >= OUTPUT_BLOCK:  # whole rows of the tile outputs' blocks: each written once
        rows -= rows % OUTPUT_BLOCK
    return rows


def row_blocks(height: int, rows: int) -> list[tuple[int, int]]:
    """``(b0, b1)`` row ranges of blocks of ``rows`` rows covering ``height`` rows."""
    return [(b0, min(b0 + rows, height)) for b0 in range(0, height, rows)]


class BlockGeometry:
    """DEM of rows ``b0:b1`` of the unpadded tile with its one-pixel halo, and the cosines and sines of the
    longitudes of its columns ``c0:c1`` (those the images cover, plus the halo) and of the latitudes of its rows:
    what :func:`geometry.observe_window` computes points and normals from (the DEM is read for every column: it
    is a tile output)."""

    def __init__(self, scene: Scene, tile, b0: int, b1: int, c0: int = 0, c1: int | None = None, shadows=None):
        s = scene.settings
        c1 = tile.width if c1 is None else c1
        transform = tile.transform @ tile.transform.translation(-1, b0 - 1)
        shape = (b1 - b0 + 2, tile.width + 2)
        if shadows is not None and shadows.dem is not None:  # the cast-shadow DEM holds these rows: not read twice
            halo_dem = shadows.rows(b0 - 1, b1 + 1, -1, tile.width + 1)
        else:
            halo_dem = read_dem_onto_grid(scene.dems, transform, shape, scene.crs, s.no_dem_data_val)
        self.dem = halo_dem[1:-1, 1:-1]
        self.halo = np.ascontiguousarray(halo_dem[:, c0:c1 + 2])
        lon, lat = geometry.lonlat_axes(transform, shape)
        lon_r, lat_r = np.radians(lon[c0:c1 + 2]), np.radians(lat)
        self.trig = (np.cos(lon_r), np.sin(lon_r), np.cos(lat_r), np.sin(lat_r))
        self.lon, self.lat = lon[1:-1], lat[1:-1]  # of the block's columns and rows
        self.c0 = c0

    def surface(self):
        """Body-fixed points (km, with the halo) and normals of the block's columns ``c0:c1``, as x, y, z planes
        (:func:`geometry.surface_block`)."""
        return geometry.surface_block(*self.trig, self.halo, MOON_RADIUS_KM)

    def observe(self, use, r0: int, c0: int, sun, spacecraft):
        """Candidate observations of a window at block row ``r0``, column ``c0`` (:func:`geometry.observe_window`)."""
        return geometry.observe_window(use, self.halo, *self.trig, MOON_RADIUS_KM, r0, c0 - self.c0,
                                       np.asarray(sun, np.float64), np.asarray(spacecraft, np.float64),
                                       MIN_COS_INCIDENCE_MODEL)


def tile_geometry(scene: Scene, tile):
    """DEM (m), body-fixed points (km), normals and the no-DEM mask of the whole unpadded tile."""
    geo = BlockGeometry(scene, tile, 0, tile.height)
    points, normals = geo.surface()
    return (geo.dem, np.moveaxis(points[:, 1:-1, 1:-1], 0, -1), np.moveaxis(normals, 0, -1), ~np.isfinite(geo.dem))


def saturation_of(dtype: str) -> float | None:
    """The saturated value of an integer DRG (its type's maximum, e.g. 255); None for float DRGs."""
    dt = np.dtype(dtype)
    return float(np.iinfo(dt).max) if dt.kind in "ui" else None


def gather_blocks(scene: Scene, t: int, lut: np.ndarray | None = None, helpers: int = 0, box=None):
    """Read and reduce every image over tile ``t``, block by block: yields ``(b0, b1, observations, per-pixel arrays,
    cols)``, ``cols = (c0, c1)`` the columns of the per-pixel sums (module docstring).  ``box``: the part of the tile
    gone through (:func:`footprint`, the default): rows, columns and pixel numbers count from its corner.

    See the module docstring for the arrays.  The ``usable`` flag (valid, lit, not
    saturated, not in a cast shadow, DEM, incidence <= 85 degrees and cos e > 0) and the
    blending weight are folded into ``weight``; observations with zero weight are
    dropped.  ``lut``: camera response g over 0..255 (Kim et al.), applied to each DRG's DN
    before it is resampled onto the tile grid.  ``helpers`` >= 2: that many helper threads read
    the images' windows and reduce them to observations, as many at once, while this thread
    adds up the earlier ones in tile order (:func:`lunaralbedo.parallel.ahead.ahead`; the same
    results; the blocks are made shorter by as many windows).
    """
    s = scene.settings
    model = scene.model
    tile = scene.tiles[t].part(footprint(scene, t) if box is None else box)
    if not tile.height or not tile.width:
        return
    geometry_needed = model.needs_geometry
    cast = TileShadows(scene, tile, scene.tile_images[t]) if geometry_needed and s.uses_cast_shadows else None
    windows = tile_windows(scene, t, tile)
    depth = helpers if helpers > 1 else 0
    pool = helper("windows", depth) if depth else None
    for b0, b1 in row_blocks(tile.height, block_rows(scene, t, depth, tile)):
        cols = [(w[2], w[3]) for _, w in windows if w is not None and w[0] < b1 and w[1] > b0]
        span = (min(c for c, _ in cols), max(c for _, c in cols)) if cols else (0, 0)
        band = cast.for_rows(b0, b1) if cast is not None else None  # the tile's terrain, or its band of these rows
        geo = BlockGeometry(scene, tile, b0, b1, *span, shadows=band) if geometry_needed else None
        yield (b0, b1, *_gather_block(scene, tile, b0, b1, windows, geo, band, model, lut, pool, depth, span), span)
        del band, geo


@njit(cache=True, nogil=True)
def _compact(rows, cols, keep, val, wb, ci, ce, al, row_off, col_off, width):
    """The candidates of one window that ``keep`` (all when it is empty), in one pass.

    Returns their window ``rows``, ``cols`` and geometry (as given: the same arrays when every
    candidate is kept), their block pixel numbers ``(row + row_off) * width + col + col_off``
    (int32) and their value and blending weight (float32, from the window arrays ``val``, ``wb``).
    """
    n = rows.shape[0]
    m = n
    if keep.shape[0]:
        m = 0
        for o in range(n):
            m += keep[o]
    pix, value, weight = np.empty(m, np.int32), np.empty(m, np.float32), np.empty(m, np.float32)
    if m == n:  # nothing to leave out (no cast shadow in the window): the candidates' arrays as they are
        for o in range(n):
            r, c = rows[o], cols[o]
            pix[o] = (r + row_off) * width + c + col_off
            value[o], weight[o] = val[r, c], wb[r, c]
        return rows, cols, pix, value, weight, ci, ce, al
    out_r, out_c = np.empty(m, np.int64), np.empty(m, np.int64)
    out_i, out_e, out_a = np.empty(m, ci.dtype), np.empty(m, ce.dtype), np.empty(m, al.dtype)
    j = 0
    for o in range(n):
        if not keep[o]:
            continue
        r, c = rows[o], cols[o]
        out_r[j], out_c[j] = r, c
        pix[j] = (r + row_off) * width + c + col_off
        value[j], weight[j] = val[r, c], wb[r, c]
        out_i[j], out_e[j], out_a[j] = ci[o], ce[o], al[o]
        j += 1
    return out_r, out_c, pix, value, weight, out_i, out_e, out_a


def _gather_block(scene: Scene, tile, b0, b1, windows, geo, cast, model, lut, pool, depth, span):
    s = scene.settings
    h, w = b1 - b0, tile.width
    s0, s1 = span  # the columns the block's windows cover: its per-pixel sums' columns
    thresh = s.shadow_thresh if s.shadow_type == shadows.THRESHOLD else None
    with_cos_i = geo is not None and s.shadow_type == shadows.LAMBERT_RATIO
    kept = []  # (k, window in block rows, window blending weights, then the observations: pix, value, weight, layers)
    weights_sum = np.zeros((h, s1 - s0))
    todo = [(k, (max(win[0], b0), min(win[1], b1), win[2], win[3])) for k, win in windows
            if win is not None and win[1] > b0 and win[0] < b1]

    def observe(item):
        """One image's window: its observations with positive weight, or None (thread-safe: no shared writes)."""
        k, (r0, r1, c0, c1) = item
        info = scene.images[k]
        got = read_drg_onto_grid(info, scene.profiles[k], tile.transform @ tile.transform.translation(c0, r0),
                                 (r1 - r0, c1 - c0), scene.crs, thresh, saturation=saturation_of(info.dtype), lut=lut)
        if got is None:
            return None
        val, ok, wt, use = got
        wb = (wt if s.use_weights else ok).astype(np.float32, copy=False)
        use &= (val > 0) & (wb > 0)  # zero blending weight: no observation (no geometry, no shadow test either)
        layers = {}
        if geo is not None:
            rows, cols, ci, ce, al = geo.observe(use, r0 - b0, c0, scene.sun[k], scene.spacecraft[k])
            lit = ~cast.shadowed(k, rows, cols, r0, c0) if (cast is not None and len(rows)) else np.ones(0, bool)
            rows, cols, pix, value, weight, ci, ce, al = _compact(rows, cols, lit, val, wb, ci, ce, al, r0 - b0, c0, w)
            if not len(rows):
                return None
            where = dict(lon=geo.lon[c0 + cols], lat=geo.lat[r0 - b0 + rows]) if model.needs_location else {}
            layers = model.layers(ci, ce, al, **where)
            if with_cos_i:
                layers["cos_i"] = ci
        else:
            if not use.any():
                return None
            rows, cols = np.nonzero(use)
            pix, value, weight = _compact(rows, cols, np.ones(0, bool), val, wb, *(np.zeros(len(rows)),) * 3,
                                          r0 - b0, c0, w)[2:5]
        return wb, pix, value, weight, {n: np.asarray(layers[n]).astype(np.float32, copy=False) for n in layers}

    for (k, (r0, r1, c0, c1)), got in zip(todo, ahead(observe, todo, pool, depth=max(depth, 1))):
        if got is None:
            continue
        wb, pix, value, weight, layers = got
        weights_sum[r0 - b0:r1 - b0, c0 - s0:c1 - s0] += wb  # float64, images in tile order
        # compact at once: only the window's blending weights stay (for eq. 7's denominator)
        kept.append((k, (r0 - b0, r1 - b0, c0 - s0, c1 - s0), wb if s.use_normalized_cost_fun else None, pix, value, weight, layers))
        del got, wb
    if s.use_normalized_cost_fun:  # the weights are divided by their float32 sums; eq. 7 then has its own denominator
        weights_sum32, wblend_sum = weights_sum.astype(np.float32), np.zeros((h, s1 - s0))
    else:
        wblend_sum = None  # eq. 7's denominator is weights_sum itself
    names = model.layer_names + (("cos_i",) if with_cos_i else ())
    counts = [len(e[3]) for e in kept]
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    values = np.empty((2 + len(names), int(start[-1])), np.float32)  # one array: runs.chunk_runs moves its rows at once
    obs = {"pix": np.empty(int(start[-1]), np.int32), **dict(zip(("image", "weight", *names), values))}
    obs["index"] = np.array([e[0] for e in kept], np.int32)
    obs["start"] = start
    for i in range(len(kept)):  # copied into place one image at a time, each image's arrays freed after
        k, (r0, r1, c0, c1), wb, pix, val, weight, layers = kept[i]
        kept[i] = None
        if s.use_normalized_cost_fun:
            with np.errstate(invalid="ignore", divide="ignore"):
                wb = np.where(wb > 0, wb / weights_sum32[r0:r1, c0:c1], 0.0).astype(np.float32)
                weight = (weight / weights_sum32[pix // w, pix % w - s0]).astype(np.float32)
            wblend_sum[r0:r1, c0:c1] += wb
        part = slice(start[i], start[i + 1])
        obs["pix"][part], obs["image"][part], obs["weight"][part] = pix, val, weight
        for n in names:
            obs[n][part] = layers[n]
    per_pixel = {"weights_sum": weights_sum.astype(np.float32)}  # float64 sums, float32 outputs
    if wblend_sum is not None:
        per_pixel["wblend_sum"] = wblend_sum.astype(np.float32)
    if geo is not None:
        per_pixel["dem"] = geo.dem
    return obs, per_pixel
