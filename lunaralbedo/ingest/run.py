"""``ingest`` orchestration: cubes + kernels + DEM -> WORKDIR (see :mod:`.workdir` for the layout).

Per cube: open it (kernels loaded, ``campt``-time positions), build the camera,
find its footprint on the DEM, orthoproject onto the DEM-aligned grid cropped to
the footprint and write the DRG.  Footprints and the written SIMULATION_BOX use
continuous longitudes: a cube across ±180° gets a DRG at e.g. 179.5..180.4, not a
360°-wide one.  A cube that fails (bad label, missing kernel,
no footprint) is skipped with its reason; the run fails only when no cube works.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import InputError, LunarAlbedoError
from ..io.positions import write_positions
from ..isis.pixels import read_band
from ..model.longitude import continuous_span, union_span
from ..spice.kernels import expand_kernel_args
from ..camera.build import build_camera
from ..camera.pushframe import PushFrameCamera
from .dem import DemMosaic, load_dems
from ..model.grid import mpp_to_degrees
from .keys import band_items
from .observation import open_observation
from .orthoproject import footprint, level2_bounds, orthoproject, warp_level2
from .workdir import remove_stale_drgs, write_dem, write_drg, write_settings


@dataclass
class CubeResult:
    """Outcome for one cube: footprint box (degrees), valid pixels, speed, or why it was skipped."""

    path: Path
    key: str
    band: int = 1
    band_center_nm: float | None = None
    box: tuple[float, float, float, float] | None = None
    valid_pixels: int = 0
    grid_pixels: int = 0
    seconds: float = 0.0
    source: str = ""
    kind: str = ""
    skipped: str | None = None
    sun: np.ndarray | None = None
    spacecraft: np.ndarray | None = None

    @property
    def pixels_per_second(self) -> float:
        return self.grid_pixels / self.seconds if self.seconds > 0 else float("nan")


@dataclass
class IngestReport:
    workdir: Path
    results: list[CubeResult] = field(default_factory=list)
    box: tuple[float, float, float, float] | None = None
    settings: Path | None = None
    dem_radius_converted: list[Path] = field(default_factory=list)
    removed: list[Path] = field(default_factory=list)

    @property
    def done(self) -> list[CubeResult]:
        return [r for r in self.results if r.skipped is None]


def _lon_base(dem: DemMosaic) -> float:
    """Longitudes are named like the first DEM's: from 0 for a 0..360 DEM, else from -180."""
    first = dem.sources[0]
    return 0.0 if first.geographic and first.lon_range()[1] > 180.0 else -180.0


def _box(lon, lat, base: float = -180.0):
    """``(west, south, east, north)`` of a footprint, continuous longitudes (179.5..180.4 across ±180°)."""
    ok = np.isfinite(lon) & np.isfinite(lat)
    if ok.sum() < 3:
        return None
    west, east = continuous_span(np.asarray(lon)[ok], base)
    return west, float(lat[ok].min()), east, float(lat[ok].max())


def union_box(boxes, base: float = -180.0) -> tuple[float, float, float, float]:
    """Union ``(west, south, east, north)`` of footprint boxes, continuous across ±180°."""
    west, east = union_span([(b[0], b[2]) for b in boxes], base)
    return west, min(b[1] for b in boxes), east, max(b[3] for b in boxes)


def _ingest_one(res: CubeResult, obs, dem: DemMosaic, mpp_deg, drg_dir: Path, legacy_8bit: bool):
    label = obs.label
    if label.data_path is None:
        raise InputError(f"{res.path}: label only, no pixels to orthoproject")
    t0 = time.perf_counter()
    if label.is_map_projected:
        res.kind = "level2"
        lon, lat = level2_bounds(label)
    else:
        camera = build_camera(label, obs.ephemeris, obs.code, band=res.band)
        res.kind = "line scanner" if camera.is_line_scanner else "frame camera"
        if isinstance(camera, PushFrameCamera):  # positions at this band's centre time (framelet timing)
            res.kind = f"push-frame band {res.band}"
            res.sun = np.asarray(obs.ephemeris.sun(camera.center_et), dtype=np.float64)
            res.spacecraft = np.asarray(obs.ephemeris.spacecraft(camera.center_et), dtype=np.float64)
        lon, lat = footprint(camera, dem.height)
    box = _box(lon, lat, _lon_base(dem))
    if box is None:
        raise InputError(f"{res.path}: the image does not see the Moon's surface (no footprint)")
    grid = dem.base_grid(box, mpp_deg)
    heights = dem.onto(grid)
    if label.is_map_projected:
        values = warp_level2(label, grid)
    else:
        values = orthoproject(camera, read_band(label, res.band), grid, heights)
    res.seconds = time.perf_counter() - t0
    res.valid_pixels = int(np.isfinite(values).sum())
    res.grid_pixels = int(values.size)
    if res.valid_pixels == 0:
        raise InputError(f"{res.path}: no pixel of the image falls on the DEM")
    res.box = box
    write_drg(drg_dir / f"{res.key}.tif", values, grid, legacy_8bit, res.band_center_nm)


