"""``export_web``: the static web map and run report of a RESULTS_DIR.

Layout of the site (``RESULTS_DIR/web/`` by default)::

    index.html                     the page (map + run report panel)
    lib/leaflet/                   Leaflet 1.9.4 and its licence (vendored package data)
    lib/app.js, lib/app.css        the page's code
    tiles/<layer>/<z>/<x>/<y>.png  albedo, error, outliers, hillshade, hillshade_input, dem_change: the KML
                                   pyramid's layout (export/tiling.py)
    data/*.js                      meta, report, footprints, per-tile values (see :mod:`.data`)

The tiles of every layer are the quadtree that :func:`..export.plan.plan_export` plans for
``export-kml`` too (:mod:`..export.pyramid`) over the albedo tiles (level 0 = one tile of at most ``tile_size`` px; row 0 at the north edge), with
one stretch per layer for all its tiles.  The site is built in a ``.tmp-*`` sibling
and swapped in at the end.
"""
from __future__ import annotations

import contextlib
import shutil
import time
from importlib import resources
from pathlib import Path

import dask

from .. import __version__
from ..constants import MOON_RADIUS_M
from ..export.api import remove_stale_staging, staged_dir
from ..export.plan import albedo_sources, plan_export, scan_sources
from ..export.sources import find_sources
from ..export.stretch import Stretch
from ..export.tiling import compute_tasks, pyramid_tasks
from ..io.atomic import atomic_write_text
from ..parallel import local_workers, make_executor
from .data import footprints, js_assign, read_exposures, read_key_table, read_report, write_values
from .render import ColorTiles, GrayTiles, HillshadeTiles, colormap_lut

STATIC = ("index.html", "map.js", "panel.js", "app.css")
ERROR_COLORMAP = "magma"
OUTLIERS_COLORMAP = "inferno"  # 0 (nothing taken away) black .. 1 (rejected) pale yellow
DEM_CHANGE_COLORMAP = "RdBu_r"  # lowered blue, unchanged white, raised red
COLORMAPS = {"error": ERROR_COLORMAP, "outliers": OUTLIERS_COLORMAP, "dem_change": DEM_CHANGE_COLORMAP}
#: what a click reads from the value scripts beside albedo and error: layer -> the panel's label
VALUE_LABELS = {"albedo": "albedo", "error": "error", "outliers": "outlier weight lost",
                "dem_change": "height change (m)"}


def _copy_static(site: Path) -> None:
    root = resources.files(__package__) / "static"
    lib = site / "lib"
    for name in STATIC:
        dest = site / name if name == "index.html" else lib / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_bytes((root / name).read_bytes())
    with resources.as_file(root / "leaflet") as leaflet:
        shutil.copytree(leaflet, lib / "leaflet")


def _layer_meta(layer: str, label: str, st) -> dict:
    """What the page needs to know of a layer: its stretch and colour ramp (for the legend)."""
    meta = {"id": layer, "name": label, "stretch": None if st is None else {"lo": st.lo, "hi": st.hi, "method": st.method}}
    if layer == "dem_change":
        meta["unit"] = "m"
    if layer in COLORMAPS:
        meta["ramp"] = ["#%02x%02x%02x" % tuple(c) for c in colormap_lut(COLORMAPS[layer])[::32]]
    return meta


def _symmetric(st: Stretch) -> Stretch:
    """A stretch about 0 (a height change: unchanged is the middle of the colour map) as wide as ``st``'s wider end."""
    lim = max(abs(st.lo), abs(st.hi)) or 1.0
    return Stretch(-lim, lim, "symmetric percentile", st.percentiles)


def _optional_sources(folder: Path, what: str):
    return find_sources(folder, what) if any(folder.glob("tile_*.tif")) else []


