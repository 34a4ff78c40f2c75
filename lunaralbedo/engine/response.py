"""Camera response inside ``solve`` (seed 002, unaligned case): estimate g, or load it, before the prepare pass.

``--response estimate``: a *response pass* maps :func:`response_tile` over the tiles.
Each task reads every DRG over its tile with nearest-neighbour resampling (real
observations: integer DN on the tile grid), computes the reflectance model R of seed 000
(the photometric model's reflectance with its initial parameters) and returns a fixed subsample of
``(pixel, image, DN, R)``.  The driver concatenates them in tile order (identical for
any worker count) and fits g, the albedo (the seed's r, with c = R) and, unless
``--exposure-times`` gives them, the exposures by
:func:`lunaralbedo.model.response_fit.fit_response`.  The prepare pass then applies g to
each DRG's DN *before* resampling (:func:`lunaralbedo.io.drgs.read_drg_onto_grid`),
and the usual albedo/exposure solve runs on the linearised values.

``--response FILE`` loads a ``response.csv`` instead.  The estimated response, its plots
and its fit report are checkpointed (``OUTDIR/checkpoint/response/`` + ``state.json``;
the files move into OUTDIR with the other results), so ``--resume`` does not refit.
"""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
from rasterio.enums import Resampling

from ..constants import MIN_COS_INCIDENCE_MODEL
from ..errors import InputError, ResumeError
from ..io import response as rio
from ..io.drgs import read_drg_onto_grid
from ..model import geometry, shadows
from ..model.response import Observations
from ..model.response_fit import fit_response
from ..settings import Settings
from .scene import Scene
from .observations import tile_geometry

#: Observations per tile handed to the response fit (a fixed stride over pixels beyond it).
MAX_PIXELS_PER_TILE = 40_000
RESPONSE_FILE = "response.csv"


def known_exposures(path: str | Path, keys: list[str]) -> np.ndarray:
    """Exposure per image key from ``key,exposure`` (the solver's exposure.csv format)."""
    table = rio.read_exposure_table(path)
    missing = [k for k in keys if k not in table]
    if missing:
        raise InputError(f"{path}: no exposure for image key(s) {', '.join(missing[:5])}")
    return np.array([table[k] for k in keys], np.float64)


def given_exposures(settings: Settings, exposure_times, keys: list[str]) -> tuple[str, np.ndarray | None]:
    """The exposure mode and the given exposures: ``--exposure-times FILE`` (fixed), else EXPOSURE_MODE with
    EXPOSURE_FILE (``fixed``/``prior`` without a file: every exposure 1, the calibrated I/F case)."""
    if exposure_times is not None:
        return "fixed", known_exposures(exposure_times, keys)
    mode = settings.exposure_mode
    if mode == "solve":
        return mode, None
    f = settings.exposure_file
    if f is None:
        return mode, np.ones(len(keys))
    try:
        return mode, known_exposures(f, keys)
    except InputError as exc:
        raise InputError(f"EXPOSURE_FILE {exc}") from None


def response_tile(t: int, *, scene: Scene, max_pixels: int = MAX_PIXELS_PER_TILE) -> dict:
    """Real observations of tile ``t``: flat pixel index, image index, DN, reflectance R (seed 002 eq. 6)."""
    s = scene.settings
    tile = scene.tiles[t]
    shape = (tile.height, tile.width)
    geo = tile_geometry(scene, tile) if s.needs_geometry else None
    thresh = s.shadow_thresh if s.shadow_type == shadows.THRESHOLD else None
    step = max(1, int(np.ceil(tile.height * tile.width / max_pixels)))
    pick = np.arange(0, tile.height * tile.width, step)
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
            r = s.model.reflectance(ci, ce, al, s.initial_params)
            use &= r > 0
        sel = pick[use.ravel()[pick]]
        out["pixel"].append(sel)
        out["image"].append(np.full(len(sel), k, np.int32))
        out["dn"].append(np.rint(val.ravel()[sel]).astype(np.int16))
        out["factor"].append(np.asarray(r, np.float32).ravel()[sel])
    return {name: (np.concatenate(v) if v else np.zeros(0)) for name, v in out.items()} | {"n_pixels": tile.height * tile.width}


def _reduce(scene: Scene, parts: list[dict]) -> Observations:
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
    return _reduce(scene, parts)


def lut_digest(lut: np.ndarray | None) -> str | None:
    return None if lut is None else hashlib.sha256(np.nan_to_num(lut, nan=-1).astype(np.float32).tobytes()).hexdigest()[:16]


def check_resume(ck: dict | None, lut, t_known) -> None:
    """A resumed run must use the response and exposure mode of the checkpoint."""
    if ck is None:
        return
    if (ck.get("response") or {}).get("digest") != lut_digest(lut) or bool(ck.get("exposure_fixed")) != (t_known is not None):
        raise ResumeError("the checkpoint was made with another --response / --exposure-times; run without --resume")


def resolve_response(spec, scene: Scene, executor, folder: Path, t_known, ck: dict | None, plots: bool):
    """The LUT for the prepare pass and its report: None (linear), a FILE's, or estimated.

    An estimate (and a FILE's copy) is written into ``folder`` (the checkpoint's response
    folder; the driver moves its files into OUTDIR when the run succeeds).
    """
    if spec is None:
        return None, None
    folder.mkdir(parents=True, exist_ok=True)
    if spec != "estimate":
        lut = rio.read_response_csv(spec)
        shutil.copyfile(spec, folder / RESPONSE_FILE)  # the output records the response it used
        dn = np.flatnonzero(np.isfinite(lut))
        return lut, {"source": str(spec), "dn": dn.tolist(), "g": lut[dn].astype(np.float64).tolist(), "digest": lut_digest(lut)}
    if ck is not None and ck.get("response"):
        lut = rio.read_response_csv(folder / RESPONSE_FILE)
        if lut_digest(lut) != ck["response"]["digest"]:
            raise ResumeError(f"{folder / RESPONSE_FILE}: differs from the checkpointed response; run without --resume")
        return lut, ck["response"]
    fit = fit_response(response_observations(scene, executor), t_known)
    from ..response.aligned import fit_report, write_outputs

    write_outputs(folder, fit, scene.keys, plots, exposure_given=True)
    report = {"source": "estimate", **fit_report(fit, scene.keys)}
    report.pop("loglik")
    lut = rio.read_response_csv(folder / RESPONSE_FILE)  # one source of truth: estimate, FILE and resume agree bit for bit
    report["digest"] = lut_digest(lut)
    return lut, report


def move_outputs(folder: Path, out: Path) -> None:
    """Move the response files of a finished run from the checkpoint into OUTDIR."""
    if folder.is_dir():
        for f in sorted(folder.iterdir()):
            f.replace(out / f.name)


def report_parts(resp: dict | None) -> dict:
    """report.json's ``response`` (the curve dn, g and the fit's scalars) and ``residuals``."""
    if not resp:
        return {"response": None, "residuals": None}
    resp = dict(resp)
    return {"residuals": resp.pop("residuals", None), "response": resp}
