"""``lunaralbedo photometry``: photometric correction of a Level-1 cube (orchestration).

Geometry comes from a backplane (ISIS phocube cube or our ``backplanes`` GeoTIFF) or
from our camera on a shape (see :mod:`lunaralbedo.backplanes.shape`); with a DEM the
local angles are used (ISIS ``usedem=true``), on the sphere the plain ones.  The
output is float32, NaN where ISIS writes Null.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rasterio.errors import NotGeoreferencedWarning
from rasterio.transform import Affine

from ..backplanes.run import camera_geometry
from ..errors import InputError, IsisError
from ..io.geotiff import write_geotiff
from ..io.guard import open_quietly
from ..isis.labels import read_label
from ..isis.pixels import read_band
from ..isis.parameter_map import read_parameter_map
from .hapkemap import hapke_map_correction
from .params import load_hapke_map, load_lroc_empirical

MODELS = ("lroc-empirical", "hapke-map")
#: ISIS's default angle limits (degrees): lronacpho / lrowacphomap (min, max) for incidence, emission, phase.
DEFAULT_LIMITS = {"lroc-empirical": ((0, 85), (0, 85), (0, 180)), "hapke-map": ((0, 90), (0, 90), (0, 180))}


@dataclass
class Result:
    """Summary of a corrected band: valid pixel count and statistics (float64 over the float32 output)."""

    band: int
    center: float
    count: int
    mean: float
    std: float
    minimum: float
    maximum: float
    total: float
    geometry: str = ""


def _band_centers(label) -> list[float]:
    bb = label.group("BandBin", required=False)
    c = None if bb is None else bb.get("Center")
    c = getattr(c, "value", c)
    if c is None:
        raise IsisError(f"{label.path}: no BandBin/Center (the band's wavelength selects the parameters)")
    return [float(getattr(v, "value", v)) for v in (c if isinstance(c, (list, tuple)) else [c])]


def read_backplane(path: str | Path, ground: bool = True) -> dict[str, np.ndarray]:
    """Angles (and, if ``ground``, latitude/longitude) from a backplane, matched by band name.

    The backplane is an ISIS phocube cube or our ``backplanes`` GeoTIFF; emission/incidence
    prefer the "Local" bands (what ISIS's ``lrowacphomap`` and ``lronacpho`` read).
    """
    path = Path(path)
    with open_quietly(path, "backplane") as ds:
        names = list(ds.descriptions)
    if path.suffix.lower() == ".cub":
        label = read_label(path)
        bb = label.group("BandBin", required=False)
        names = [str(n) for n in (bb.get("Name") if bb is not None and "Name" in bb else [])]
        bands = {n: read_band(label, k + 1) for k, n in enumerate(names)}
    else:
        with open_quietly(path, "backplane") as ds:
            bands = {n: ds.read(k + 1).astype(np.float64) for k, n in enumerate(names) if n}
    pick = {}
    wanted = [("phase", ["Phase Angle"]), ("emission", ["Local Emission Angle", "Emission Angle"]),
              ("incidence", ["Local Incidence Angle", "Incidence Angle"])]
    for want, options in wanted + ([("lat", ["Latitude"]), ("lon", ["Longitude"])] if ground else []):
        hit = next((o for o in options if o in bands), None)
        if hit is None:
            raise InputError(f"{path}: backplane has no {' or '.join(repr(o) for o in options)} band (bands: {names})")
        pick[want] = bands[hit]
    return pick


def correct(cube, out, model: str, params, band: int | None = None, param_map=None, backplane=None, dem=None,
            ellipsoid: bool = False, isis_compat: bool = False, limits=None, kernels=(), isisdata=None) -> list[Result]:
    """Correct ``cube`` (all bands, or ``band``) and write ``out`` (float32 GeoTIFF, one band per corrected band)."""
    if model not in MODELS:
        raise InputError(f"unknown photometric model {model!r} (known: {', '.join(MODELS)})")
    label = read_label(cube)
    nbands = label.shape[0]
    if band is not None and not 1 <= band <= nbands:
        raise IsisError(f"{cube}: band {band} out of range 1..{nbands}")
    selected = [band] if band is not None else list(range(1, nbands + 1))
    centers = _band_centers(label)
    if len(centers) != nbands:
        raise IsisError(f"{cube}: BandBin/Center has {len(centers)} values for {nbands} bands")
    if backplane is not None and len(selected) != 1:
        raise InputError(f"{cube}: a backplane applies to one band at a time (give --band)")
    if model == "hapke-map" and param_map is None:
        raise InputError("--model hapke-map needs --param-map (the Hapke parameter cube)")
    limits = limits or DEFAULT_LIMITS[model]
    if model == "lroc-empirical":
        per_band, reference = load_lroc_empirical(params, [centers[b - 1] for b in selected])
    else:
        pmap = read_parameter_map(param_map)
        hparams = load_hapke_map(params, pmap.band_names)
    results, planes = [], []
    for k, b in enumerate(selected):
        image = read_band(label, b)
        if backplane is not None:
            geo, how = read_backplane(backplane, ground=model == "hapke-map"), f"backplane {backplane}"
            apply_limits = not isis_compat  # ISIS skips the angle limits with a backplane
        else:
            g, shape = camera_geometry(label, b, dem=dem, ellipsoid=ellipsoid, kernels=kernels, isisdata=isisdata)
            local = not shape.is_sphere
            geo = {"phase": g["Phase Angle"], "lat": g["Latitude"], "lon": g["Longitude"],
                   "emission": g["Local Emission Angle" if local else "Emission Angle"],
                   "incidence": g["Local Incidence Angle" if local else "Incidence Angle"]}
            how, apply_limits = f"camera on {shape.name}", True
        if model == "lroc-empirical":
            corr = per_band[k].correction(geo["incidence"], geo["emission"], geo["phase"], reference)
        else:
            corr = hapke_map_correction(hparams, pmap, geo["incidence"], geo["emission"], geo["phase"], geo["lat"],
                                        geo["lon"], centers[b - 1], isis_compat,
                                        [centers[s - 1] for s in selected], k + 1)
        ok = np.all(np.isfinite(np.stack(list(geo.values()))), axis=0) & np.isfinite(corr)
        if apply_limits:
            for (lo, hi), name in zip(limits, ("incidence", "emission", "phase")):
                with np.errstate(invalid="ignore"):
                    ok &= (geo[name] >= lo) & (geo[name] <= hi)
        plane = np.where(ok, image * corr, np.nan).astype(np.float32)
        planes.append(plane)
        v = plane[np.isfinite(plane)].astype(np.float64)
        stats = (v.mean(), v.std(ddof=1) if v.size > 1 else 0.0, v.min(), v.max(), v.sum()) if v.size else (np.nan,) * 5
        results.append(Result(b, centers[b - 1], int(v.size), *map(float, stats), geometry=how))
    with warnings.catch_warnings():  # a Level-1 image has no georeference
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        write_geotiff(out, np.stack(planes), Affine.identity(), None, nodata=float("nan"), dtype="float32",
                      descriptions=[f"band {r.band} ({r.center:g} nm) {model} corrected" for r in results],
                      tags=[dict(band_center_nm=r.center, model=model, isis_compat=str(isis_compat)) for r in results])
    return results