def export_web(
    results_dir: str | Path,
    out: str | Path | None = None,
    levels: int | None = None,
    stretch: tuple[float, float] = (2.0, 98.0),
    value_range: tuple[float, float] | None = None,
    tile_size: int = 256,
    client=None,
    workers: int | None = None,
    scheduler: str | None = None,
    pool: str = "threads",
    name: str | None = None,
) -> dict:
    """Write the static web map and run report of a ``solve`` results folder.

    A Leaflet page (``index.html``, ``lib/``) that works from the file system, with tile
    layers ``tiles/<layer>/<z>/<x>/<y>.png`` of the same quadtree and albedo stretch as
    :func:`lunaralbedo.export.api.export_kml` (``albedo``; ``error``, the per-pixel error
    of the PhotometryTK manual's error equation, when ``results_dir/error`` holds tiles;
    ``outliers``, the fraction 0..1 of a pixel's observation weight the robust weights took
    away, when ``results_dir/outliers`` does; ``hillshade`` of the DEM when ``results_dir/DEM``
    does; after ``REFINE_DEM 1`` also ``hillshade_input``, the input heights' hillshade, and
    ``dem_change``, refined minus input heights in metres), and ``data/*.js``: metadata, the
    run report (``report.json``), exposures (``exposure.csv``), haze (``haze.csv``) and image
    offsets (``image_offsets.csv``), image footprints and per-pixel values of the finest
    level.  Built in a ``.tmp-*`` sibling and swapped in at the end.

    Parameters
    ----------
    results_dir : str or Path
        The ``RESULTS_DIR`` of a solve (``albedo/tile_*.tif``, ``report.json``).
    out : str or Path, optional
        Folder of the site; default ``results_dir/web``.
    levels : int, optional
        Levels of the quadtree; default as many as the data needs.
    stretch : tuple of float, default (2.0, 98.0)
        Low and high percentiles (0..100) of the albedo values of the 8-bit stretch.
    value_range : tuple of float, optional
        Albedo values ``(lo, hi)`` of the stretch; replaces ``stretch``.
    tile_size : int, default 256
        Side of a PNG tile, pixels.
    client : distributed.Client, optional
        A client the caller owns to run the tasks on (not closed here).
    workers : int, optional
        Local workers when neither ``client`` nor ``scheduler`` is given; default all cores.
    scheduler : str, optional
        Address (``tcp://host:port``) of a Dask scheduler to run the tasks on.
    pool : {"threads", "processes"}, default "threads"
        Kind of the local workers.
    name : str, optional
        Title of the map; default the folder's name.

    Returns
    -------
    dict
        ``results_dir`` and ``site`` (resolved paths, str); ``index`` (path of
        ``index.html``); ``levels``; ``tiles_per_layer`` (tiles of one layer, all levels);
        ``layers`` (ids written, e.g. ``["albedo", "error", "outliers", "hillshade"]``);
        ``value_tiles`` (finest-level tiles with per-pixel values); ``footprints`` (image
        footprints drawn); ``bounds`` (``[west, south, east, north]``, degrees);
        ``stretch`` (albedo ``lo``, ``hi``); ``seconds`` (wall time).

    Raises
    ------
    InputError
        Exit 2: no albedo tiles, no or invalid ``report.json``, an invalid
        ``exposure.csv``, ``haze.csv`` or ``image_offsets.csv``, ``tile_size`` below 16 or ``levels`` out of range.
    InfrastructureError
        Exit 3: a lost worker or a full disk.
    """
    t0 = time.perf_counter()
    results_dir = Path(results_dir).expanduser().resolve()
    out = Path(out).expanduser().resolve() if out is not None else results_dir / "web"
    report = read_report(results_dir / "report.json")
    albedo = albedo_sources(results_dir)
    errors = _optional_sources(results_dir / "error", "error")
    dem = _optional_sources(results_dir / "DEM", "DEM")
    dem_input = _optional_sources(results_dir / "dem_input", "DEM")  # REFINE_DEM 1: the heights before (docs/sfs.md)
    dem_change = _optional_sources(results_dir / "dem_change", "dem_change")  # REFINE_DEM 1: refined minus input, m
    outliers = _optional_sources(results_dir / "outliers", "outliers")  # robust weights: lost weight fraction 0..1
    exposures = read_exposures(results_dir / "exposure.csv")
    tables = {"haze": read_key_table(results_dir / "haze.csv", ("key", "haze")),
              "image_offsets": read_key_table(results_dir / "image_offsets.csv",
                                              ("key", "east_m", "north_m", "east_se_m", "north_se_m"))}
    remove_stale_staging(out.parent)

    executor = make_executor(local_workers(workers), scheduler, client=client, local=pool)
    with contextlib.closing(executor):
        # the same extent (the data, not whole solver tiles), pyramid and stretch as export-kml
        plan = plan_export(results_dir, albedo, executor, levels=levels, tile_size=tile_size, stretch=stretch,
                           value_range=value_range)
        st, grid, albedo, pyr, present, resampling = plan.stretch, plan.grid, plan.sources, plan.pyramid, plan.present, plan.resampling
        layers = [("albedo", "Albedo", albedo, GrayTiles(st, pyr.tile_size), st)]
        if errors:
            st_err, _ = scan_sources(errors, results_dir / "error", executor, (2.0, 98.0), None, "error")
            layers.append(("error", "Error (eq. 7)", errors, ColorTiles(st_err, colormap_lut(ERROR_COLORMAP), pyr.tile_size), st_err))
        if outliers:  # a fraction: the same 0..1 colours in every run
            st_out = Stretch(0.0, 1.0, "range")
            layers.append(("outliers", "Outliers (weight lost)", outliers,
                           ColorTiles(st_out, colormap_lut(OUTLIERS_COLORMAP), pyr.tile_size), st_out))
        if dem:
            layers.append(("hillshade", "DEM hillshade" + (" (refined)" if dem_input else ""), dem,
                           HillshadeTiles(pyr.tile_size), None))
        if dem_input:
            layers.append(("hillshade_input", "DEM hillshade before REFINE_DEM", dem_input, HillshadeTiles(pyr.tile_size),
                           None))
        if dem_change:
            st_dz = _symmetric(scan_sources(dem_change, results_dir / "dem_change", executor, (2.0, 98.0), None,
                                            "dem_change")[0])
            layers.append(("dem_change", "DEM change (refined - input)", dem_change,
                           ColorTiles(st_dz, colormap_lut(DEM_CHANGE_COLORMAP), pyr.tile_size), st_dz))
        drg_dir = Path(report.get("settings", {}).get("drg_dir", ""))
        centre_lon = (grid.bounds[0] + grid.bounds[2]) / 2

        task = dask.delayed(pure=False)
        with staged_dir(out) as site:
            tasks = []
            for layer, _, sources, writer, _ in layers:
                tasks += pyramid_tasks(site / "tiles" / layer, plan, sources, writer)
            value_layers = {"albedo": albedo, "error": errors, "outliers": outliers, "dem_change": dem_change}
            finest = present[pyr.levels - 1]
            tasks += [task(write_values)(site, node, value_layers, resampling) for node in finest]
            tasks.append(task(footprints)(drg_dir, exposures, centre_lon, tables["image_offsets"]))
            results = compute_tasks(tasks, executor)
            fc = results[-1]
            _copy_static(site)
            fh, fw = pyr.level_shape(pyr.levels - 1)
            meta = {
                "name": name or results_dir.name,
                "generator": f"lunaralbedo {__version__}",
                "radius_m": MOON_RADIUS_M,
                "bounds": list(pyr.bounds),
                "levels": pyr.levels,
                "tile_size": pyr.tile_size,
                "root_size": [pyr.root_width, pyr.root_height],
                "finest_size": [fw, fh],
                "native_size": [grid.width, grid.height],
                "tiles": {str(k): [[n.col, n.row] for n in present[k]] for k in range(pyr.levels)},
                "layers": [_layer_meta(lid, label, s) for lid, label, _, _, s in layers],
                "values": [k for k, v in value_layers.items() if v],
                "value_labels": {k: VALUE_LABELS[k] for k, v in value_layers.items() if v},
                "footprints": len(fc["features"]),
            }
            atomic_write_text(site / "data" / "meta.js", js_assign("LUNARALBEDO_META", meta))
            atomic_write_text(site / "data" / "report.js", js_assign("LUNARALBEDO_REPORT", report)
                              + js_assign("LUNARALBEDO_EXPOSURES", exposures) + js_assign("LUNARALBEDO_TABLES", tables))
            atomic_write_text(site / "data" / "footprints.js", js_assign("LUNARALBEDO_FOOTPRINTS", fc))
    return {
        "results_dir": str(results_dir),
        "site": str(out),
        "index": str(out / "index.html"),
        "levels": pyr.levels,
        "tiles_per_layer": sum(len(v) for v in present.values()),
        "layers": [lid for lid, *_ in layers],
        "value_tiles": len(present[pyr.levels - 1]),
        "footprints": len(fc["features"]),
        "bounds": list(pyr.bounds),
        "stretch": {"lo": st.lo, "hi": st.hi},
        "seconds": round(time.perf_counter() - t0, 3),
    }
