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
    """Render a synthetic mission in the input contract of ``ingest``: Level-1 ISIS cubes, kernels, a DEM.

    :func:`.mission.build`: a DEM and true albedo, SPICE kernels written for the scene (SPK,
    CK, LSK, PCK, FK, IK, SCLK), and frame-camera (and optionally one line-scanner) cubes
    whose radiance is :math:`A\\,T\\,R` of the PhotometryTK manual's eq. 1 with the
    Lunar-Lambert model and multiplicative noise, rendered by a pinhole model independent
    of the ingest camera code.  Imported lazily: the mission needs spiceypy and the kernel
    writers, the strip does not.  A failed render leaves no folder behind.

    Parameters
    ----------
    out_dir : str or Path
        Scene folder to write: new, or existing and empty.
    seed : int, default 20240601
        Seed of the random scene (terrain, albedo, pointing, noise).
    n_frames : int, default 5
        Frame-camera images, at least 1.
    with_line : bool, default False
        Add one line-scanner image.
    noise : float, default 0.005
        Relative standard deviation of the multiplicative noise (0: none).

    Returns
    -------
    dict
        The truth (also ``truth/truth.json``, see :mod:`.truth`): ``reflectance_type``,
        ``c1``, ``c2``, ``noise_relative``, ``seed``, ``albedo`` and ``dem`` (paths
        relative to ``out_dir``), ``frame`` and ``images``: per key its ``exposure``,
        ``sun_km`` and ``spacecraft_km`` (km, Moon body-fixed), ``cube`` and the shot's
        geometry (``kind``, ``et`` in s TDB, aim and Sun angles in degrees).

    Raises
    ------
    InputError
        Exit 2: ``n_frames`` not an integer >= 1, or ``noise`` not a number >= 0.
    OutputError
        Exit 2: ``out_dir`` cannot be created or is not empty.
    """
    from ..errors import InputError
    from .mission import build
    from .truth import render_into

    if not isinstance(n_frames, int) or isinstance(n_frames, bool) or n_frames < 1:
        raise InputError(f"--images (n_frames) must be an integer >= 1, got {n_frames!r}")
    if not (np.isfinite(noise) and noise >= 0):
        raise InputError(f"noise must be a number >= 0, got {noise!r}")
    return render_into(out_dir, lambda out: build(out, seed=seed, n_frames=n_frames, with_line=with_line, noise=noise))
