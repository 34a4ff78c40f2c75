"""The forward model: synthetic scenes rendered from a known Moon, in every input contract of the product.

One forward model (:mod:`.forward`: Sun geometry, :math:`A\\,T\\,R` of eq. 1 with the photometric
registry, the recording as 8-bit DN or float radiance), one truth format (:mod:`.truth`), and
the scenes built on them:

* :mod:`.strip` — a strip of DRGs in the solver's input contract (``lunaralbedo simulate OUT``);
* :mod:`.mission` — Level-1 ISIS cubes with SPICE kernels and a DEM, the ingest contract
  (``lunaralbedo simulate OUT --format isis``; ``sample_data/`` is one);
* :mod:`.nacpair` — an LRO-NAC-like LE/RE line-scanner pair with a known boresight error;
* :mod:`.lunar_missions` — the same mission seen by Kaguya MI/TC-, Clementine UVVIS- or
  Chandrayaan-2 TMC-2-like cameras with their labels and IKs (``lunaralbedo simulate OUT --instrument NAME``).

:func:`score` compares a solve's outputs with any scene's truth.
"""
from __future__ import annotations

import numpy as np

from .fields import fresh_craters, truth_albedo, truth_dem
from .strip import SceneSpec, render_scene
from .truth import read_truth, score, true_exposures

__all__ = ["SceneSpec", "fresh_craters", "read_truth", "render_instrument_mission", "render_mission", "render_scene",
           "score", "true_exposures", "truth_albedo", "truth_dem"]


def _check_mission_args(n_images, noise, option: str) -> None:
    from ..errors import InputError

    if not isinstance(n_images, int) or isinstance(n_images, bool) or n_images < 1:
        raise InputError(f"--images ({option}) must be an integer >= 1, got {n_images!r}")
    if not (np.isfinite(noise) and noise >= 0):
        raise InputError(f"noise must be a number >= 0, got {noise!r}")


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
    from .mission import build
    from .truth import render_into

    _check_mission_args(n_frames, noise, "n_frames")
    return render_into(out_dir, lambda out: build(out, seed=seed, n_frames=n_frames, with_line=with_line, noise=noise))


def render_instrument_mission(out_dir, instrument: str, seed: int = 4601, n_images: int = 3, noise: float = 0.005) -> dict:
    """Render the mission of :func:`render_mission` as one lunar instrument sees it (:mod:`.lunar_missions`).

    Parameters
    ----------
    out_dir : str or Path
        Scene folder to write: new, or existing and empty.
    instrument : str
        ``kaguya_mi`` (four-band NIR line scanner), ``kaguya_tc`` (TC1, NOMINAL swath crop),
        ``clementine_uvvis`` (frames, filters A and B alternating) or ``chandrayaan2_tmc2``
        (2x summed line scanner): ISIS labels and IKs as those instruments' plugins read them.
    seed : int, default 4601
        Seed of the random scene (terrain, albedo, pointing, noise).
    n_images : int, default 3
        Images (cubes), at least 1; a Kaguya MI cube gives four DRGs (its bands).
    noise : float, default 0.005
        Relative standard deviation of the multiplicative noise (0: none).

    Returns
    -------
    dict
        The truth (``truth/truth.json``, as :func:`render_mission`), per image key also ``et`` (s TDB,
        the time of the cube's centre) and ``band_center_nm``.

    Raises
    ------
    InputError
        Exit 2: an unknown ``instrument``, ``n_images`` not an integer >= 1, or ``noise`` not a number >= 0.
    OutputError
        Exit 2: ``out_dir`` cannot be created or is not empty.
    """
    from ..errors import InputError
    from .lunar_missions import INSTRUMENTS, build
    from .truth import render_into

    if instrument not in INSTRUMENTS:
        raise InputError(f"--instrument must be one of {', '.join(sorted(INSTRUMENTS))}, got {instrument!r}")
    _check_mission_args(n_images, noise, "n_images")
    return render_into(out_dir, lambda out: build(out, instrument, seed=seed, n_images=n_images, noise=noise))
