"""Photometric parameter files (ISIS PVL) -> model parameters, with ISIS's band matching.

* ``lronacpho`` files: ``NormalizationModel/Algorithm`` (IncRef, EmaRef, PhaRef) and
  ``PhotometricModel/Algorithm`` groups; a group applies to a cube band whose
  ``BandBin/Center`` is within ``BandBinCenterTolerance`` (default 1e-6) of its
  ``BandBinCenter``.  Object-level keywords (e.g. ``Units``) are defaults of each group.
* ``lrowacphomap`` files: ``PhotometricModel`` with Incref/EmiRef/Pharef, Units, Hfunc and
  one ``Parameters`` group per wavelength naming the parameter-map bands.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..errors import IsisError
from ..isis.pvlfile import find_object, get_ci, groups, read_pvl
from ..model.photometry.lroc_empirical import VERSIONS, LrocEmpirical


def _merged(obj, group) -> dict:
    """Object keywords overridden by the group's (ISIS ``DbProfile(object, group)``), keys case-folded."""
    out = {k.casefold(): v for k, v in obj.items() if not hasattr(v, "items")}
    out.update({k.casefold(): v for k, v in group.items() if not hasattr(v, "items")})
    return out


def _float(d: dict, key: str, default, where: str) -> float:
    v = d.get(key.casefold(), default)
    try:
        return float(getattr(v, "value", v))
    except (TypeError, ValueError):
        raise IsisError(f"{where}: {key} = {v!r} is not a number") from None


def load_lroc_empirical(path: str | Path, band_centers) -> tuple[list[LrocEmpirical], tuple[float, float, float]]:
    """Per cube band (in order of ``band_centers``, nm) the LROC empirical parameters, and ``(IncRef, EmaRef, PhaRef)``."""
    where = str(path)
    module = read_pvl(path)
    norm = find_object(module, "NormalizationModel", where)
    algo = next(iter(groups(norm, "Algorithm")), None)
    if algo is None:
        raise IsisError(f"{where}: NormalizationModel has no Algorithm group")
    i_ref = float(get_ci(algo, "IncRef", 30.0))
    reference = (i_ref, float(get_ci(algo, "EmaRef", 0.0)), float(get_ci(algo, "PhaRef", i_ref)))
    pho = find_object(module, "PhotometricModel", where)
    profiles = []
    for g in groups(pho, "Algorithm"):
        d = _merged(pho, g)
        name = str(d.get("name", ""))
        if name.upper() != "LROC_EMPIRICAL":
            raise IsisError(f"{where}: algorithm {name!r} is not LROC_Empirical")
        version = int(_float(d, "AlgorithmVersion", 0, where))
        if version not in VERSIONS:
            raise IsisError(f"{where}: AlgorithmVersion {version} not recognised (2014, 2019 or none)")
        profiles.append((d, LrocEmpirical(
            a=tuple(_float(d, f"A{k}", 0.0, where) for k in range(4)),
            b=tuple(_float(d, f"B{k}", 0.0, where) for k in range(7)),
            version=version, degrees=str(d.get("units", "Radians")).lower() == "degrees",
            wavelength=_float(d, "BandBinCenter", float("nan"), where),
            tolerance=abs(_float(d, "BandBinCenterTolerance", 1e-6, where)))))
    out, missing = [], []
    for band, center in enumerate(band_centers, start=1):
        hit = next((m for d, m in profiles if "bandbincenter" in d and abs(float(center) - m.wavelength) <= m.tolerance),
                   None)
        if hit is None:
            missing.append(f"band {band} (centre {center} nm)")
        out.append(hit)
    if missing:
        raise IsisError(f"{where}: no PhotometricModel Algorithm group for {', '.join(missing)}")
    return out, reference


@dataclass
class HapkeGroup:
    """One ``Parameters`` group: its wavelength (nm) and the 0-based parameter-map band of each parameter name."""

    center: float
    bands: dict[str, int]


@dataclass
class HapkeMapParams:
    """A ``lrowacphomap`` parameter file: reference angles (degrees), units and its groups in file order."""

    reference: tuple[float, float, float]
    degrees: bool
    hfunc: str
    groups: list[HapkeGroup]


def load_hapke_map(path: str | Path, map_band_names) -> HapkeMapParams:
    """Parse a HapkeLROC parameter file; ``map_band_names`` are the parameter cube's ``BandBin/Name`` values."""
    where = str(path)
    pho = find_object(read_pvl(path), "PhotometricModel", where)
    algo = next(iter(groups(pho, "Algorithm")), None)
    name = str(get_ci(algo, "Name", "")) if algo is not None else ""
    if name.upper() != "HAPKELROC":
        raise IsisError(f"{where}: algorithm {name!r} is not supported (HapkeLROC)")
    hfunc = str(get_ci(pho, "Hfunc", "HG")).upper()
    if hfunc != "HG":
        raise IsisError(f"{where}: invalid Hfunc {hfunc} (only HG)")
    try:
        reference = tuple(float(get_ci(pho, k)) for k in ("Incref", "EmiRef", "Pharef"))
    except TypeError:
        raise IsisError(f"{where}: PhotometricModel needs Incref, EmiRef and Pharef") from None
    names = [str(n).upper() for n in map_band_names]
    out = []
    for g in groups(pho, "Parameters"):
        bands = get_ci(g, "Bands", [])
        bands = bands if isinstance(bands, (list, tuple)) else [bands]
        if any(not 1 <= int(b) <= len(names) for b in bands):
            raise IsisError(f"{where}: Parameters group names bands {bands} beyond the map's {len(names)} bands")
        out.append(HapkeGroup(float(get_ci(g, "BandBinCenter")), {names[int(b) - 1]: int(b) - 1 for b in bands}))
    if not out:
        raise IsisError(f"{where}: PhotometricModel has no Parameters groups")
    return HapkeMapParams(reference, str(get_ci(pho, "Units", "Radians")).upper() == "DEGREES", hfunc, out)
