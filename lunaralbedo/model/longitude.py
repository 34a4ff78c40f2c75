"""Longitudes across the ±180° meridian: continuous ranges (pure functions, degrees).

Everything that spans the antimeridian (footprints, SIMULATION_BOX, tiles) is kept in
*continuous* longitudes: a range is ``(west, east)`` with ``west < east`` and
``east - west <= 360``, where ``east`` may exceed 180 (e.g. 170..190 for a box written
``170:-170``).  Files may use either convention: a DRG at -180..-170 and a tile at
180..190 cover the same ground; :func:`overlap_shifts` gives the multiples of 360°
that line them up.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np


def wrap180(lon: float) -> float:
    """``lon`` (degrees) brought into [-180, 180)."""
    return ((lon + 180.0) % 360.0) - 180.0


def continuous_span(lon, base: float = -180.0) -> tuple[float, float] | None:
    """Smallest ``(west, east)`` range holding every finite longitude of ``lon`` (degrees).

    Longitudes are taken modulo 360; ``west`` lies in ``[base, base + 360)`` and ``east``
    may pass ``base + 360`` when the points straddle that cut (e.g. 179.5 and -179.6 give
    179.5..180.4).  The range opens at the widest gap between the points, so a set that
    does not straddle the cut gives plain ``(min, max)``.  None without finite values.
    """
    v = np.asarray(lon, dtype=np.float64).ravel()
    v = np.sort(np.mod(v[np.isfinite(v)] - base, 360.0)) + base
    if v.size == 0:
        return None
    gaps = np.diff(np.append(v, v[0] + 360.0))  # gap after each point, the last one across the cut
    k = int(np.argmax(gaps))
    if k == v.size - 1:  # widest gap is across the cut: no wrap
        return float(v[0]), float(v[-1])
    return float(v[k + 1]), float(v[k] + 360.0)


def longitude_shifts(intervals: Sequence[tuple[float, float]]) -> list[float]:
    """Shifts (multiples of 360) that make the ``(west, east)`` intervals one continuous range.

    Wests are first normalised to [-180, 180); the cut goes into the widest gap of
    the circular coverage, so intervals on both sides of ±180° end up side by side.
    """
    if not intervals:
        return []
    norm = [wrap180(w) - w for w, _ in intervals]  # shift bringing west into [-180, 180)
    spans = sorted(((w + d, e + d) for (w, e), d in zip(intervals, norm)))
    best_gap, start = -math.inf, spans[0][0]
    reach = spans[0][1]
    for w, e in spans[1:]:
        if w - reach > best_gap + 1e-9:
            best_gap, start = w - reach, w
        reach = max(reach, e)
    if spans[0][0] + 360.0 - reach >= best_gap - 1e-9:  # the gap across ±180° is the widest: no cut needed
        start = spans[0][0]
    return [d + (360.0 if w + d < start - 1e-9 else 0.0) for (w, _), d in zip(intervals, norm)]


def union_span(intervals: Sequence[tuple[float, float]], base: float = -180.0) -> tuple[float, float]:
    """The continuous ``(west, east)`` union of ``(west, east)`` intervals, ``west`` in ``[base, base + 360)``."""
    shifts = longitude_shifts(intervals)
    west = min(w + d for (w, _), d in zip(intervals, shifts))
    east = max(e + d for (_, e), d in zip(intervals, shifts))
    east = min(east, west + 360.0)
    k = 360.0 * math.floor((west - base) / 360.0)
    return west - k, east - k


def box_longitudes(lon_min: float, lon_max: float) -> tuple[float, float]:
    """A box's longitudes made continuous: ``170, -170`` -> ``170, 190`` (``lon_max`` + 360 when below ``lon_min``)."""
    if lon_max < lon_min:
        lon_max += 360.0
    return lon_min, lon_max


def overlap_shifts(bounds: Sequence[float], box: Sequence[float], eps: float = 0.0) -> list[float]:
    """Shifts ``s`` (multiples of 360°) for which ``bounds`` moved by ``s`` overlaps ``box`` in longitude.

    Both are ``(west, south, east, north)`` in degrees; latitudes must overlap too
    (else ``[]``).  The overlap must exceed ``eps`` degrees.  Most often ``[0.0]``; a
    DRG at -180..-170 and a tile at 180..190 give ``[360.0]``.
    """
    if not (bounds[1] < box[3] - eps and box[1] < bounds[3] - eps):
        return []
    k0 = math.floor((box[0] - bounds[2]) / 360.0)
    k1 = math.ceil((box[2] - bounds[0]) / 360.0)
    out = []
    for k in range(k0, k1 + 1):
        s = 360.0 * k
        if bounds[0] + s < box[2] - eps and box[0] < bounds[2] + s - eps:
            out.append(s)
    return sorted(out, key=abs)
