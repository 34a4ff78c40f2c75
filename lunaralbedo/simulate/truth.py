"""The one truth format of every synthetic scene, and the comparison of a solve with it.

A scene folder holds ``truth/truth.json`` and ``truth/albedo.tif`` (float32, the true
albedo on a lon/lat grid).  ``truth.json``, whatever rendered the scene (the DRG strip
of :mod:`.strip` or the ISIS mission of :mod:`.mission`)::

    {
      "reflectance_type": 2,            # the photometric model's REFLECTANCE_TYPE code
      "c1": 1.4, "c2": 0.5,             # its fitted parameters, by the model's names (none for R = 1 or cos i)
      "seed": ...,
      "albedo": "truth/albedo.tif",     # paths relative to the scene folder
      "dem": "DEM/dem.tif",
      "frame": "...",                   # the body-fixed frame of the positions (km)
      "images": {                       # one entry per image, by its 11-character key
        "KEY": {"exposure": 1.03, "sun_km": [x, y, z], "spacecraft_km": [x, y, z], ...},
        ...
      },
      ...                               # generator-specific extras (e.g. "spec", "gain", "noise_relative")
    }
"""
from __future__ import annotations

import glob
import json
import shutil
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError, OutputError
from ..io.atomic import atomic_write_text
from ..io.guard import check_output_dir

#: Keys every truth.json has, and the keys of every image entry.
REQUIRED = ("reflectance_type", "albedo", "images")
IMAGE_REQUIRED = ("exposure", "sun_km", "spacecraft_km")


def check_truth(truth: dict, where: str) -> dict:
    """``truth`` itself, or :class:`InputError` naming ``where`` and the missing keys."""
    missing = [k for k in REQUIRED if k not in truth]
    missing += [f"images.{key}.{k}" for key, im in truth.get("images", {}).items() for k in IMAGE_REQUIRED if k not in im]
    if missing:
        raise InputError(f"{where}: not a lunaralbedo truth file (missing {', '.join(missing)})")
    return truth


def write_truth(scene_dir: str | Path, truth: dict) -> None:
    """Write ``truth`` (checked) as ``scene_dir/truth/truth.json``, atomically."""
    path = Path(scene_dir) / "truth" / "truth.json"
    atomic_write_text(path, json.dumps(check_truth(truth, str(path)), indent=1) + "\n")


def read_truth(scene_dir: str | Path) -> dict:
    """The truth of a rendered scene (:class:`InputError` naming the file when it is missing or malformed)."""
    path = Path(scene_dir) / "truth" / "truth.json"
    try:
        truth = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no truth file; is {scene_dir} a scene rendered by `lunaralbedo simulate`?") from None
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read the truth file ({e})") from None
    return check_truth(truth, str(path))


def true_exposures(truth: dict) -> dict[str, float]:
    """``{key: exposure}`` of every image of ``truth``."""
    return {k: float(im["exposure"]) for k, im in truth["images"].items()}


def render_into(out_dir: str | Path, render: Callable[[Path], dict], what: str = "scene folder") -> dict:
    """Run ``render(folder)`` into a new or empty folder; a failed render leaves no folder behind.

    :class:`OutputError` when ``out_dir`` cannot be created or is not empty, before anything is written.
    """
    out = check_output_dir(out_dir, what)
    if out.is_dir() and any(out.iterdir()):
        raise OutputError(f"{out}: the {what} exists and is not empty")
    created = not out.exists()
    try:
        return render(out)
    except BaseException:
        if created:  # nothing half-written
            shutil.rmtree(out, ignore_errors=True)
        raise


def score(result_dir: str | Path, scene_dir: str | Path) -> dict:
    """Compare a solve's albedo and exposures with the truth of a rendered scene.

    The solved albedo tiles are mosaicked onto the truth's grid; since :math:`A\\,T` of
    the PhotometryTK manual's eq. 1 leaves one global scale free, the albedo is first
    scaled by the least-squares :math:`s = \\sum a\\,t / \\sum a^2`, and the exposures are
    compared after normalising both to the same geometric mean.

    Parameters
    ----------
    result_dir : str or Path
        The ``RESULTS_DIR`` of a solve (``albedo/*.tif``, ``exposure.csv``).
    scene_dir : str or Path
        The scene folder (its ``truth/truth.json`` and true albedo raster).

    Returns
    -------
    dict
        ``albedo_rel_rmse`` (RMS of :math:`(s\\,a - t)/t` over the pixels with both a
        solved and a true albedo), ``exposure_max_rel_err`` (largest relative exposure
        error), ``coverage`` (fraction of the truth grid with a solved and a true albedo)
        and ``images_compared`` (images in both the truth and ``exposure.csv``);
        ``albedo_rel_p99`` (99th percentile of the scaled relative error's magnitude),
        ``albedo_ratio_median`` and ``albedo_rel_rms_unscaled`` (solved / true albedo with no
        scale fitted: physical units); with a ``haze.csv`` in the results, ``haze_max_abs_err``
        (largest haze error, DRG units).

    Raises
    ------
    InputError
        Exit 2: no or malformed truth file, no albedo tiles in ``result_dir``, an
        unreadable ``exposure.csv``.
    """
    import rasterio
    from rasterio.merge import merge

    from ..io.outputs import read_exposure_csv

    result_dir, scene_dir = Path(result_dir), Path(scene_dir)
    truth = read_truth(scene_dir)
    with rasterio.open(scene_dir / truth["albedo"]) as t:
        ta, tt, tb = t.read(1), t.transform, t.bounds
    files = sorted(glob.glob(str(result_dir / "albedo" / "*.tif")))
    if not files:
        raise InputError(f"{result_dir / 'albedo'}: no albedo tiles to compare with the truth")
    mos, _ = merge(files, bounds=tb, res=(tt.a, -tt.e), nodata=np.nan, dtype="float32")
    a = mos[0]
    ok = np.isfinite(a) & np.isfinite(ta)
    s = np.sum(a[ok] * ta[ok]) / np.sum(a[ok] ** 2)
    rel = (s * a[ok] - ta[ok]) / ta[ok]
    est = read_exposure_csv(result_dir / "exposure.csv")
    true_exp = true_exposures(truth)
    keys = sorted(set(true_exp) & set(est))
    te = np.array([true_exp[k] for k in keys])
    ratio = np.array([est[k] for k in keys]) / te
    ratio /= np.exp(np.mean(np.log(ratio)))
    extra = {}
    if (result_dir / "haze.csv").exists():
        solved_haze = _read_key_csv(result_dir / "haze.csv", "haze")
        extra["haze_max_abs_err"] = max(abs(solved_haze[k] - float(truth["images"][k].get("haze", 0.0))) for k in solved_haze)
    raw = a[ok] / ta[ok]
    return {
        **extra,
        "albedo_rel_p99": float(np.percentile(np.abs(rel), 99)),
        "albedo_ratio_median": float(np.median(raw)),
        "albedo_rel_rms_unscaled": float(np.sqrt(np.mean((raw - 1) ** 2))),
        "albedo_rel_rmse": float(np.sqrt(np.mean(rel**2))),
        "exposure_max_rel_err": float(np.max(np.abs(ratio - 1))),
        "coverage": float(ok.mean()),
        "images_compared": len(keys),
    }


def _read_key_csv(path: Path, column: str) -> dict[str, float]:
    """``{key: value}`` of one column of a ``key,...`` CSV written by ``solve``."""
    import csv

    with open(path, newline="") as f:
        return {row["key"]: float(row[column]) for row in csv.DictReader(f)}
