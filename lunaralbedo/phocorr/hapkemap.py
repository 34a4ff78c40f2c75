"""``lrowacphomap``: HapkeLROC with per-pixel parameters from a map, correct and ISIS-compatible modes.

The parameter map is an Equirectangular cube (:mod:`lunaralbedo.isis.parameter_map`).

Correct mode: the ``Parameters`` group whose ``BandBinCenter`` equals the image band's
centre, and ``r(i_r, e_r, g_r) / r(i, e, g)`` from that one group.
``isis_compat`` reproduces two defects of ISIS (documented in docs/photometry.md):
(1) with one band selected, groups whose centre is not the band's keep ISIS's default
band 1, so every group "matches" and the last one in the file is used; (2) the result
cache keyed only on (i, e, g) gives every matching group the reference value of the
first matching group.  Points outside the map give 0 (ISIS) or NaN (correct mode).
"""
from __future__ import annotations

import numpy as np

from ..errors import IsisError
from ..isis.parameter_map import ParameterMap
from ..model.photometry.hapke import HAPKE_LROC_PARAMETERS, hapke_lroc
from .params import HapkeMapParams


def isis_group_choice(params: HapkeMapParams, selected_centers, band: int) -> tuple[int, int]:
    """ISIS's ``(group used for the pixel, group giving the reference value)`` for virtual band ``band`` (1-based).

    Each group's band is the last selected band whose centre equals its ``BandBinCenter``,
    else 1; the pixel uses the last group whose band is ``band``, the reference value
    comes from the first (result cache).
    """
    owner = []
    for g in params.groups:
        hits = [j + 1 for j, c in enumerate(selected_centers) if float(c) == g.center]
        owner.append(hits[-1] if hits else 1)
    matching = [k for k, b in enumerate(owner) if b == band]
    if not matching:
        raise IsisError(f"no Parameters group for band {band}")
    return matching[-1], matching[0]


def correct_group(params: HapkeMapParams, center: float) -> int:
    """The group whose ``BandBinCenter`` is the band's centre (nm)."""
    for k, g in enumerate(params.groups):
        if g.center == float(center):
            return k
    raise IsisError(f"no Parameters group for band centre {center} nm "
                    f"(groups: {', '.join(str(g.center) for g in params.groups)})")


def _values(pmap: ParameterMap, group, rows, cols):
    missing = [n for n in HAPKE_LROC_PARAMETERS if n not in group.bands]
    if missing:
        raise IsisError(f"{pmap.path}: the Parameters group for {group.center} nm lacks {', '.join(missing)}")
    return [pmap.data[group.bands[n]][rows, cols] for n in HAPKE_LROC_PARAMETERS]


def hapke_map_correction(params: HapkeMapParams, pmap: ParameterMap, incidence, emission, phase, lat, lon,
                         center: float, isis_compat: bool = False, selected_centers=None, band: int = 1):
    """Multiplicative correction per pixel (NaN where not computable; 0 outside the map in ISIS mode)."""
    rows, cols, inside = pmap.pixel(lat, lon)
    if isis_compat:
        used, ref = isis_group_choice(params, selected_centers if selected_centers is not None else [center], band)
    else:
        used = ref = correct_group(params, center)
    pix = _values(pmap, params.groups[used], rows, cols)
    std = _values(pmap, params.groups[ref], rows, cols)
    i_r, e_r, g_r = params.reference
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = hapke_lroc(i_r, e_r, g_r, *std) / hapke_lroc(incidence, emission, phase, *pix)
    special = np.any(~np.isfinite(np.stack(pix + std)), axis=0)
    corr = np.where(special, np.nan, corr)
    return np.where(inside, corr, 0.0 if isis_compat else np.nan)
