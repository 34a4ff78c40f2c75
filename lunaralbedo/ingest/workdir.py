"""What ``ingest`` writes besides DRGs: the DEM tile, position files and the legacy settings file.

Layout of WORKDIR (all paths in ``settings.txt`` are relative to WORKDIR)::

    DRG/<KEY>.tif              float32 image values (band 1) + valid mask (band 2), NaN nodata
    DEM/dem.tif                heights (m above 1737.4 km) on the same grid, nodata -32767
    meta/sunpos.txt            KEY x y z (km, MOON_ME)
    meta/spacecraftpos.txt     KEY x y z (km, MOON_ME)
    settings.txt               legacy settings that ``lunaralbedo solve`` takes as it is
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write_text
from ..io.rasters import MOON_CRS
from ..io.geotiff import write_geotiff
from ..settings import legacy_text, load_settings
from ..model.grid import Grid

NO_DEM = -32767.0


def write_drg(path: Path, values: np.ndarray, grid: Grid, legacy_8bit: bool = False, band_center_nm=None) -> None:
    """One DRG: float32 value + mask bands, or (legacy) uint8 stretch + 0/255 alpha.

    ``band_center_nm`` (the cube band's wavelength) goes into the first band's
    description (``"<centre> nm"``) and tag ``band_center_nm``.
    """
    meta = {} if band_center_nm is None else dict(descriptions=[f"{band_center_nm:g} nm"],
                                                   tags=[dict(band_center_nm=f"{band_center_nm:g}")])
    valid = np.isfinite(values)
    if legacy_8bit:
        hi = float(np.percentile(values[valid], 99.5)) if valid.any() else 1.0
        v = np.clip(np.round(values / (hi if hi > 0 else 1.0) * 200.0), 1, 255)
        bands = np.stack([np.where(valid, v, 0), np.where(valid, 255, 0)]).astype(np.uint8)
        write_geotiff(path, bands, grid.transform, MOON_CRS, nodata=None, dtype="uint8", **meta)
        return
    bands = np.stack([np.where(valid, values, np.nan), valid.astype(np.float64)]).astype(np.float32)
    write_geotiff(path, bands, grid.transform, MOON_CRS, nodata=float("nan"), dtype="float32", **meta)


def remove_stale_drgs(drg_dir: Path, keep: set[str]) -> list[Path]:
    """Delete DRGs of an earlier run in ``drg_dir`` that this run did not write (the solver reads the whole folder)."""
    from ..io.atomic import remove_stale_temporaries

    remove_stale_temporaries(drg_dir)
    removed = [p for p in sorted(drg_dir.glob("*.tif")) if p.name not in keep]
    for p in removed:
        p.unlink()
    return removed


def write_dem(path: Path, heights: np.ndarray, grid: Grid) -> None:
    """DEM tile (float32 metres above 1737.4 km; -32767 where unknown)."""
    write_geotiff(path, np.where(np.isfinite(heights), heights, NO_DEM).astype(np.float32), grid.transform,
                  MOON_CRS, nodata=NO_DEM, dtype="float32")


def settings_text(box, tile_size: float, legacy_8bit: bool, note: str = "") -> str:
    """Legacy settings for the ingested products (relative paths; Lunar-Lambertian)."""
    shadow_type, shadow_thresh = (1, 10) if legacy_8bit else (0, 0)
    values = {
        "DRG_DIR": "DRG", "DEM_DIR": "DEM",
        "SUN_POSITION_FILE": "meta/sunpos.txt", "SPACECRAFT_POSITION_FILE": "meta/spacecraftpos.txt",
        "NUM_PROCESSES": 1, "TILE_SIZE": float(tile_size), "SIMULATION_BOX": tuple(box),
        "REFLECTANCE_TYPE": 2, "SHADOW_THRESH": shadow_thresh, "SHADOW_TYPE": shadow_type,
        "TR_CONST": 1.5, "PHASE_COEFF_C1": 1.4, "PHASE_COEFF_C2": 0.5, "MAX_NUM_ITER": 10,
        "NO_DEM_DATA_VAL": NO_DEM, "USE_WEIGHTS": 1, "USE_NORMALIZED_COST_FUN": 0, "COMPUTE_ERRORS": 1,
    }
    comment = "Written by lunaralbedo ingest. SIMULATION_BOX = union of image footprints (lon_min:lon_max:lat_min:lat_max)."
    if note:
        comment += "\n" + note
    if not legacy_8bit:
        comment += "\nDRGs are float32 in physical units: SHADOW_TYPE 0 (no DN threshold)."
    return legacy_text(values, comment)


def write_settings(workdir: Path, box, tile_size: float, legacy_8bit: bool, note: str = "") -> Path:
    """Write ``WORKDIR/settings.txt`` atomically (``note``: comment lines) and check that :func:`load_settings` accepts it."""
    path = workdir / "settings.txt"
    atomic_write_text(path, settings_text(box, tile_size, legacy_8bit, note))
    load_settings(path)
    return path
