"""``export_kml``: Google Earth and GIS products of a RESULTS_DIR, built as independent dask tasks.

Task graph (plain functions, run on a local thread/process pool or on a
``distributed.Client``):

1. the plan shared with ``export-web`` (:func:`.plan.plan_export`): one task per albedo tile
   samples its valid values -> the shared percentile stretch (skipped with ``value_range``),
   the data grid and its pyramid;
2. one task per PNG tile per level: finest-level tiles read the albedo tiles they
   cover, each coarser tile waits only for its (up to 4) children and averages
   them, so a level's tiles run in parallel and the albedo is read once; one task
   per albedo tile for ``albedo_sub4/``; one task per 2048-px block of each mosaic plus one that writes the COG.

Folders are built in a ``.tmp-*`` sibling and swapped in at the end, so a re-run
replaces the previous export cleanly and a failed run leaves the old one intact.
With a ``distributed.Client`` the RESULTS_DIR must be on a file system the
workers share.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Iterator, Sequence

import dask
from rasterio.enums import Resampling

from ..errors import InputError
from ..io.atomic import TMP_PREFIX, atomic_write_text, make_readable
from ..model.grid import Grid
from ..parallel import local_workers, make_executor
from .kml import ROOT_NAME, KmlTileWriter
from .mosaic import assemble_cog, block_grids, write_mosaic_block, write_sub4
from .extent import clip, crop_grid
from .plan import albedo_sources, plan_export
from .sources import Source, find_sources, native_grid
from .tiling import compute_tasks, covering, pyramid_tasks

STRETCH_FILE = "stretch.json"


@contextlib.contextmanager
def staged_dir(final: Path) -> Iterator[Path]:
    """Yield an empty sibling folder; on success it replaces ``final`` (old content removed)."""
    final.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}{final.name}-", dir=final.parent))
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    for path in [stage, *stage.rglob("*")]:
        make_readable(path)
    old = None
    if final.exists():
        old = final.parent / f"{TMP_PREFIX}old-{final.name}-{os.getpid()}"
        os.replace(final, old)
    os.replace(stage, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


STAGING_PREFIXES = ("kml-", "albedo_sub4-", "mosaic-", "old-", "web-")


def remove_stale_staging(results_dir: Path) -> int:
    """Delete ``.tmp-*`` folders a killed export left in ``results_dir``; return how many.

    Two exports of the same RESULTS_DIR at the same time are not supported.
    """
    stale = [p for p in results_dir.glob(f"{TMP_PREFIX}*") if p.is_dir() and p.name[len(TMP_PREFIX):].startswith(STAGING_PREFIXES)]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def _mosaic_task(sources: Sequence[Source], grid: Grid, path: Path, scratch: str):
    """One task per 2048-px block of the mosaic, then one that assembles the COG."""
    task = dask.delayed(pure=False)
    blocks = [
        task(write_mosaic_block)(covering(sources, g.bounds), r0, c0, g, Path(scratch) / f"{path.stem}-{i}.tif")
        for i, (r0, c0, g) in enumerate(block_grids(grid))
    ]
    return task(assemble_cog)(blocks, grid, sources[0].crs_wkt, path)


def _file_grid(src: Source, bounds) -> Grid | None:
    """The part of ``src`` inside ``bounds`` (continuous longitudes) on its own pixels, in the file's longitudes."""
    part = clip(src.bounds, bounds)
    if part is None or part == src.bounds:
        return None
    w, s, e, n = src.file_bounds
    whole = Grid.from_bounds((w, max(s, -90.0), e, min(n, 90.0)), src.height, src.width)
    return crop_grid(whole, (part[0] - src.shift, part[1], part[2] - src.shift, part[3]))


