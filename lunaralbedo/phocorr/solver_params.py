"""Hapke settings of the solver: the ISIS-style PVL (and optional parameter map) -> a model and per-point parameters.

The PVL is an object ``PhotometricModel`` with ``Units``, ``Incref``, ``Emiref``,
``Pharef``, a group ``Algorithm`` whose ``Name`` picks the variant (HapkeLROC,
HapkeHen, HapkeLeg), and ``Parameters`` groups holding either ``BandBinCenter`` +
``Bands`` (indices into the parameter map, as ``hapke_full_reformatted.pvl``; parsed by
:func:`.params.load_hapke_map`) or the constants themselves (``W, B, C, BCO, HC, BSO,
HS, THETA, PHI`` for HapkeLROC; ISIS photomet's ``Wh, B0, Hh, Theta, Hg1, Hg2`` /
``Bh, Ch`` for HapkeHen / HapkeLeg, also accepted in the ``Algorithm`` group).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import IsisError, SettingsError
from ..isis.pvlfile import find_object, get_ci, groups, read_pvl
from ..model.photometry.hapke_solver import VARIANTS, HapkeModel


@dataclass
class SolverHapke:
    """The model and, with a map, the parameter-map group (band index per parameter name)."""

    model: HapkeModel
    map_path: Path | None = None
    map_bands: dict[str, int] | None = None

    def params_at(self, lon_deg, lat_deg) -> dict:
        """Per-point parameters (empty without a map); NaN outside the map or at its special pixels."""
        if self.map_path is None:
            return {}
        pmap = _parameter_map(str(self.map_path))
        rows, cols, inside = pmap.pixel(lat_deg, lon_deg)
        out = {}
        for name, band in self.map_bands.items():
            v = pmap.data[band][rows, cols].astype(np.float64)
            out[name] = np.where(inside, v, np.nan)
        return out


@lru_cache(maxsize=2)
def _parameter_map(path: str):
    from .hapkemap import read_parameter_map

    return read_parameter_map(path)


def _choose(groups_: list, center: float | None, where: str):
    if len(groups_) == 1:
        return groups_[0]
    centers = [float(get_ci(g, "BandBinCenter", math.nan)) for g in groups_]
    if center is None:
        raise SettingsError(f"{where}: {len(groups_)} Parameters groups ({', '.join(f'{c:g}' for c in centers)} nm); "
                            "set HAPKE_BAND_CENTER to the images' band centre (nm)")
    for g, c in zip(groups_, centers):
        if c == float(center):
            return g
    raise SettingsError(f"{where}: no Parameters group for HAPKE_BAND_CENTER {center:g} nm "
                        f"(groups: {', '.join(f'{c:g}' for c in centers)})")


def load_solver_hapke(pvl_path: Path, map_path: Path | None = None, band_center: float | None = None) -> SolverHapke:
    """Parse the solver's Hapke settings; :class:`SettingsError` naming the file on any problem."""
    where = str(pvl_path)
    try:
        pho = find_object(read_pvl(pvl_path), "PhotometricModel", where)
    except IsisError as exc:
        raise SettingsError(str(exc)) from None
    algo = next(iter(groups(pho, "Algorithm")), {})
    variant = str(get_ci(algo, "Name", "")).upper()
    if variant not in VARIANTS:
        raise SettingsError(f"{where}: Algorithm Name {variant!r} is not one of HapkeLROC, HapkeHen, HapkeLeg")
    try:
        reference = tuple(float(get_ci(pho, k)) for k in ("Incref", "Emiref", "Pharef"))
    except TypeError:
        raise SettingsError(f"{where}: PhotometricModel needs Incref, Emiref and Pharef") from None
    degrees = str(get_ci(pho, "Units", "Degrees")).upper() == "DEGREES"
    group = _choose(groups(pho, "Parameters") or [algo], band_center, where)
    names = VARIANTS[variant][1]
    if get_ci(group, "Bands") is not None:
        if map_path is None:
            raise SettingsError(f"{where}: Parameters name map bands; set HAPKE_PARAMETER_MAP to the parameter cube")
        if variant != "HAPKELROC":
            raise SettingsError(f"{where}: a parameter map is supported for HapkeLROC only, not {variant}")
        from .params import load_hapke_map

        try:
            pmap = _parameter_map(str(map_path))
            parsed = load_hapke_map(pvl_path, pmap.band_names)
        except IsisError as exc:
            raise SettingsError(str(exc)) from None
        center = float(get_ci(group, "BandBinCenter"))
        bands = next(g.bands for g in parsed.groups if g.center == center)
        missing = [n for n in names if n not in bands]
        if missing:
            raise SettingsError(f"{map_path}: parameter map has no band for {', '.join(missing)}")
        return SolverHapke(HapkeModel(variant, reference), Path(map_path), {n: bands[n] for n in names})
    constants = {}
    for n in names:
        v = get_ci(group, n, get_ci(algo, n))
        if v is None:
            raise SettingsError(f"{where}: {variant} parameter {n} is missing")
        try:
            constants[n] = float(v)
        except (TypeError, ValueError):
            raise SettingsError(f"{where}: {n} = {v!r} is not a number") from None
    if not degrees:
        constants["THETA"] = math.degrees(constants["THETA"])
    return SolverHapke(HapkeModel(variant, reference, constants))
