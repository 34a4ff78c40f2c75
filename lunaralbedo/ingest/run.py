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
from ..model.grid import degrees_to_mpp, mpp_to_degrees, tile_pixels
from .keys import band_items
from .observation import band_time, open_observation
from .orthoproject import footprint, level2_bounds, orthoproject, warp_level2
from .resolution import pixel_resolution_m, tile_size_deg
from .workdir import remove_stale_drgs, write_dem, write_drg, write_settings


#: Most pixels of the images' union at their native resolution (0.4 Gpx: one LRO NAC frame, 5064 x 52 000 px,
#: with room to spare); beyond it ingest asks for --mpp instead of running out of memory.
MAX_GRID_PIXELS = 400_000_000


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
    mpp: float | None = None  # output resolution, metres per pixel
    tile_size: float | None = None  # TILE_SIZE written, degrees
    resolution_note: str = ""

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
            et = band_time(obs, res.band, camera)
            res.sun = np.asarray(obs.ephemeris.sun(et), dtype=np.float64)
            res.spacecraft = np.asarray(obs.ephemeris.spacecraft(et), dtype=np.float64)
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
        mpp = degrees_to_mpp(grid.res[0])
        raise InputError(f"{res.path}: no pixel of the output grid ({grid.width} x {grid.height} px of {mpp:,.4g} m) "
                         "sees the image; give a finer --mpp" if grid.width * grid.height < 64 else
                         f"{res.path}: no pixel of the image falls on the DEM (DEM without heights under the image?)")
    res.box = box
    write_drg(drg_dir / f"{res.key}.tif", values, grid, legacy_8bit, res.band_center_nm)


def refuse_unsupported(path) -> None:
    """Raise :class:`InputError` for an image ``ingest`` cannot orthoproject (radar: Mini-RF), before its
    kernels are loaded or its times parsed (a radar label's clock counts may be ``UNK``)."""
    from ..camera.timing import RADAR_REFUSAL, camera_kind
    from ..isis.labels import read_label

    label = read_label(path)
    if label.has("Instrument") and not label.is_map_projected and camera_kind(label) == "radar":
        raise InputError(f"{path}: {RADAR_REFUSAL}: ingest has no orthoprojection model for radar (SAR) geometry "
                         "(`lunaralbedo positions` gives its positions)")


def _native_mpp(item, *, extra, isisdata, source, dem: DemMosaic):
    """``(metres, footprint box)`` of one cube (band): its native ground resolution
    (:func:`.resolution.pixel_resolution_m` at its centre, or a map-projected cube's own pixel size) and
    its footprint (west, south, east, north); None when the cube cannot be opened (its ingest task says why)."""
    path, key, band, _center = item
    try:
        refuse_unsupported(path)
        with open_observation(path, key, extra, isisdata, source) as obs:
            label = obs.label
            if label.is_map_projected:
                from ..isis.pixels import cube_georeference

                transform, crs = cube_georeference(label.data_path)
                size = abs(transform.a)
                mpp = degrees_to_mpp(size) if crs is None or crs.is_geographic else size
                box = _box(*level2_bounds(label), _lon_base(dem))
            else:
                camera = build_camera(label, obs.ephemeris, obs.code, band=band)
                mpp = pixel_resolution_m(camera, dem.height)
                box = _box(*footprint(camera, dem.height), _lon_base(dem))
            return (mpp, box) if np.isfinite(mpp) and mpp > 0 and box is not None else None
    except (LunarAlbedoError, KeyError, ValueError, TypeError, IndexError):
        return None


def _check_union_size(found, dem: DemMosaic) -> None:
    """Refuse (before anything is written) a native grid of the images' union beyond :data:`MAX_GRID_PIXELS`."""
    mpp = min(m for m, _ in found)
    grid = dem.base_grid(union_box([b for _, b in found], _lon_base(dem)), mpp_to_degrees(mpp))
    n = grid.width * grid.height
    if n > MAX_GRID_PIXELS:
        coarser = mpp * (n / MAX_GRID_PIXELS) ** 0.5
        raise InputError(f"at the images' native resolution ({mpp:.4g} m/px) their union is a grid of {grid.width:,} x "
                         f"{grid.height:,} px ({n / 1e9:.2g} Gpx, more than {MAX_GRID_PIXELS / 1e9:g}); give --mpp "
                         f"{coarser:.3g} or coarser, or ingest distant images into separate work folders")


