"""Which lunar instrument an ISIS label belongs to, for the cameras ISIS models specially.

``instrument_of`` names the instrument (ISIS camera plugin in brackets):

* ``kaguya_mi``  - SELENE/Kaguya Multiband Imager, VIS or NIR head (``KaguyaMiCamera``);
* ``kaguya_tc``  - SELENE/Kaguya Terrain Camera TC1/TC2 (``KaguyaTcCamera``);
* ``clementine_uvvis`` - Clementine UV/VIS camera, one filter per cube (``UvvisCamera``);
* ``chandrayaan2_tmc2`` - Chandrayaan-2 Terrain Mapping Camera-2 (``Chandrayaan2TmcCamera``);

and None for every other label (the generic frame/line-scanner models apply).
"""
from __future__ import annotations

import re

from ..errors import IsisError
from ..isis.labels import IsisLabel, value_of

KAGUYA_MI, KAGUYA_TC = "kaguya_mi", "kaguya_tc"
CLEMENTINE_UVVIS, CHANDRAYAAN2_TMC2 = "clementine_uvvis", "chandrayaan2_tmc2"
#: instruments whose bands are co-registered images of one camera geometry: one DRG per band
MULTIBAND = (KAGUYA_MI,)


def _text(inst, key) -> str:
    return str(value_of(inst.get(key, ""))).strip().upper()


def instrument_of(label: IsisLabel) -> str | None:
    """The instrument name (module docstring) of a Level-1 label, or None."""
    if not label.has("Instrument"):
        return None
    inst = label.instrument
    sc, iid = _text(inst, "SpacecraftName"), _text(inst, "InstrumentId")
    if sc in ("KAGUYA", "SELENE") or _text(inst, "MissionName") == "SELENE":
        if iid.startswith("MI-"):
            return KAGUYA_MI
        if iid in ("TC1", "TC2"):
            return KAGUYA_TC
    if sc.startswith("CLEMENTINE") and iid == "UVVIS":
        return CLEMENTINE_UVVIS
    if sc.replace(" ", "") in ("CHANDRAYAAN-2", "CHANDRAYAAN2") and ("TMC" in iid):
        return CHANDRAYAAN2_TMC2
    return None


def band_centers_nm(label: IsisLabel) -> list[float]:
    """``BandBin/Center`` of every band in nanometres (micrometre values, e.g. Clementine's, converted)."""
    c = label.group("BandBin")["Center"]
    units = str(getattr(c, "units", "") or "").lower()
    vals = []
    for x in (value_of(c) if isinstance(value_of(c), (list, tuple)) else [c]):
        m = re.match(r"\s*([-+0-9.eE]+)\s*(\S*)", str(value_of(x)))  # e.g. Kaguya TC's "640nm"
        if m is None:
            raise IsisError(f"{label.path}: BandBin/Center {x!r} is not a number")
        vals.append(float(m.group(1)))
        units = units or m.group(2).lower()
    if units.startswith("micro") or units in ("um", "µm") or (not units and max(vals) < 10.0):
        vals = [v * 1000.0 for v in vals]
    return vals
