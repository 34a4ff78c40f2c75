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
    """Positions of every cube/label in ``paths`` (raises on the first failure, naming the file)."""
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
