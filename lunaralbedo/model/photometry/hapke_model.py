r"""Hapke model (REFLECTANCE_TYPE 3, TOML ``reflectance = "hapke"``): normalised to a reference geometry, as ``lrowacphomap``.

The solved albedo is the reflectance the surface would have at the reference geometry
:math:`(i_r, e_r, g_r)` (``Incref``, ``Emiref``, ``Pharef``), so the model reflectance of an
observation at :math:`(i, e, g)` is

.. math:: R = \frac{r_H(i, e, g; \mathbf{p})}{r_H(i_r, e_r, g_r; \mathbf{p})}

with :math:`r_H` one of ISIS's Hapke variants (:mod:`.hapke`, the one implementation) and
the parameters :math:`\mathbf{p}` constant or per ground point (parameter map).  With
:math:`I = A\,T\,R` (eq. 1's model) the albedo :math:`A = I / (T R)` is exactly the
``lrowacphomap`` correction :math:`(I/T)\,r_H(i_r,e_r,g_r)/r_H(i,e,g)`.  Hapke has no
fitted parameters in the solver (the phase behaviour is in :math:`\mathbf{p}`).

Settings the model declares: ``HAPKE_PARAMETERS`` (an ISIS-style PVL, required),
``HAPKE_PARAMETER_MAP`` (optional parameter cube) and ``HAPKE_BAND_CENTER`` (nm: which
``Parameters`` group, when the PVL has several).  The PVL is an object ``PhotometricModel``
with ``Units``, ``Incref``, ``Emiref``, ``Pharef``, a group ``Algorithm`` whose ``Name``
picks the variant (HapkeLROC, HapkeHen, HapkeLeg) and ``Parameters`` groups holding either
``BandBinCenter`` + ``Bands`` (1-based bands of the map, named by its ``BandBin/Name``, as
``hapke_full_reformatted.pvl``) or the constants themselves (``W, B, C, BCO, HC, BSO, HS,
THETA, PHI`` for HapkeLROC; ISIS photomet's ``Wh, B0, Hh, Theta, Hg1, Hg2`` / ``Bh, Ch`` for
HapkeHen / HapkeLeg, also accepted in the ``Algorithm`` group).  The files are read by the
engine (:mod:`lunaralbedo.engine.photometry`); this module sees their contents only
(plain PVL values, an in-memory parameter map).  Angles in degrees; pure NumPy.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import SettingsError
from .base import PhotometricModel
from .hapke import HAPKE_LROC_PARAMETERS, hapke_hen, hapke_leg, hapke_lroc

#: ISIS algorithm name (upper case) -> (function, parameter names in call order, argument order of the angles).
VARIANTS = {
    "HAPKELROC": (hapke_lroc, HAPKE_LROC_PARAMETERS, "ieg"),
    "HAPKEHEN": (hapke_hen, ("WH", "B0", "HH", "THETA", "HG1", "HG2"), "gie"),
    "HAPKELEG": (hapke_leg, ("WH", "B0", "HH", "THETA", "BH", "CH"), "gie"),
}

#: HapkeLROC constants of the forward model's Hapke scenes (THETA in degrees) and their reference geometry.
EXAMPLE = {"W": 0.3, "B": 0.25, "C": 0.6, "BCO": 0.9, "HC": 0.06, "BSO": 1.6, "HS": 0.07, "THETA": 20.0, "PHI": 0.4}
EXAMPLE_REFERENCE = (60.0, 0.0, 60.0)


@dataclass
class HapkeModel:
    """A Hapke variant, its reference geometry (degrees) and constant parameters (THETA in degrees).

    Parameters missing from ``constants`` come per ground point (``params`` argument of
    :meth:`normalised`).
    """

    variant: str
    reference: tuple[float, float, float]
    constants: dict[str, float] = field(default_factory=dict)

    def __post_init__(self):
        self.variant = self.variant.upper()
        if self.variant not in VARIANTS:
            raise ValueError(f"Hapke variant must be one of {', '.join(VARIANTS)}, got {self.variant!r}")

    @property
    def names(self) -> tuple[str, ...]:
        return VARIANTS[self.variant][1]

    def reflectance(self, i_deg, e_deg, g_deg, params: dict | None = None):
        """:math:`r_H(i, e, g)` with the constants, overridden by per-point ``params`` arrays."""
        fn, names, order = VARIANTS[self.variant]
        p = {**self.constants, **(params or {})}
        angles = {"i": i_deg, "e": e_deg, "g": g_deg}
        return fn(*(angles[c] for c in order), *(p[n] for n in names))

    def normalised(self, cos_i, cos_e, alpha_rad, params: dict | None = None):
        """:math:`R = r_H(i,e,g)/r_H(i_r,e_r,g_r)`; 0 where unlit or unseen (cos i or cos e <= 0)."""
        ci = np.asarray(cos_i, dtype=np.float64)
        ce = np.asarray(cos_e, dtype=np.float64)
        seen = (ci > 0) & (ce > 0)
        i = np.degrees(np.arccos(np.clip(ci, -1, 1)))
        e = np.degrees(np.arccos(np.clip(ce, -1, 1)))
        g = np.degrees(np.asarray(alpha_rad, dtype=np.float64))
        with np.errstate(invalid="ignore", divide="ignore"):
            r = self.reflectance(i, e, g, params) / self.reflectance(*self.reference, params)
        return np.where(seen & np.isfinite(r), r, 0.0)


@dataclass
class PointParameters:
    """Per-ground-point parameters from a parameter map (``pixel``/``data`` of an ISIS parameter cube)."""

    pmap: object  #: :class:`lunaralbedo.isis.parameter_map.ParameterMap` (duck-typed: ``pixel``, ``data``)
    bands: dict[str, int]  #: parameter name -> 0-based map band

    def __call__(self, lon_deg, lat_deg) -> dict:
        """Parameters at east longitude / latitude (degrees); NaN outside the map or at its special pixels."""
        rows, cols, inside = self.pmap.pixel(lat_deg, lon_deg)
        return {n: np.where(inside, self.pmap.data[b][rows, cols].astype(np.float64), np.nan) for n, b in self.bands.items()}


def pvl_text(constants: dict, reference=EXAMPLE_REFERENCE) -> str:
    """An ISIS-style HapkeLROC parameter file with constant parameters (a HAPKE_PARAMETERS file)."""
    lines = ["Object = PhotometricModel", "  Units  = Degrees"]
    lines += [f"  {k} = {v:g}" for k, v in zip(("Incref", "Emiref", "Pharef"), reference)]
    lines += ["  Group = Algorithm", "    Name = HapkeLROC", "  EndGroup", "  Group = Parameters"]
    lines += [f"    {k} = {v:g}" for k, v in constants.items()]
    lines += ["  EndGroup", "EndObject", "End"]
    return "\n".join(lines) + "\n"


def _choose(groups: list[dict], center: float | None, where: str) -> dict:
    if len(groups) == 1:
        return groups[0]
    centers = [float(g.get("BANDBINCENTER", math.nan)) for g in groups]
    listed = ", ".join(f"{c:g}" for c in centers)
    if center is None:
        raise SettingsError(f"{where}: {len(groups)} Parameters groups ({listed} nm); "
                            "set HAPKE_BAND_CENTER to the images' band centre (nm)")
    for g, c in zip(groups, centers):
        if c == float(center):
            return g
    raise SettingsError(f"{where}: no Parameters group for HAPKE_BAND_CENTER {center:g} nm (groups: {listed})")


def _map_bands(group: dict, variant: str, pmap, where: str, map_path) -> dict[str, int]:
    """Parameter name -> 0-based map band of a ``Bands`` group (names from the map's ``BandBin/Name``)."""
    if pmap is None:
        raise SettingsError(f"{where}: Parameters name map bands; set HAPKE_PARAMETER_MAP to the parameter cube")
    if variant != "HAPKELROC":
        raise SettingsError(f"{where}: a parameter map is supported for HapkeLROC only, not {variant}")
    bands = group["BANDS"] if isinstance(group["BANDS"], (list, tuple)) else [group["BANDS"]]
    names = [str(n).upper() for n in pmap.band_names]
    if any(not 1 <= int(b) <= len(names) for b in bands):
        raise SettingsError(f"{where}: Parameters group names bands {list(bands)} beyond the map's {len(names)} bands")
    got = {names[int(b) - 1]: int(b) - 1 for b in bands}
    missing = [n for n in VARIANTS[variant][1] if n not in got]
    if missing:
        raise SettingsError(f"{map_path}: parameter map has no band for {', '.join(missing)}")
    return {n: got[n] for n in VARIANTS[variant][1]}


def _constants(group: dict, algo: dict, variant: str, degrees: bool, where: str) -> dict[str, float]:
    out = {}
    for n in VARIANTS[variant][1]:
        v = group.get(n, algo.get(n))
        if v is None:
            raise SettingsError(f"{where}: {variant} parameter {n} is missing")
        try:
            out[n] = float(v)
        except (TypeError, ValueError):
            raise SettingsError(f"{where}: {n} = {v!r} is not a number") from None
    if not degrees:
        out["THETA"] = math.degrees(out["THETA"])
    return out


def setup(pho: dict, where: str, band_center: float | None = None, pmap=None, map_path=None):
    """``(HapkeModel, per-point parameters or None)`` from a plain ``PhotometricModel`` object (upper-case keys).

    :class:`SettingsError` naming ``where`` on any problem.
    """
    algo = next(iter(pho.get("ALGORITHM", [])), {})
    variant = str(algo.get("NAME", "")).upper()
    if variant not in VARIANTS:
        raise SettingsError(f"{where}: Algorithm Name {variant!r} is not one of HapkeLROC, HapkeHen, HapkeLeg")
    try:
        reference = tuple(float(pho[k]) for k in ("INCREF", "EMIREF", "PHAREF"))
    except (KeyError, TypeError, ValueError):
        raise SettingsError(f"{where}: PhotometricModel needs Incref, Emiref and Pharef") from None
    group = _choose(pho.get("PARAMETERS") or [algo], band_center, where)
    if "BANDS" in group:
        return HapkeModel(variant, reference), PointParameters(pmap, _map_bands(group, variant, pmap, where, map_path))
    degrees = str(pho.get("UNITS", "Degrees")).upper() == "DEGREES"
    return HapkeModel(variant, reference, _constants(group, algo, variant, degrees, where)), None


def _validate(values, where: str) -> None:
    if values.get("HAPKE_PARAMETERS") is None:
        raise SettingsError(f"{where}: HAPKE_PARAMETERS (an ISIS-style PVL) is required by the hapke reflectance model")
    center = values.get("HAPKE_BAND_CENTER")
    if center is not None and not center > 0:
        raise SettingsError(f"{where}: HAPKE_BAND_CENTER must be a wavelength > 0 nm, got {center}")


def _unbound(*_args, **_kw):
    raise SettingsError("the hapke reflectance model needs its HAPKE_PARAMETERS file: use the model bound to the "
                        "settings (lunaralbedo.engine.photometry.solver_model)")


def configure(values, contents, where: str) -> PhotometricModel:
    """The model bound to its settings: ``contents`` holds what the engine read (plain PVL, parameter map)."""
    hapke, points = setup(contents["HAPKE_PARAMETERS"], str(values["HAPKE_PARAMETERS"]), values.get("HAPKE_BAND_CENTER"),
                          contents.get("HAPKE_PARAMETER_MAP"), values.get("HAPKE_PARAMETER_MAP"))

    def layers(cos_i, cos_e, alpha, lon=None, lat=None):
        if points is not None and lon is None:
            raise SettingsError(f"{where}: the Hapke parameter map needs the ground points' longitude and latitude")
        return {"geometric": hapke.normalised(cos_i, cos_e, alpha, points(lon, lat) if points is not None else None)}

    def reflectance(cos_i, cos_e, alpha, params=(), lon=None, lat=None):
        return layers(cos_i, cos_e, alpha, lon, lat)["geometric"]

    return dataclasses.replace(MODEL, layers=layers, reflectance=reflectance, configure=None,
                               needs_location=points is not None)


MODEL = PhotometricModel(
    name="hapke",
    code=3,
    description="Hapke (HapkeLROC/HapkeHen/HapkeLeg of an ISIS PVL), normalised to Incref/Emiref/Pharef",
    layers=_unbound,
    layer_names=("geometric",),
    reflectance_from=lambda arrays, params=(): arrays["geometric"],
    reflectance=_unbound,
    settings={"HAPKE_PARAMETERS": (Path, None, None), "HAPKE_PARAMETER_MAP": (Path, None, None),
              "HAPKE_BAND_CENTER": (float, None, None)},
    validate=_validate,
    files={"HAPKE_PARAMETERS": "photometric-pvl", "HAPKE_PARAMETER_MAP": "parameter-map"},
    configure=configure,
    examples={"HAPKE_PARAMETERS": ("hapke.pvl", pvl_text(EXAMPLE))},
)
