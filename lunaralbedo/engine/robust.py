r"""The outlier pass: each tile's observations get robust weights (:mod:`lunaralbedo.model.outliers`).

The spatial test does not depend on the solve's state: an observation's deviation from its own
image's neighbourhood, :math:`\log a - \operatorname{med}_N \log a` with
:math:`a = (I - H_k)/(T_k R)`, loses the image's :math:`\log T_k`, the haze is 0 and the model's
parameters are the initial ones when it runs.  So where the shadow mask does not depend on the
exposures either (:func:`in_prepare`: shadow type 0 or 1) the prepare step runs it on each block as
it is cached (:func:`prepared_block`): the block keeps the observations it rejected (``rejected``,
generation 1 of the weights, :data:`PREPARED`), the exposures' first start leaves their overlaps
out, and no pass over the cache is spent on it.  Where the mask needs the exposures (types 2 and 3,
:math:`I/(R T) \ge t`), the first reweight pass runs it.

A *reweight pass* maps :func:`reweight_tile` over the tiles before the first iteration and
again after a few (:data:`SCHEDULE`), with the current exposures, haze and model parameters.
Each block of a tile gets an effective weight per observation, :math:`m\\,w` (0: rejected by
the spatial test; below 1: down-weighted by the robust loss), saved in the tile's cache
entry (:mod:`.robust_store`: ``robust_<generation>/``, atomic); the iterate and finalise tasks read
the generation the state names (:func:`.tilework.effective_weights`), so the albedo,
exposure, phase and error updates all use them.  Everything is computed per tile from the
tile's own observations in a fixed order: the same bytes for any number of workers.  The
generation is part of the checkpoint, so ``--resume`` reads the same weights.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.cache import load_meta
from ..model import exposure_init, outliers, shadows
from ..parallel.progress import ROWS
from . import loss_kernels, pair_kernels, robust_kernels, robust_store
from .scene import Scene
from .tilework import SolveState, cache_dir, effective_weights, pixel_stack, tile_model

#: Reweight passes run before these iterations (0: before the first; counted from 0).  The second (IRLS with
#: the settled albedo) runs only where the robust loss applies: pixels with three or more images remain.
SCHEDULE = (0, 2)
#: The iteration of the generation the prepare step made (:func:`passes`: before every iteration, never run).
PREPARED = -1


def passes(settings, ck: dict) -> tuple[int, ...]:
    """The reweight schedule of a run: generation ``g + 1`` of the weights is made before iteration ``passes[g]``
    (:data:`SCHEDULE`; none when it does not reweight; the prepare step's first, :data:`PREPARED`, with the
    robust loss's passes after it only where a pixel has three images; one pass fewer when the first pass of the
    loss found no observation it applies to)."""
    if not enabled(settings):
        return ()
    first = (PREPARED,) if ck.get("spatial_prepared") else ()
    loss = SCHEDULE if not first or (settings.robust_loss != "none" and ck.get("loss_possible")) else ()
    if ck.get("robust", 0) > len(first) and not ck.get("loss_observations"):
        loss = loss[:1]
    return first + loss


def in_prepare(settings) -> bool:
    """True when the prepare step runs the spatial test (REJECT_OUTLIERS 1 and a shadow mask that does not depend
    on the exposures: shadow type 0 or 1)."""
    return bool(settings.reject_outliers) and settings.shadow_type not in (shadows.LAMBERT_RATIO,
                                                                          shadows.LUNAR_LAMBERT_RATIO)


def prepared_block(arrays: dict, scene: Scene, width: int) -> dict:
    """The spatial test on one block being prepared (chunk-major runs; ``width``: the tile's, pixels are numbered
    by): ``rejected`` (the observations it rejects, int64, ascending), ``counts`` ``(2, local images)`` (used and
    rejected), ``pairs`` (the overlap sums the rejected observations took part in, negated: :func:`_removed_pairs`)
    and ``loss_possible`` (a pixel has three images: the robust loss may apply).  The state is the initial one
    with every exposure 1 (the test does not depend on them: module docstring) and no haze."""
    s = scene.settings
    n_obs, n_img = len(arrays["weight"]), len(arrays["index"])
    state = SolveState(np.ones(len(scene.images)), np.asarray(s.initial_params, np.float64))
    r, w, texp = tile_model(scene, arrays, state)
    used = np.empty(n_obs, bool)
    flag = robust_kernels.spatial_test(arrays, width, np.zeros(n_img, np.float32), texp, r, np.asarray(w, np.float32),
                                       used)
    rejected = np.flatnonzero(flag)
    starts, images = np.asarray(arrays["run_start"], np.int64), np.asarray(arrays["run_image"], np.int64)
    def per_image(obs):  # how many of the observations ``obs`` each local image has
        return np.bincount(images[np.searchsorted(starts, obs, side="right") - 1], minlength=n_img)

    # the used observations: each image's, less the few not used (T R <= 0 or no weight)
    counts = np.stack([np.bincount(images, np.diff(starts), n_img) - per_image(np.flatnonzero(~used)),
                       per_image(rejected)])
    most = robust_kernels.most_runs_on_a_pixel(arrays["chunks"], arrays["run_start"], arrays["run_pixel"])
    return {"rejected": rejected.astype(np.int64), "index": np.asarray(arrays["index"]).tolist(),
            "counts": counts.astype(np.float64),
            "pairs": _removed_pairs(arrays, r, flag), "loss_possible": bool(most >= outliers.MIN_IMAGES_FOR_LOSS)}


def enabled(settings) -> bool:
    """True when the solve reweights (REJECT_OUTLIERS 1 or a robust loss)."""
    return bool(settings.reject_outliers) or settings.robust_loss != "none"


def _blocks(t: int, scene: Scene, cache_root: Path):
    """``(block folder, observations)`` of tile ``t``'s cached blocks of rows that hold any, in order (the row
    progress advanced for every block)."""
    folder = cache_dir(cache_root, scene, t)
    for i, (b0, b1) in enumerate(load_meta(folder)["blocks"]):
        block = folder / f"block_{i:04d}"
        arrays = pixel_stack(block, cache_root, scene)
        ROWS.advance(b1 - b0)
        if len(arrays["index"]):
            yield block, arrays


def reweight_tile(t: int, *, scene: Scene, cache_root: Path, state: SolveState, gen: int, pairs: bool = False) -> dict:
    """Write generation ``gen`` of the effective weights of tile ``t``'s blocks; return per local image the
    counts of used, rejected and down-weighted (sum of 1 - m) observations, and with ``pairs`` the overlap
    log-ratio sums of the pairs the rejected observations took part in, negated (:func:`_removed_pairs`): added to
    the prepare step's, the exposures can be initialised again without the outliers."""
    meta = load_meta(cache_dir(cache_root, scene, t))
    idx = np.asarray(meta["index"], np.int32)
    width = scene.tiles[t].width
    counts = np.zeros((3, len(idx)))
    loss_obs = 0
    pos = {k: j for j, k in enumerate(idx.tolist())}
    totals: dict = {}
    for block, arrays in _blocks(t, scene, cache_root):
        w_prev = effective_weights(block, arrays, state.robust)
        w_new, c, n_loss, removed = block_weights(arrays, scene, state, w_prev, width, pairs)
        loss_obs += n_loss
        if pairs:
            exposure_init.merge_pair_sums(totals, removed)
        counts[:, [pos[k] for k in np.asarray(arrays["index"]).tolist()]] += c
        robust_store.save(block, gen, arrays["weight"], w_new)
    return {"index": idx, "counts": counts, "loss_observations": loss_obs, "pairs": sorted(totals.items())}


