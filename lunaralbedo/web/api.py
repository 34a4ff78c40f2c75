"""``export_web``: the static web map and run report of a RESULTS_DIR.

Layout of the site (``RESULTS_DIR/web/`` by default)::

    index.html                     the page (map + run report panel)
    lib/leaflet/                   Leaflet 1.9.4 and its licence (vendored package data)
    lib/app.js, lib/app.css        the page's code
    tiles/<layer>/<z>/<x>/<y>.png  albedo, error, hillshade: the KML pyramid's layout (export/tiling.py)
    data/*.js                      meta, report, footprints, per-tile values (see :mod:`.data`)

The tiles of every layer are the quadtree of :mod:`..export.pyramid` over the albedo
tiles (level 0 = one tile of at most ``tile_size`` px; row 0 at the north edge), with
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
from ..export.api import check_pixel_size, compute_tasks, data_grid, remove_stale_staging, scan_sources, staged_dir
from ..export.extent import clip
from ..export.pyramid import plan_pyramid, present_nodes
from ..export.sources import find_sources
from ..export.tiling import level_resampling, pyramid_children, pyramid_tasks
from ..io.atomic import atomic_write_text
from ..parallel import local_workers, make_executor
from .data import footprints, js_assign, read_exposures, read_report, write_values
from .render import ColorTiles, GrayTiles, HillshadeTiles, colormap_lut

STATIC = ("index.html", "map.js", "panel.js", "app.css")
ERROR_COLORMAP = "magma"


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
    if layer == "error":
        meta["ramp"] = ["#%02x%02x%02x" % tuple(c) for c in colormap_lut(ERROR_COLORMAP)[::32]]
    return meta


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
    """Write the web map of ``results_dir`` to ``out`` (default ``results_dir/web``); return a summary.

    Options as :func:`lunaralbedo.export.export_kml` (same pyramid, same albedo stretch, same
    executor options: ``client``, ``scheduler``, ``workers``, ``pool``).
    """
    t0 = time.perf_counter()
    results_dir = Path(results_dir).expanduser().resolve()
    out = Path(out).expanduser().resolve() if out is not None else results_dir / "web"
    report = read_report(results_dir / "report.json")
    albedo = find_sources(results_dir / "albedo", "albedo")
    check_pixel_size(albedo, results_dir / "albedo")
    errors = _optional_sources(results_dir / "error", "error")
    dem = _optional_sources(results_dir / "DEM", "DEM")
    dem_input = _optional_sources(results_dir / "dem_input", "DEM")  # REFINE_DEM 1: the heights before (docs/sfs.md)
    exposures = read_exposures(results_dir / "exposure.csv")
    remove_stale_staging(out.parent)

    executor = make_executor(local_workers(workers), scheduler, client=client, local=pool)
    with contextlib.closing(executor):
        # the same extent (the data, not whole solver tiles), pyramid and stretch as export-kml
        st, scans = scan_sources(albedo, results_dir / "albedo", executor, stretch, value_range)
        grid, albedo, _ = data_grid(results_dir, albedo, scans)
        pyr = plan_pyramid(grid.bounds, grid.shape, tile_size, levels)
        present = present_nodes(pyr, [clip(s.bounds, grid.bounds) for s in albedo])
        children = pyramid_children(pyr, present)
        resampling = level_resampling(pyr, pyr.levels - 1, grid)
        layers = [("albedo", "Albedo", albedo, GrayTiles(st, pyr.tile_size), st)]
        if errors:
            st_err, _ = scan_sources(errors, results_dir / "error", executor, (2.0, 98.0), None, "error")
            layers.append(("error", "Error (eq. 7)", errors, ColorTiles(st_err, colormap_lut(ERROR_COLORMAP), pyr.tile_size), st_err))
        if dem:
            layers.append(("hillshade", "DEM hillshade" + (" (refined)" if dem_input else ""), dem,
                           HillshadeTiles(pyr.tile_size), None))
        if dem_input:
            layers.append(("hillshade_input", "DEM hillshade before REFINE_DEM", dem_input, HillshadeTiles(pyr.tile_size),
                           None))
        drg_dir = Path(report.get("settings", {}).get("drg_dir", ""))
        centre_lon = (grid.bounds[0] + grid.bounds[2]) / 2

        task = dask.delayed(pure=False)
        with staged_dir(out) as site:
            tasks = []
            for layer, _, sources, writer, _ in layers:
                tasks += pyramid_tasks(site / "tiles" / layer, pyr, present, children, sources, writer, resampling)
            value_layers = {"albedo": albedo, "error": errors}
            finest = present[pyr.levels - 1]
            tasks += [task(write_values)(site, node, value_layers, resampling) for node in finest]
            tasks.append(task(footprints)(drg_dir, exposures, centre_lon))
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
                "footprints": len(fc["features"]),
            }
            atomic_write_text(site / "data" / "meta.js", js_assign("LUNARALBEDO_META", meta))
            atomic_write_text(site / "data" / "report.js", js_assign("LUNARALBEDO_REPORT", report) + js_assign("LUNARALBEDO_EXPOSURES", exposures))
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
