"""The prepare task: a tile's images read once, reduced to compact observations and cached.

:func:`prepare_tile` is the first of the three kinds of tile task (:mod:`.tilework` has the
cache layout it writes, the iterate and the finalise tasks).  It goes through the tile a block
of rows at a time (:func:`.observations.gather_blocks`): each block's observations are
reordered into chunk-major runs (:func:`.runs.chunk_runs`), its outliers found by the spatial test
(:func:`.robust.prepared_block`, when it runs here), its exposure-initialisation sums added
(:func:`_init_sums`, less the rejected observations' overlaps), and the block handed to this process's cache writer
(:data:`WRITER`) with the block's rows of the tile outputs known at once (DEM, weight sums).
"""
from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np

from ..io.cache import load_stack
from ..io.cachewriter import CacheWriter
from ..model import exposure_init
from ..parallel.ahead import ahead, helper
from ..parallel.progress import ROWS
from . import kernels, observations, robust, runs
from .scene import Scene
from .tilework import CACHE_LAYOUT, KNOWN_OUTPUTS, OUTPUT_OPTIONS, cache_dir

#: Blocks whose observations take at most this many bytes are reduced (initialisation sums,
#: chunk-major runs) on a helper thread while the next block is gathered, when the prepare
#: step has helpers; bigger ones in the task's thread (a block less held at once: make bench
#: item 10's blocks of a 4000 x 4000 px tile raised its peak by 120 MB when reduced ahead).
AHEAD_BYTES = 64 * 2**20


def prepare_tile(t: int, *, scene: Scene, cache_root: Path, lut: np.ndarray | None = None, wait: bool = True,
                 helpers: int = 0) -> dict:
    """Read every image over tile ``t`` (its footprint window only), compute geometry, cache the observations.

    ``lut``: camera response g over 0..255 (Kim et al.), applied to each DRG's DN before
    it is resampled onto the tile grid; None keeps the DN (linear response).

    The tile is done block of rows by block (:func:`observations.gather_blocks`), each
    block handed to this process's cache writer (:data:`WRITER`), which writes it while the
    next one is computed, into a temporary folder renamed once the tile is complete.  With
    ``wait`` the task returns once its tile is on disk (Dask workers: a finished task's tile
    can be read by any worker); without, the caller calls ``WRITER.flush()`` before the cache
    is read (a run in one process: the writing then overlaps the next tiles too).  Returns
    the tile's initialisation sums (also stored in the cache's meta, so a resumed run does not
    recompute them): per-image reflectance sums for the seed exposure, and pairwise log-ratio
    sums for the overlap exposure, added block by block in block order.  ``helpers`` (>= 2, a
    task with CPUs to spare: :mod:`lunaralbedo.parallel.ahead`): each block's image windows are
    read and reduced to observations on that many helper threads, ahead of the task's thread,
    which adds them up in tile order, and each block is reordered on another while the next
    one is gathered (the same bytes as one thread's).
    """
    folder = cache_dir(cache_root, scene, t)
    cached = load_stack(folder)
    if cached is not None and cached[1].get("layout") == CACHE_LAYOUT and \
            (cached[1].get("spatial") is not None) == robust.in_prepare(scene.settings):
        return {**cached[1], "reused": True}
    entry = WRITER.entry(folder)  # the tile's folder appears when all its blocks are written
    try:
        meta = _prepare_blocks(scene, t, lut, entry, helpers)
    except BaseException:
        entry.abandon()
        if wait:
            WRITER.drain()  # nothing of the task left in flight when it reports its failure
        raise
    if wait:
        WRITER.flush()
        robust.release_scratch()  # a worker's next task may be another kind: the spatial test's scratch not kept
    return {**meta, "reused": False}


#: This process's cache writer (:mod:`lunaralbedo.io.cachewriter`).
WRITER = CacheWriter()


