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
    """Read the photometric angles (and ground coordinates) of a backplane, matched by band name.

    The backplane is an ISIS ``phocube`` cube (band names from ``BandBin/Name``) or the
    GeoTIFF of :func:`lunaralbedo.backplanes.run.write_backplanes` (band descriptions).
    Emission and incidence prefer the "Local" bands (DEM normal), as ISIS ``lrowacphomap``
    and ``lronacpho`` read them.

    Parameters
    ----------
    path : str or Path
        The backplane cube or GeoTIFF.
    ground : bool, default True
        Also read ``"Latitude"`` and ``"Longitude"``.

    Returns
    -------
    dict of str to numpy.ndarray
        Float64 ``(lines, samples)`` arrays in degrees under the keys ``"phase"``,
        ``"emission"``, ``"incidence"`` and, with ``ground``, ``"lat"`` (planetocentric) and
        ``"lon"`` (as the backplane holds it: 0..360 east from ``phocube`` and ours).

    Raises
    ------
    InputError
        Exit 2: the file cannot be opened, or a needed band is missing (the message lists
        the bands it has).
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
    """Photometrically correct a Level-1 cube to standard angles and write a float32 GeoTIFF.

    Each valid pixel is multiplied by :math:`r(i_r, e_r, g_r) / r(i, e, g)`: the model's
    reflectance at the reference angles over that at the pixel's incidence :math:`i`,
    emission :math:`e` and phase :math:`g`.  ``"lroc-empirical"`` is ISIS ``lronacpho``
    (the LROC empirical model, reference angles ``IncRef``/``EmaRef``/``PhaRef`` of the
    parameter file); ``"hapke-map"`` is ISIS ``lrowacphomap`` (HapkeLROC with per-pixel
    parameters read from a map at the pixel's latitude/longitude).  Pixels outside the
    angle ``limits`` or without geometry are NaN (where ISIS writes Null).

    Parameters
    ----------
    cube : str or Path
        ISIS3 Level-1 cube with ``BandBin/Center`` (nm; the wavelength selects the
        parameters).
    out : str or Path
        GeoTIFF to write (atomically): one float32 band per corrected band, in the cube's
        pixel frame, described and tagged with the band centre and model.
    model : {"lroc-empirical", "hapke-map"}
        The photometric model, as above.
    params : str or Path
        Photometric parameter file (PVL): ``NormalizationModel`` of ``lronacpho`` or
        ``PhotometricModel`` HapkeLROC of ``lrowacphomap``.
    band : int, optional
        Correct only this band (1-based); default every band.
    param_map : str or Path, optional
        Equirectangular Hapke parameter cube (e.g. the Sato et al. WAC map); required for
        ``"hapke-map"``.
    backplane : str or Path, optional
        Take the angles from this backplane (:func:`read_backplane`; one ``band`` only)
        instead of our camera.
    dem : str or Path or sequence of them, optional
        DEM(s) for the camera geometry (local angles, ISIS ``usedem=true``); default the
        cube's ``ShapeModel`` when it resolves, else the sphere.
    ellipsoid : bool, default False
        Sphere geometry with the plain angles (ISIS ``usedem=no``).
    isis_compat : bool, default False
        Reproduce ISIS ``lrowacphomap``'s numbers including its two band-matching defects
        (see docs/photometry.md); with a backplane also skip the angle limits, as ISIS does.
    limits : sequence of (float, float), optional
        ``(min, max)`` in degrees for incidence, emission and phase; default ISIS's:
        ``(0, 85), (0, 85), (0, 180)`` for ``lronacpho``, ``(0, 90), (0, 90), (0, 180)`` for
        ``lrowacphomap``.
    kernels : sequence of str or Path, optional
        Extra SPICE kernels, kernel folders or meta-kernels, loaded after the label's.
    isisdata : str or Path, optional
        ISIS data area that resolves ``$base``/``$<mission>`` paths.

    Returns
    -------
    list of Result
        One per corrected band, in order: ``band`` (1-based), ``center`` (nm), ``count``
        (valid pixels), ``mean``, ``std`` (ddof 1), ``minimum``, ``maximum``, ``total``
        (float64 statistics of the float32 output's finite values; NaN when none) and
        ``geometry`` (where the angles came from: ``"camera on <shape>"`` or
        ``"backplane <path>"``).

    Raises
    ------
    InputError
        Exit 2: an unknown ``model``, ``"hapke-map"`` without ``param_map``, a backplane
        with more than one band selected, a backplane without a needed band.
    IsisError
        Exit 2: ``band`` out of range, no or mismatched ``BandBin/Center``, a malformed
        parameter file or parameter map.
    SpiceError
        Exit 2: a missing kernel or a time the kernels do not cover.
    """
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
