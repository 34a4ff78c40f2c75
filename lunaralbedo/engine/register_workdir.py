"""``ingest --register``: a WORK DIR's DRGs registered to its DEM, written back with their georeference corrected.

The shifts are those of the solve's registration (:func:`lunaralbedo.engine.registration.estimate`, with the
WORK DIR's settings and ``REGISTER_MAX_SHIFT``); each DRG file gets its transform moved by its shift (pixels
unchanged, atomically), and ``WORKDIR/image_offsets.csv`` records them.  A solve of the WORK DIR then needs no
REGISTER_IMAGES.
"""
from __future__ import annotations

from pathlib import Path

from ..io.drg_levels import write_moved
from ..settings import load_settings, replace
from .offsets import Registration, shifted_scene, write_offsets_csv
from .registration import estimate
from .scene import build_scene


def register_workdir(workdir: str | Path, max_shift_px: float | None = None) -> Registration:
    """Register the DRGs of ``workdir`` (its ``settings.txt``) to its DEM and rewrite their georeference."""
    workdir = Path(workdir)
    s = load_settings(workdir / "settings.txt")
    s = replace(s, register_images=1, **({} if max_shift_px is None else {"register_max_shift": float(max_shift_px)}))
    scene = build_scene(s)
    r = estimate(scene)
    for info in shifted_scene(scene, r.offsets_m).images:
        write_moved(info.path, info.transform)
    write_offsets_csv(workdir / "image_offsets.csv", r)
    return r
