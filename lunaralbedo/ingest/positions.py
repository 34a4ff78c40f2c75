"""Sun and spacecraft positions of cubes at their ``campt`` centre time (replaces
``get_sun_or_spacecraft_position.pl``).  Positions: km, Moon-centred body-fixed (MOON_ME)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..io.positions import write_positions
from ..spice.kernels import expand_kernel_args
from .keys import make_keys
from .observation import open_observation


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
    for path, key in zip(paths, make_keys(paths)):
        with open_observation(path, key, extra, isisdata, source) as obs:
            out.append(ImagePositions(key, Path(path), obs.et, obs.source, obs.sun.copy(), obs.spacecraft.copy()))
    return out


def write_position_files(results: Sequence[ImagePositions], sun_file: str | Path, spacecraft_file: str | Path) -> None:
    """Write the legacy ``KEY x y z`` files (atomically)."""
    write_positions(sun_file, {r.key: r.sun for r in results})
    write_positions(spacecraft_file, {r.key: r.spacecraft for r in results})