def _removed_pairs(arrays: dict, r, flag) -> dict:
    """The overlap log-ratio sums ``{(j, k): (-n, -sum d)}`` of the pairs the block's rejected observations took part
    in (:func:`.pair_kernels.removed_pairs`), :func:`lunaralbedo.model.exposure_init.pair_sums`' form: added to the
    prepare step's sums, those of the observations kept."""
    n_img = len(arrays["index"])
    count, total = np.zeros((n_img, n_img)), np.zeros((n_img, n_img))
    pair_kernels.removed_pairs(arrays["chunks"], arrays["run_start"], arrays["run_pixel"], arrays["run_image"],
                               arrays["image"], np.asarray(r, np.float32), flag, count, total)
    index = np.asarray(arrays["index"]).tolist()
    out = {}
    for a, b in zip(*np.nonzero(count)):
        n, j, k, d = int(count[a, b]), int(index[a]), int(index[b]), float(total[a, b])
        out[(j, k) if j < k else (k, j)] = (-n, -d if j < k else d)
    return out


def block_weights(arrays: dict, scene: Scene, state: SolveState, w_prev: np.ndarray, width: int, pairs: bool = False):
    """The effective weights of one block (float32), its ``(3, local images)`` counts (used, rejected, down-weighted),
    the observations the robust loss applies to and, with ``pairs``, the overlap sums the rejected observations
    took part in, negated (:func:`_removed_pairs`; else None)."""
    s = scene.settings
    base = np.asarray(arrays["weight"], np.float32)
    r, w_lit, texp = tile_model(scene, arrays, state)
    n_obs, n_img = len(base), len(arrays["index"])
    used, w_lit = np.empty(n_obs, bool), np.asarray(w_lit, np.float32)
    if s.reject_outliers and not state.robust:  # the spatial test, in the first pass
        flag = robust_kernels.spatial_test(arrays, width, state.haze_of(arrays["index"]), texp, r, w_lit, used)
    else:  # later passes keep the first pass's rejections
        robust_kernels.usable(arrays["run_start"], arrays["run_image"], texp, r, w_lit, used)
        flag = used & (np.asarray(w_prev) == 0) & (base > 0) if s.reject_outliers else np.zeros(n_obs, bool)
    keep = used & ~flag
    removed = _removed_pairs(arrays, r, flag) if pairs else None
    m, n_loss = np.ones(0), 0  # m: the robust loss's factors (none: 1)
    if s.robust_loss != "none":
        m, n_loss = _loss_factors(arrays, state, r, texp, keep, w_prev, s, robust_kernels.workspace("loss", n_obs)[:n_obs])
    w_new, counts = robust_kernels.workspace("weights", n_obs).view(np.float32)[:n_obs], np.zeros((3, n_img))
    robust_kernels.finish(arrays["run_start"], arrays["run_image"], base, used, flag, keep, m, w_new, counts)
    return w_new, counts, n_loss, removed


