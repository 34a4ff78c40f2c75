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


def _bands(path: Path) -> list[float | None]:
    """Band centres (nm) of a Level-1 push-frame or multi-band camera cube (e.g. Kaguya MI; one DRG each),
    ``[centre]`` of a single-band cube of an instrument of ``camera.instruments`` (e.g. a Clementine UVVIS
    filter), else ``[None]`` (band 1 only)."""
    from ..camera.instruments import MULTIBAND, band_centers_nm, instrument_of
    from ..camera.timing import camera_kind
    from ..errors import LunarAlbedoError
    from ..isis.labels import read_label

    try:
        label = read_label(path)
        if label.is_map_projected or not label.has("Instrument"):
            return [None]
        name = instrument_of(label)
        if camera_kind(label) != "pushframe" and name not in MULTIBAND:
            return band_centers_nm(label)[:1] if name is not None else [None]
        centers = band_centers_nm(label)
        return centers if len(centers) == label.shape[0] else [None]
    except (LunarAlbedoError, KeyError, ValueError, TypeError):
        return [None]  # the cube's own task reports what is wrong with it


def band_items(paths: Sequence[str | Path]) -> list[tuple[Path, str, int, float | None]]:
    """``(path, key, band, centre nm)`` per DRG to make: one per band of multi-band push-frame cubes.

    Band ``b`` of such a cube gets the key ``<first 8 characters of its key>B<bb>`` (e.g. ``M1181493B01``).
    """
    items = []
    for path, key in zip(paths, make_keys(paths)):
        centers = _bands(Path(path))
        if len(centers) == 1:
            items.append((Path(path), key, 1, centers[0]))
        else:
            items.extend((Path(path), key[: KEY_LENGTH - 3] + f"B{b:02d}", b, c) for b, c in enumerate(centers, 1))
    return items
