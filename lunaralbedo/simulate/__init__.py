"""The forward model: synthetic scenes rendered from a known Moon, in every input contract of the product.

One forward model (:mod:`.forward`: Sun geometry, :math:`A\\,T\\,R` of eq. 1 with the photometric
registry, the recording as 8-bit DN or float radiance), one truth format (:mod:`.truth`), and
the scenes built on them:

* :mod:`.strip` — a strip of DRGs in the solver's input contract (``lunaralbedo simulate OUT``);
* :mod:`.mission` — Level-1 ISIS cubes with SPICE kernels and a DEM, the ingest contract
  (``lunaralbedo simulate OUT --format isis``; ``sample_data/`` is one);
* :mod:`.nacpair` — an LRO-NAC-like LE/RE line-scanner pair with a known boresight error.

:func:`score` compares a solve's outputs with any scene's truth.
"""
from __future__ import annotations

import numpy as np

from .fields import fresh_craters, truth_albedo, truth_dem
from .strip import SceneSpec, render_scene
from .truth import read_truth, score, true_exposures

__all__ = ["SceneSpec", "fresh_craters", "read_truth", "render_mission", "render_scene", "score", "true_exposures",
           "truth_albedo", "truth_dem"]


def render_mission(out_dir, seed: int = 20240601, n_frames: int = 5, with_line: bool = False, noise: float = 0.005) -> dict:
    """Render the synthetic mission (:func:`.mission.build`) into a new or empty ``out_dir``; return its truth.

    Imported lazily: the mission needs spiceypy and the kernel writers, the strip does not.
    """
    from ..errors import InputError
    from .mission import build
    from .truth import render_into

    if not isinstance(n_frames, int) or isinstance(n_frames, bool) or n_frames < 1:
        raise InputError(f"--images (n_frames) must be an integer >= 1, got {n_frames!r}")
    if not (np.isfinite(noise) and noise >= 0):
        raise InputError(f"noise must be a number >= 0, got {noise!r}")
    return render_into(out_dir, lambda out: build(out, seed=seed, n_frames=n_frames, with_line=with_line, noise=noise))