def _loss_factors(arrays, state, r, texp, keep, w_prev, s, out) -> tuple:
    """The robust loss's IRLS factors m (empty: 1 everywhere, fewer than three images remain on every pixel; else 1
    where they do; ``out``: float64 scratch they go into) and how many observations it applies to
    (:mod:`.loss_kernels`)."""
    if robust_kernels.most_runs_on_a_pixel(arrays["chunks"], arrays["run_start"], arrays["run_pixel"]) < \
            outliers.MIN_IMAGES_FOR_LOSS:  # no pixel of the block has three images
        return np.ones(0), 0
    return loss_kernels.block_loss_factors(arrays, state.haze_of(arrays["index"]), texp, r, keep, w_prev,
                                           s.robust_loss, s.robust_threshold, out)


def reweight_pass(on_tiles, threads: int, scene: Scene, state: SolveState, ck: dict, init_pairs: dict | None) -> SolveState:
    """A reweight pass over the tiles (``on_tiles``: the solve's map over them): the next generation of robust
    weights, their per-image counts into the checkpoint ``ck``; with ``init_pairs`` (the prepare step's overlap
    sums, the exposures' first start; None: no new start) the first pass initialises the exposures again from the
    overlaps of the observations kept (those sums less the pairs of the rejected observations, summed in the same
    pass; when it rejected any, else the observations kept are those the exposures were initialised with)."""
    gen = ck["robust"] + 1
    want_pairs = gen == 1 and init_pairs is not None
    parts = on_tiles(reweight_tile, f"outliers {gen}", state=state, gen=gen, threads=threads, pairs=want_pairs)
    counts = np.zeros((3, len(scene.images)))
    for p in parts:  # fixed tile order
        np.add.at(counts.T, p["index"], p["counts"].T)
    t = state.exposure
    if want_pairs and counts[1].sum() > 0:  # the overlaps' exposures again, without the rejected observations
        pairs: dict = dict(init_pairs)
        for p in parts:  # fixed tile order
            exposure_init.merge_pair_sums(pairs, {tuple(k): tuple(v) for k, v in p["pairs"]})
        t = exposure_init.overlap_exposure(pairs, np.log(state.exposure))
    release_scratch()
    ck.update(robust=gen, reweight_now=False, outliers=counts.tolist(), exposure=np.asarray(t).tolist(),
              loss_observations=sum(int(p["loss_observations"]) for p in parts))
    return SolveState(np.asarray(t, np.float64), state.params, robust=gen, haze=state.haze,
                      exposures_known=state.exposures_known)


