"""``export_kml``: Google Earth and GIS products of a RESULTS_DIR, built as independent dask tasks.

Task graph (plain functions, run on a local thread/process pool or on a
``distributed.Client``):

1. one task per albedo tile samples its valid values -> the shared percentile stretch
   (skipped with ``value_range``);
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
import warnings
from pathlib import Path
from typing import Iterator, Sequence

import dask
import numpy as np
from rasterio.enums import Resampling
from rasterio.errors import NotGeoreferencedWarning

from ..errors import InputError
from ..io.atomic import TMP_PREFIX, atomic_write_text, make_readable
from ..parallel import local_workers, make_executor
from .kml import ROOT_NAME, pyramid_children, render_leaf, render_parent
from .mosaic import assemble_cog, block_grids, write_mosaic_block, write_sub4
from .pyramid import Pyramid, plan_pyramid, present_nodes
from .sources import Grid, Source, find_sources, intersects, native_grid, sample_values
from .stretch import stretch_from_range, stretch_from_values

STRETCH_FILE = "stretch.json"
SAMPLE_BUDGET = 20_000_000  # at most about this many albedo values enter the percentiles


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


STAGING_PREFIXES = ("kml-", "albedo_sub4-", "mosaic-", "old-")


def remove_stale_staging(results_dir: Path) -> int:
    """Delete ``.tmp-*`` folders a killed export left in ``results_dir``; return how many.

    Two exports of the same RESULTS_DIR at the same time are not supported.
    """
    stale = [p for p in results_dir.glob(f"{TMP_PREFIX}*") if p.is_dir() and p.name[len(TMP_PREFIX):].startswith(STAGING_PREFIXES)]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def _compute(tasks: list, executor) -> list:
    with warnings.catch_warnings():
        # rasterio silences this warning for its in-memory arrays with catch_warnings,
        # which is not thread-safe: with threads it leaks out.
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        return executor.compute(tasks)


def _covering(sources: Sequence[Source], bounds) -> list[Source]:
    return [s for s in sources if intersects(s.bounds, bounds)]


def _pyramid_tasks(kml_dir, pyr, present, children, sources, st, label, resampling) -> list:
    """One task per written tile: finest level from the albedo, each coarser tile from its children."""
    task = dask.delayed(pure=False)
    done: dict = {}
    for level in range(pyr.levels - 1, -1, -1):
        for node in present[level]:
            if level == pyr.levels - 1:
                done[node.key] = task(render_leaf)(kml_dir, node, _covering(sources, node.bounds), st, label, resampling)
            else:
                kids = children[node.key]
                done[node.key] = task(render_parent)(kml_dir, node, kids, [done[k.key] for k in kids], st, label)
    # Every written tile is below the root, so computing the root computes all of them,
    # and each tile's arrays are freed once its parent has used them.
    (root,) = present[0]
    return [done[root.key]]


def _mosaic_task(sources: Sequence[Source], grid: Grid, path: Path, scratch: str):
    """One task per 2048-px block of the mosaic, then one that assembles the COG."""
    task = dask.delayed(pure=False)
    blocks = [
        task(write_mosaic_block)(_covering(sources, g.bounds), r0, c0, g, Path(scratch) / f"{path.stem}-{i}.tif")
        for i, (r0, c0, g) in enumerate(block_grids(grid))
    ]
    return task(assemble_cog)(blocks, grid, sources[0].crs_wkt, path)


def _level_resampling(pyr: Pyramid, level: int, grid: Grid) -> Resampling:
    """``nearest`` for a level at least as fine as the native grid, ``average`` for a coarser one."""
    height, width = pyr.level_shape(level)
    return Resampling.nearest if width >= grid.width and height >= grid.height else Resampling.average


def _check_pixel_size(sources: Sequence[Source], folder: Path) -> None:
    rx, ry = sources[0].res
    for s in sources[1:]:
        if abs(s.res[0] - rx) > 1e-6 * rx or abs(s.res[1] - ry) > 1e-6 * ry:
            raise InputError(
                f"{folder}: tiles must share one pixel size; {sources[0].path.name} has {rx:g} x {ry:g} "
                f"degrees but {s.path.name} has {s.res[0]:g} x {s.res[1]:g}"
            )


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
    """Write ``albedo_sub4/``, ``kml/doc.kml`` (+ tree) and ``albedo_mosaic.tif`` (+ ``error_mosaic.tif``).

    ``stretch`` are the low/high percentiles of the 8-bit stretch, unless
    ``value_range=(lo, hi)`` is given.  ``levels`` None means as many as the data
    needs.  Where tasks run (:func:`lunaralbedo.parallel.make_executor`): ``client``
    (a ``distributed.Client``), else ``scheduler`` (address of a Dask scheduler),
    else ``workers`` local workers (default: all cores; 1 = serial) of kind
    ``pool`` (``"threads"`` or ``"processes"``).  Returns a
    summary dict (also the content of the printed summary).  ``sub4_resampling``
    is ``"average"`` (default) or ``"nearest"`` (PhotometryTK's values).
    """
    try:
        sub4_rs = {"average": Resampling.average, "nearest": Resampling.nearest}[sub4_resampling]
    except KeyError:
        raise InputError(f"sub4 resampling must be 'average' or 'nearest', got {sub4_resampling!r}") from None
    t0 = time.perf_counter()
    results_dir = Path(results_dir).expanduser().resolve()
    albedo_dir = results_dir / "albedo"
    sources = find_sources(albedo_dir, "albedo")
    _check_pixel_size(sources, albedo_dir)
    error_dir = results_dir / "error"
    errors = find_sources(error_dir, "error") if any(error_dir.glob("tile_*.tif")) else []
    remove_stale_staging(results_dir)
    grid = native_grid(sources)
    pyr = plan_pyramid(grid.bounds, grid.shape, tile_size, levels)
    present = present_nodes(pyr, [s.bounds for s in sources])
    children = pyramid_children(pyr, present)
    task = dask.delayed(pure=False)
    with contextlib.closing(make_executor(local_workers(workers), scheduler, client=client, local=pool)) as executor:
        if value_range is not None:
            st = stretch_from_range(*value_range)
        else:
            budget = max(10_000, SAMPLE_BUDGET // len(sources))  # values per tile for the percentiles
            samples = _compute([task(sample_values)(s, budget) for s in sources], executor)
            if not any(len(v) for v in samples):
                raise InputError(f"{albedo_dir}: the albedo tiles hold no valid pixel (all no-data); nothing to export")
            st = stretch_from_values(np.concatenate(samples), tuple(stretch))

        label = name or results_dir.name
        with (
            staged_dir(results_dir / "kml") as kml_dir,
            staged_dir(results_dir / "albedo_sub4") as sub4_dir,
            tempfile.TemporaryDirectory(prefix=f"{TMP_PREFIX}mosaic-", dir=results_dir) as scratch,
        ):
            pyramid = _pyramid_tasks(kml_dir, pyr, present, children, sources, st, label, _level_resampling(pyr, pyr.levels - 1, grid))
            sub4 = [task(write_sub4)(s, sub4_dir / s.path.name, sub4_rs) for s in sources]
            mosaics = [_mosaic_task(sources, grid, results_dir / "albedo_mosaic.tif", scratch)]
            if errors:
                mosaics.append(_mosaic_task(errors, native_grid(errors), results_dir / "error_mosaic.tif", scratch))
            mosaics = _compute(pyramid + sub4 + mosaics, executor)[len(pyramid) + len(sub4):]
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
