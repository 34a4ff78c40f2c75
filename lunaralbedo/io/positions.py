"""Sun and spacecraft position files: one ``KEY x y z`` line per image.

Positions are in km in the Moon-centred body-fixed frame (the PhotometryTK manual, section 6).
KEY is the 11-character lookup key taken from the start of the DRG file name.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from ..errors import InputError, MissingPositionError
from .atomic import atomic_write_text


def read_positions(path: str | Path) -> dict[str, np.ndarray]:
    """Read a position file into ``{key: array([x, y, z]) (km, float64)}``.

    Blank lines and ``#`` comments are ignored; a later line for the same key
    replaces an earlier one (as the legacy program's map did).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: position file not found")
    out: dict[str, np.ndarray] = {}
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 4:
            raise InputError(f"{path}:{lineno}: expected 'KEY x y z', got {line!r}")
        try:
            xyz = np.array([float(v) for v in parts[1:]], dtype=np.float64)
        except ValueError:
            raise InputError(f"{path}:{lineno}: coordinates are not numbers: {line!r}") from None
        if not np.all(np.isfinite(xyz)):
            raise InputError(f"{path}:{lineno}: coordinates are not finite: {line!r}")
        out[parts[0]] = xyz
    return out


def write_positions(path: str | Path, positions: Mapping[str, np.ndarray]) -> None:
    """Write ``{key: xyz_km}`` as a legacy position file (atomically)."""
    lines = [f"{k} {p[0]:.17g} {p[1]:.17g} {p[2]:.17g}" for k, p in positions.items()]
    atomic_write_text(path, "\n".join(lines) + "\n")


def lookup(positions: Mapping[str, np.ndarray], key: str, source: str | Path) -> np.ndarray:
    """The position of ``key``; :class:`MissingPositionError` naming key and file if absent."""
    try:
        return positions[key]
    except KeyError:
        raise MissingPositionError(f"{source}: no position line for image key {key!r}") from None