def _process_cube(item, *, extra, isisdata, source, dem: DemMosaic, mpp_deg, drg_dir: Path, legacy_8bit: bool) -> CubeResult:
    """One task of the ingest graph: positions and DRG of one cube (skipped with the reason on error)."""
    path, key, band, center = item
    res = CubeResult(Path(path), key, band, center)
    try:
        refuse_unsupported(path)
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
           dem_mode: str = "auto", legacy_8bit: bool = False, tile_size: float | None = None,
           on_cube: Callable[[CubeResult], None] | None = None, workers: int = 1, scheduler: str | None = None,
           progress: bool = False, match_dem: bool = False) -> IngestReport:
    """Orthoproject ISIS cubes onto a DEM and write the work folder ``solve`` reads.

    Replaces the PhotometryTK manual's preparation chain (ISIS ``spiceinit``, ``campt``,
    ``cam2map``, ``get_sun_or_spacecraft_position.pl``): per cube (per band of a multi-band
    push-frame cube) the camera is built from the label and its kernels, its footprint found
    on the DEM, and the image orthoprojected onto a DEM-aligned geographic grid cropped to
    that footprint.  Writes ``workdir/DRG/<KEY>.tif`` (float32, NaN no-data),
    ``workdir/DEM/dem.tif`` (heights in metres above the 1737.4 km sphere over the union of
    the footprints plus 10 pixels), ``workdir/meta/sunpos.txt`` and ``spacecraftpos.txt``
    (``KEY x y z``, km, Moon-centred body-fixed MOON_ME, at the ``campt`` centre time) and
    ``workdir/settings.txt``.  A cube that fails is skipped with its reason; DRGs of an
    earlier run that this run did not produce are removed.

    Parameters
    ----------
    cubes : sequence of str or Path
        ISIS3 Level-1 cubes (or detached labels), or map-projected Level-2 cubes.  The DRG
        key is the file name up to its first ``.``, cut or padded to 11 characters.
    dems : sequence of str or Path
        DEM GeoTIFFs or ISIS DEM cubes, or folders of them, geographic or projected; where
        they overlap their heights are averaged (the PhotometryTK manual's rule).
    workdir : str or Path
        Work folder to write (created when missing).
    kernels : sequence of str or Path, optional
        Extra SPICE kernels, kernel folders or meta-kernels, loaded after the kernels of each
        label's ``Kernels`` group.
    isisdata : str or Path, optional
        ISIS data area that resolves ``$base``/``$<mission>`` kernel paths of the labels.
    mpp : float, optional
        Output resolution in metres per pixel.  Default: the images' native resolution (the
        finest image's pixel at its centre, as ISIS ``cam2map``), or the first DEM's grid
        with ``match_dem``.
    source : {"auto", "table", "kernels"}, default "auto"
        Ephemeris source: the cube's attached SPICE tables when present (``auto``), only
        the tables, or only the kernels.
    dem_mode : {"auto", "radius", "height"}, default "auto"
        Whether DEM values are radii in metres (converted to heights above 1737.4 km) or
        heights; ``auto`` takes radius when the median exceeds 1000 km.
    legacy_8bit : bool, default False
        Write 8-bit DRGs (stretch + alpha) as the PhotometryTK tools did.
    tile_size : float, optional
        ``TILE_SIZE`` written to ``settings.txt``, degrees (at most 360).  Default: tiles of
        about one block of the solver's memory budget at the output resolution.
    on_cube : callable, optional
        Called with each :class:`CubeResult`, in the cubes' order, once all are done.
    workers : int, default 1
        Local worker processes that ingest cubes in parallel (each with its own SPICE pool).
    scheduler : str, optional
        Address of a Dask scheduler to run the cubes on instead of local workers.
    progress : bool, default False
        Show a progress bar (tqdm) of the tasks.
    match_dem : bool, default False
        Use the first DEM's grid instead of the native resolution (exclusive with ``mpp``).

    Returns
    -------
    IngestReport
        ``workdir``; ``results`` (one :class:`CubeResult` per cube band: ``key``, ``path``,
        ``box`` = footprint ``(west, south, east, north)`` in degrees, ``valid_pixels``,
        ``kind``, ephemeris ``source``, ``sun``/``spacecraft`` positions in km body-fixed,
        or ``skipped`` = the reason); ``box`` = SIMULATION_BOX ``(west, east, south,
        north)`` in degrees, continuous across ±180°; ``mpp`` (m/px) and ``tile_size``
        (degrees) written; ``settings`` (path of ``settings.txt``);
        ``dem_radius_converted`` (DEMs read as radius) and ``removed`` (stale DRGs).

    Raises
    ------
    InputError
        Exit 2: no cube given, an invalid ``mpp``/``tile_size`` (or both ``mpp`` and
        ``match_dem``), an unreadable DEM, a native grid over :data:`MAX_GRID_PIXELS`, or
        no cube could be ingested (the message lists each cube's reason; nothing is
        written then).
    InfrastructureError
        Exit 3: a worker lost or a Dask cluster that cannot be reached.
    """
    from ..parallel import make_executor

    workdir = Path(workdir)
    if not cubes:
        raise InputError("no cubes given")
    check_grid_options(mpp, tile_size, match_dem)
    extra = expand_kernel_args(kernels)
    dem = DemMosaic(load_dems(dems, dem_mode))
    report = IngestReport(workdir, dem_radius_converted=dem.radius_converted)
    drg_dir = workdir / "DRG"
    items = band_items(cubes)
    executor = make_executor(workers, scheduler, progress=progress)
    try:
        if mpp is None and not match_dem:
            firsts = list({str(it[0]): it for it in reversed(items)}.values())  # a cube's first band: its bands share a grid
            native = [m for m in executor.map(_native_mpp, firsts, "resolution", shared=("dem",), extra=extra,
                                              isisdata=isisdata, source=source, dem=dem) if m]
            if native:
                _check_union_size(native, dem)
            mpp = min(m for m, _ in native) if native else None  # none: no cube opens (their tasks say why)
            report.resolution_note = "native: the finest image's pixel at its centre, as ISIS cam2map" if native else ""
        mpp_deg = mpp_to_degrees(mpp) if mpp else None
        results = executor.map(
            _process_cube, items, "ingest", shared=("dem",),
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
    report.mpp = degrees_to_mpp(rx)
    note = report.resolution_note or ("given (--mpp)" if mpp else "the first DEM's pixels")
    if tile_size is None:
        tile_size = tile_size_deg(report.mpp)
        tile_note = f"{tile_pixels(tile_size, rx)} px a side, one block of the solver's memory budget"
    else:
        tile_note = f"given (--tile-size): {tile_pixels(tile_size, rx)} px a side"
    report.tile_size = tile_size
    comment = (f"Resolution {report.mpp:.6g} m/px ({note}): the DRGs' and DEM's pixels.\n"
               f"TILE_SIZE {tile_size:g} degrees = {tile_note}.")
    report.settings = write_settings(workdir, report.box, tile_size, legacy_8bit, comment)
    return report


def check_grid_options(mpp, tile_size, match_dem: bool = False) -> None:
    """``--mpp`` and ``--tile-size`` must be positive finite numbers (checked before anything is written)."""
    if mpp is not None and match_dem:
        raise InputError("give either --mpp or --match-dem, not both")
    for name, v in (("--mpp", mpp), ("--tile-size", tile_size)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v:g}")
    if tile_size is not None and tile_size > 360:
        raise InputError(f"--tile-size is in degrees and at most 360, got {tile_size:g}")