def _prepare_blocks(scene: Scene, t: int, lut, entry, helpers: int) -> dict:
    r_sums: dict[int, list] = {}
    pairs: dict = {}
    blocks = []
    tile = scene.tiles[t]
    box = observations.footprint(scene, t)  # the rows and columns gone through: all but for tiles far bigger than
    r0, c0, width = box[0], box[2], box[3] - box[2]  # their images, whose other pixels keep the outputs' fill values
    n_obs = 0
    spatial = robust.in_prepare(scene.settings)
    tested: dict[int, np.ndarray] = {}  # per image: used and rejected by the spatial test
    loss_possible = False
    # the tile outputs known once it is prepared (its DEM and blending sums), written a block of rows at a time
    sparse = box != (0, tile.height, 0, tile.width)  # a part of the tile: the blocks outside it not stored
    known = partial(entry.save_rows, shape=(tile.height, tile.width), transform=tile.transform, crs=scene.crs,
                    sparse=sparse)
    skipped = tile.height - (box[1] - r0)  # the rows no image reaches: left to the fill values, never computed
    for kind in (KNOWN_OUTPUTS if scene.model.needs_geometry else ("weightsSum",)) if skipped else ():
        entry.skip_rows(f"{kind}.tif", skipped, shape=(tile.height, tile.width), transform=tile.transform,
                        crs=scene.crs, sparse=sparse, **OUTPUT_OPTIONS[kind])
    if skipped:
        ROWS.advance(skipped)

    def reduce(block):  # the initialisation sums and the chunk-major runs of a block
        b0, b1, obs, per_pixel, cols = block
        names = [n for n in obs if n not in ("pix", "start", "index")]
        pm = runs.chunk_runs(obs, (b1 - b0) * width, names)
        if "alpha" in pm:  # the phase-angle range of the block's observations (iterate_block): computed once
            pm["alpha_range"] = np.array(kernels.alpha_range(pm["alpha"], pm["weight"]), np.float32)
        part = _init_sums(scene, obs, width)
        if spatial and len(pm["index"]):
            part["spatial"] = robust.prepared_block(pm, scene, tile.width)
            pm["rejected"] = part["spatial"]["rejected"]
        return b0, b1, cols, per_pixel, part, pm

    big = lambda block: sum(a.nbytes for a in block[2].values()) > AHEAD_BYTES  # noqa: E731
    for b0, b1, cols, per_pixel, part, pm in ahead(reduce, observations.gather_blocks(scene, t, lut, helpers, box),
                                             helper("reduce") if helpers > 1 else None, here=big):
        if "dem" in per_pixel:  # every column (a view of the tile's terrain: copied, the writer holds only these rows)
            known("DEM.tif", np.array(per_pixel.pop("dem"), np.float32), r0 + b0, col0=c0, **OUTPUT_OPTIONS["DEM"])
        sums = np.zeros((b1 - b0, width), np.float32)  # 0 in the columns no image's window reaches
        sums[:, cols[0]:cols[1]] = per_pixel["weights_sum"]
        known("weightsSum.tif", sums, r0 + b0, col0=c0, **OUTPUT_OPTIONS["weightsSum"])
        for k, rs, n in zip(part["index"], part["r_sum"], part["r_count"]):
            acc = r_sums.setdefault(k, [0.0, 0.0])
            acc[0] += rs
            acc[1] += n
        exposure_init.merge_pair_sums(pairs, part["pairs"])
        if "spatial" in part:  # the overlaps of the observations kept
            exposure_init.merge_pair_sums(pairs, part["spatial"]["pairs"])
            for k, c in zip(part["spatial"]["index"], part["spatial"]["counts"].T):
                tested[k] = tested.get(k, 0) + c
            loss_possible |= part["spatial"]["loss_possible"]
        n_obs += len(pm["image"])
        entry.save(f"block_{len(blocks):04d}", {**pm, **{f"tile_{k}": v for k, v in per_pixel.items()}},
                   {"rows": [b0, b1], "cols": [int(cols[0]), int(cols[1])]})
        del pm, per_pixel, sums
        blocks.append([b0, b1])
        ROWS.advance(b1 - b0)
    index = [int(k) for k in scene.tile_images[t] if int(k) in r_sums]  # tile order
    meta = {
        "index": index,
        "r_sum": [r_sums[k][0] for k in index],
        "r_count": [r_sums[k][1] for k in index],
        "pairs": [[j, k, n_, d] for (j, k), (n_, d) in sorted(pairs.items())],
        "tile": scene.tiles[t].name,
        "blocks": blocks,
        "box": list(box),
        "observations": n_obs,
        "spatial": {"counts": [[float(tested.get(k, np.zeros(2))[i]) for k in index] for i in (0, 1)],
                    "loss_possible": loss_possible} if spatial else None,
        "layout": CACHE_LAYOUT,
    }
    entry.complete(meta)
    return meta


def _init_sums(scene: Scene, obs, width: int) -> dict:
    s = scene.settings
    r = scene.model.reflectance_from(obs, s.initial_params)
    rs, n = exposure_init.mean_reflectance_sums(r, obs["start"])  # observations already have positive weight,
    use = r > 0  # value and geometry; R > 0 remains (nearly always: no copies then)
    ustart = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)
    pick = (lambda a: a) if use.all() else (lambda a: a[use])
    pairs = exposure_init.pair_sums(pick(obs["pix"]), ustart, pick(obs["image"]), pick(r), obs["index"], width)
    return {"index": obs["index"].tolist(), "r_sum": rs.tolist(), "r_count": n.tolist(), "pairs": pairs}
