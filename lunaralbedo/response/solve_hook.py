"""Camera response inside ``solve`` (Kim et al., unaligned case): estimate g, or load it, before the prepare pass.

``--response estimate``: the engine's *response pass*
(:func:`lunaralbedo.engine.response_pass.response_observations`) reads every DRG over each
tile with nearest-neighbour resampling (real observations: integer DN on the tile grid),
computes the reflectance model R (the photometric model's reflectance with its initial
parameters) and returns a fixed subsample of ``(pixel, image, DN, R)`` in tile order
(identical for any worker count).  :func:`resolve_response` fits g, the albedo (the
paper's r, with c = R) and, unless ``--exposure-times`` gives them, the exposures by
:func:`lunaralbedo.response.smoothing.fit_regularised` (Kim et al.'s likelihood with a roughness
penalty whose weight is cross-validated).  The prepare pass then applies g to each
DRG's DN *before* resampling (:func:`lunaralbedo.io.drgs.read_drg_onto_grid`), and the
usual albedo/exposure solve runs on the linearised values.

``--response FILE`` loads a ``response.csv`` instead.  The estimated response, its plots
and its fit report are checkpointed (``OUTDIR/checkpoint/response/`` + ``state.json``;
the files move into OUTDIR with the other results), so ``--resume`` does not refit.
"""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import InputError, ResumeError
from . import io as rio
from .smoothing import fit_regularised
from .model import Observations

RESPONSE_FILE = "response.csv"


def known_exposures(path: str | Path, keys: list[str]) -> np.ndarray:
    """Exposure per image key from ``key,exposure`` (the solver's exposure.csv format)."""
    table = rio.read_exposure_table(path)
    missing = [k for k in keys if k not in table]
    if missing:
        raise InputError(f"{path}: no exposure for image key(s) {', '.join(missing[:5])}")
    return np.array([table[k] for k in keys], np.float64)


def given_exposures(settings, exposure_times, keys: list[str]) -> tuple[str, np.ndarray | None]:
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


def lut_digest(lut: np.ndarray | None) -> str | None:
    return None if lut is None else hashlib.sha256(np.nan_to_num(lut, nan=-1).astype(np.float32).tobytes()).hexdigest()[:16]


def check_resume(ck: dict | None, lut, t_known) -> None:
    """A resumed run must use the response and exposure mode of the checkpoint."""
    if ck is None:
        return
    if (ck.get("response") or {}).get("digest") != lut_digest(lut) or bool(ck.get("exposure_fixed")) != (t_known is not None):
        raise ResumeError("the checkpoint was made with another --response / --exposure-times; run without --resume")


def resolve_response(spec, observe: Callable[[], Observations], keys: Sequence[str], folder: Path, t_known,
                     ck: dict | None, plots: bool):
    """The LUT for the prepare pass and its report: None (linear), a FILE's, or estimated.

    ``observe()`` runs the response pass (called only when an estimate is needed); ``keys``
    name the images.  An estimate (and a FILE's copy) is written into ``folder`` (the
    checkpoint's response folder; the driver moves its files into OUTDIR when the run succeeds).
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
    fit = fit_regularised(observe(), t_known)
    from .aligned import fit_report, write_outputs

    write_outputs(folder, fit, keys, plots, exposure_given=True)
    report = {"source": "estimate", **fit_report(fit, keys)}
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