def release_scratch() -> None:
    """Drop the reweight kernels' scratch of every thread (the end of a pass or of the prepare step)."""
    robust_kernels.release()


def prepared(metas: list, n_images: int, ck: dict) -> None:
    """Into a new checkpoint ``ck``: generation 1 of the weights, the prepare step's spatial test (its per-image
    counts summed over the tiles' ``metas`` in tile order, whether the robust loss may apply), when it ran there."""
    if not metas or metas[0].get("spatial") is None:
        return
    counts = np.zeros((3, n_images))  # used, rejected, down-weighted (none yet)
    for m in metas:  # fixed tile order
        for row, c in zip(counts, m["spatial"]["counts"]):
            np.add.at(row, np.asarray(m["index"], np.int64), np.asarray(c, np.float64))
    ck.update(robust=1, spatial_prepared=True, outliers=counts.tolist(),
              loss_possible=any(m["spatial"]["loss_possible"] for m in metas))


def drop_generation(cache_root: Path, gen: int) -> None:
    """Delete every tile's effective weights of generation ``gen`` (superseded and checkpointed)."""
    import shutil

    if gen <= 0:
        return
    for d in Path(cache_root).glob(f"*/robust_{gen}"):
        shutil.rmtree(d, ignore_errors=True)


def report(keys: list[str], ck: dict, settings) -> dict | None:
    """``report.json``'s ``outliers`` from the checkpoint ``ck``: where the spatial test ran (``prepare``, the
    first ``reweight pass`` or, REJECT_OUTLIERS 0, None), how many reweight passes the iterations made, per image
    its used observations and the fractions rejected by the spatial test and taken away by the robust loss (sum
    of 1 - m over the used ones), after the last reweight pass."""
    counts = ck.get("outliers")
    if counts is None:
        return None
    used, rejected, down = (np.asarray(c, np.float64) for c in counts)
    frac = lambda x, n: round(float(x / n), 6) if n else 0.0  # noqa: E731
    first = bool(ck.get("spatial_prepared"))
    return {"spatial_test": "prepare" if first else ("reweight pass" if settings.reject_outliers else None),
            "reweight_passes": ck.get("robust", 0) - first,
            "rejected_fraction": frac(rejected.sum(), used.sum()),
            "images": {k: {"observations": int(n), "rejected_fraction": frac(r, n), "downweighted_fraction": frac(d, n)}
                       for k, n, r, d in zip(keys, used, rejected, down)}}