def _process_cube(item, *, extra, isisdata, source, dem: DemMosaic, mpp_deg, drg_dir: Path, legacy_8bit: bool) -> CubeResult:
    """One task of the ingest graph: positions and DRG of one cube (skipped with the reason on error)."""
    path, key, band, center = item
    res = CubeResult(Path(path), key, band, center)
    try:
        with open_observation(path, key, extra, isisdata, source) as obs:
            res.source, res.sun, res.spacecraft = obs.source, obs.sun.copy(), obs.spacecraft.copy()
            try:
                _ingest_one(res, obs, dem, mpp_deg, drg_dir, legacy_8bit)
            except (KeyError, ValueError, TypeError, IndexError) as exc:
                raise InputError(f"{path}: unexpected label content ({type(exc).__name__}: {exc})") from None
    except LunarAlbedoError as exc:
        res.skipped = str(exc)
    return res


def ingest(cubes: Sequence[str | Path], dems: Sequence[str | Path], workdir: str | Path,
           kernels: Sequence[str | Path] = (), isisdata=None, mpp: float | None = None, source: str = "auto",
           dem_mode: str = "auto", legacy_8bit: bool = False, tile_size: float = 4.0,
           on_cube: Callable[[CubeResult], None] | None = None, workers: int = 1, scheduler: str | None = None,
           progress: bool = False) -> IngestReport:
    """Ingest ``cubes`` into ``workdir``; returns a report of footprints and skipped cubes.

    ``mpp`` (metres per pixel) sets the output resolution; without it the grid is
    the first DEM's.  Cubes are independent tasks: ``workers`` local processes or a
    Dask ``scheduler`` address run them in parallel (each worker process has its own
    SPICE kernel pool).  ``on_cube`` is called for each result, in the cubes' order.
    Raises :class:`InputError` when no cube could be ingested.
    """
    from ..parallel import make_executor

    workdir = Path(workdir)
    if not cubes:
        raise InputError("no cubes given")
    if mpp is not None and mpp <= 0:
        raise InputError(f"--mpp must be positive, got {mpp}")
    extra = expand_kernel_args(kernels)
    dem = DemMosaic(load_dems(dems, dem_mode))
    mpp_deg = mpp_to_degrees(mpp) if mpp else None
    report = IngestReport(workdir, dem_radius_converted=dem.radius_converted)
    drg_dir = workdir / "DRG"
    executor = make_executor(workers, scheduler, progress=progress)
    try:
        results = executor.map(
            _process_cube, band_items(cubes), "ingest", shared=("dem",),
            extra=extra, isisdata=isisdata, source=source, dem=dem, mpp_deg=mpp_deg, drg_dir=drg_dir, legacy_8bit=legacy_8bit,
        )
    finally:
        executor.close()
    for res in results:
        report.results.append(res)
        if on_cube is not None:
            on_cube(res)
    done = report.done
    if not done:
        reasons = "; ".join(r.skipped or "" for r in report.results)
        raise InputError(f"no cube could be ingested: {reasons}")
    stale = remove_stale_drgs(drg_dir, {f"{r.key}.tif" for r in done})
    report.removed = stale
    west, south, east, north = union_box([r.box for r in done], _lon_base(dem))
    report.box = (west, east, south, north)
    rx, ry = dem.base_grid((west, south, east, north), mpp_deg).res
    pad = 10  # pixels of DEM beyond the footprints, for the solver's padded tiles
    union = dem.base_grid((west - pad * rx, south - pad * ry, east + pad * rx, north + pad * ry), mpp_deg)
    write_dem(workdir / "DEM" / "dem.tif", dem.onto(union), union)
    write_positions(workdir / "meta" / "sunpos.txt", {r.key: r.sun for r in done})
    write_positions(workdir / "meta" / "spacecraftpos.txt", {r.key: r.spacecraft for r in done})
    report.settings = write_settings(workdir, report.box, tile_size, legacy_8bit)
    return report
