"""The 11-character lookup keys of images (the solver matches DRGs and positions by them).

Rule: the key is the cube's file name up to its first ``.`` (e.g. ``M143947267L``
from ``M143947267L.cal.echo.crop.cub``), cut to 11 characters or padded with
``_`` to 11.  When two cubes would share a key, the later ones (in the order
given) get their last three characters replaced by a counter ``001``, ``002``, ...
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from ..constants import KEY_LENGTH


def base_key(path: str | Path) -> str:
    stem = Path(path).name.split(".", 1)[0]
    return stem[:KEY_LENGTH].ljust(KEY_LENGTH, "_")


def make_keys(paths: Sequence[str | Path]) -> list[str]:
    """Unique 11-character keys for ``paths`` (see the module docstring)."""
    keys: list[str] = []
    used: set[str] = set()
    for p in paths:
        key = base_key(p)
        n = 0
        while key in used:
            n += 1
            key = base_key(p)[: KEY_LENGTH - 3] + f"{n:03d}"
        used.add(key)
        keys.append(key)
    return keys
