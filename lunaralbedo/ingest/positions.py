"""Sun and spacecraft positions of cubes at their ``campt`` centre time (replaces
``get_sun_or_spacecraft_position.pl``).  Positions: km, Moon-centred body-fixed (MOON_ME).

Keys and times follow ``ingest`` (:func:`.keys.band_items`, :func:`.observation.band_time`): a
multi-band push-frame cube (LRO WAC) gets one line per band, ``M1181493B01`` .. ``B05``, at
that band's centre framelet time, so the position files match the DRGs ``ingest`` writes."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..io.positions import write_positions
from ..spice.kernels import expand_kernel_args
from .keys import band_items
from .observation import band_time, open_observation


@dataclass(frozen=True)
class ImagePositions:
    """Positions of one image (km, body-fixed) and where they came from."""

    key: str
    path: Path
    et: float
    source: str
    sun: np.ndarray
    spacecraft: np.ndarray


def compute_positions(paths: Sequence[str | Path], kernels: Sequence[str | Path] = (), isisdata=None,
                      source: str = "auto") -> list[ImagePositions]:
    """Compute the Sun and spacecraft positions of cubes at their ``campt`` centre time.

    Replaces the PhotometryTK manual's ``get_sun_or_spacecraft_position.pl`` (which ran ISIS
    ``campt``).  The time is the image's centre time as ``campt`` gives it; a multi-band
    push-frame cube (LRO WAC) gets one entry per band, ``<8 characters>B01`` .., at that
    band's centre framelet time, so keys and times match the DRGs ``ingest`` writes.

    Parameters
    ----------
    paths : sequence of str or Path
        ISIS3 cubes or detached labels (``spiceinit``-ed or with resolvable kernels).
    kernels : sequence of str or Path, optional
        Extra SPICE kernels, kernel folders or meta-kernels, loaded after the kernels of each
        label's ``Kernels`` group.
    isisdata : str or Path, optional
        ISIS data area that resolves ``$base``/``$<mission>`` kernel paths of the labels.
    source : {"auto", "table", "kernels"}, default "auto"
        Ephemeris source: the cube's attached SPICE tables when present (``auto``), only
        the tables, or only the kernels.

    Returns
    -------
    list of ImagePositions
        One per image (band), in the order of ``paths``: ``key`` (11-character DRG key),
        ``path``, ``et`` (s past J2000, TDB), ``source`` (``"table"`` or ``"kernels"``),
        ``sun`` and ``spacecraft`` (float64 ``(3,)`` arrays, km, Moon-centred body-fixed
        MOON_ME).

    Raises
    ------
    InputError
        Exit 2, on the first image that fails, naming the file: an invalid ``source``.
    IsisError
        Exit 2: a label without an Instrument group, missing SPICE tables with
        ``source="table"``, a centre time outside the tables.
    SpiceError
        Exit 2: no leapseconds kernel, a missing kernel or a time the kernels do not cover.
    """
    extra = expand_kernel_args(kernels)
    out = []
    for path, key, band, _center in band_items(paths):
        with open_observation(path, key, extra, isisdata, source) as obs:
            et = band_time(obs, band)
            sun, sc = (np.asarray(f(et), dtype=np.float64) for f in (obs.ephemeris.sun, obs.ephemeris.spacecraft))
            out.append(ImagePositions(key, Path(path), et, obs.source, sun, sc))
    return out


def write_position_files(results: Sequence[ImagePositions], sun_file: str | Path, spacecraft_file: str | Path) -> None:
    """Write the legacy ``KEY x y z`` files (atomically)."""
    write_positions(sun_file, {r.key: r.sun for r in results})
    write_positions(spacecraft_file, {r.key: r.spacecraft for r in results})