def export_kml(
    results_dir: str | Path,
    levels: int | None = None,
    stretch: tuple[float, float] = (2.0, 98.0),
    value_range: tuple[float, float] | None = None,
    tile_size: int = 256,
    client=None,
    workers: int | None = None,
    scheduler: str | None = None,
    pool: str = "threads",
    name: str | None = None,
    sub4_resampling: str = "average",
) -> dict:
    """Write the Google Earth and GIS products of a ``solve`` results folder.

    The products the PhotometryTK manual lists, built as independent Dask tasks:
    ``albedo_sub4/`` (each albedo tile at 1/4 resolution),
    ``kml/doc.kml`` with its super-overlay quadtree of 8-bit PNG tiles (plus
    ``kml/stretch.json``), ``albedo_mosaic.tif`` and, when ``results_dir/error`` holds
    tiles, ``error_mosaic.tif`` (float32 Cloud-Optimised GeoTIFFs, geographic degrees).
    Folders are built in a ``.tmp-*`` sibling and swapped in at the end: a failed run
    leaves the previous export intact.

    Parameters
    ----------
    results_dir : str or Path
        The ``RESULTS_DIR`` of a solve (its ``albedo/tile_*.tif``, optionally ``error/``).
        With a ``distributed.Client`` it must be on a file system the workers share.
    levels : int, optional
        Levels of the KML quadtree; default as many as the data needs (finest level at
        about the albedo's native pixel size).
    stretch : tuple of float, default (2.0, 98.0)
        Low and high percentiles (0..100) of the valid albedo values that map to 0 and 255
        of the 8-bit stretch.
    value_range : tuple of float, optional
        Albedo values ``(lo, hi)`` of the stretch; replaces ``stretch`` (no sampling pass).
    tile_size : int, default 256
        Side of a PNG tile, pixels.
    client : distributed.Client, optional
        A client the caller owns to run the tasks on (not closed here).
    workers : int, optional
        Local workers when neither ``client`` nor ``scheduler`` is given; default all
        cores, 1 runs serially.
    scheduler : str, optional
        Address (``tcp://host:port``) of a Dask scheduler to run the tasks on.
    pool : {"threads", "processes"}, default "threads"
        Kind of the local workers.
    name : str, optional
        Name of the root KML document; default the folder's name.
    sub4_resampling : {"average", "nearest"}, default "average"
        Resampling of ``albedo_sub4/``; ``"nearest"`` gives PhotometryTK's values.

    Returns
    -------
    dict
        The summary the CLI prints: ``results_dir`` (str, resolved); ``levels``;
        ``tile_size`` (px); ``tiles_per_level`` (list, coarsest first) and ``tiles``
        (total PNG tiles); ``bounds`` (``[west, south, east, north]`` of the quadtree,
        degrees); ``kml_size`` and ``native_size`` (``[width, height]`` in px of the finest
        level and of the albedo's native grid); ``longitude_shifted`` (bool: a tile was
        moved by 360° to make longitudes continuous); ``stretch`` (``lo``, ``hi``,
        ``method`` = ``"percentile"`` or ``"range"``, ``percentiles``); ``doc_kml`` and
        ``stretch_file`` (paths); ``sub4_tiles``; ``albedo_mosaic`` and ``error_mosaic``
        (None without error tiles), each a dict of ``path``, ``width``, ``height``,
        ``valid_pixels``, ``overviews``; ``seconds`` (wall time).

    Raises
    ------
    InputError
        Exit 2: no ``albedo/tile_*.tif`` (or tiles without valid pixels, of different pixel
        sizes, not north-up geographic), an unknown ``sub4_resampling``, ``tile_size``
        below 16 or ``levels`` out of range.
    InfrastructureError
        Exit 3: a lost worker or a full disk.
    """
    try:
        sub4_rs = {"average": Resampling.average, "nearest": Resampling.nearest}[sub4_resampling]
    except KeyError:
        raise InputError(f"sub4 resampling must be 'average' or 'nearest', got {sub4_resampling!r}") from None
    t0 = time.perf_counter()
    results_dir = Path(results_dir).expanduser().resolve()
    sources = albedo_sources(results_dir)
    error_dir = results_dir / "error"
    errors = find_sources(error_dir, "error") if any(error_dir.glob("tile_*.tif")) else []
    remove_stale_staging(results_dir)
    task = dask.delayed(pure=False)
    with contextlib.closing(make_executor(local_workers(workers), scheduler, client=client, local=pool)) as executor:
        plan = plan_export(results_dir, sources, executor, levels=levels, tile_size=tile_size, stretch=stretch,
                           value_range=value_range)
        st, grid, sources, extent, pyr, present = plan.stretch, plan.grid, plan.sources, plan.extent, plan.pyramid, plan.present

        label = name or results_dir.name
        with (
            staged_dir(results_dir / "kml") as kml_dir,
            staged_dir(results_dir / "albedo_sub4") as sub4_dir,
            tempfile.TemporaryDirectory(prefix=f"{TMP_PREFIX}mosaic-", dir=results_dir) as scratch,
        ):
            pyramid = pyramid_tasks(kml_dir, plan, sources, KmlTileWriter(st, label))
            sub4 = [task(write_sub4)(s, sub4_dir / s.path.name, sub4_rs, _file_grid(s, grid.bounds)) for s in sources]
            mosaics = [_mosaic_task(sources, grid, results_dir / "albedo_mosaic.tif", scratch)]
            if errors:
                mosaics.append(_mosaic_task(errors, crop_grid(native_grid(errors), extent), results_dir / "error_mosaic.tif", scratch))
            mosaics = compute_tasks(pyramid + sub4 + mosaics, executor)[len(pyramid) + len(sub4):]
            atomic_write_text(kml_dir / STRETCH_FILE, st.to_json())
    for mosaic in mosaics:
        make_readable(Path(mosaic["path"]))
    if not errors:
        with contextlib.suppress(FileNotFoundError):
            (results_dir / "error_mosaic.tif").unlink()

    fh, fw = pyr.level_shape(pyr.levels - 1)
    return {
        "results_dir": str(results_dir),
        "levels": pyr.levels,
        "tile_size": pyr.tile_size,
        "tiles_per_level": [len(present[k]) for k in range(pyr.levels)],
        "tiles": sum(len(v) for v in present.values()),
        "bounds": list(pyr.bounds),
        "kml_size": [fw, fh],
        "native_size": [grid.width, grid.height],
        "longitude_shifted": any(s.shift for s in sources),
        "stretch": {"lo": st.lo, "hi": st.hi, "method": st.method, "percentiles": st.percentiles},
        "doc_kml": str(results_dir / "kml" / ROOT_NAME),
        "stretch_file": str(results_dir / "kml" / STRETCH_FILE),
        "sub4_tiles": len(sources),
        "albedo_mosaic": mosaics[0],
        "error_mosaic": mosaics[1] if errors else None,
        "seconds": round(time.perf_counter() - t0, 3),
    }
