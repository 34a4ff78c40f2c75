"""``align`` file handling: read the DEM and the reference, run :func:`~.align.icp`, write ``pc_align``-like outputs.

Units: lon/lat in degrees (planetocentric, east-positive), radius in km in the CSV
files (as LOLA RDR exports), errors and DEM heights in metres, transforms in Moon
body-fixed metres.  Outputs (atomic): ``PREFIX-transform.txt`` /
``PREFIX-inverse-transform.txt`` (4x4, maps the DEM onto the reference / back),
``PREFIX-beg_errors.csv`` / ``PREFIX-end_errors.csv`` (``lon,lat,radius,error`` per
reference point within ``--max-displacement`` that meets the DEM, as ``pc_align`` writes them;
error = absolute vertical distance to the bilinearly interpolated DEM), ``PREFIX-trans_dem.tif`` (the aligned DEM on
the source grid), ``PREFIX-report.json``, ``PREFIX-log.txt`` and ``PREFIX-errors.png``.

Only the reference points over the source DEM take part (a global reference DEM against a
small source: the points of its footprint), at most :data:`MAX_REFERENCE_POINTS` of them
(an even subsample, as ``pc_align --max-num-reference-points``); inputs that do not overlap,
or too few points to fix a rigid transform, are refused (exit 2) before anything is written.
"""
from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np

from ..constants import MOON_RADIUS_M
from ..errors import InputError
from ..ingest.dem import DemSource, load_dems
from ..io.atomic import atomic_write_text
from ..io.outputs import save_figure
from ..io.geotiff import write_geotiff
from ..model.geometry import body_fixed, dem_normals, lonlat_height
from .align import apply, ce90_le90, error_stats, icp

#: Most reference points used (an even subsample beyond): each ICP iteration queries them all.
MAX_REFERENCE_POINTS = 100_000
#: Fewest reference points over the DEM that ``align`` accepts (a rigid transform has 6 unknowns).
MIN_POINTS = 6
_OUTPUTS = ("-transform.txt", "-inverse-transform.txt", "-beg_errors.csv", "-end_errors.csv", "-trans_dem.tif",
            "-errors.png", "-report.json", "-log.txt")

_LON = ("lon", "longitude", "pt_longitude")
_LAT = ("lat", "latitude", "pt_latitude")
_RAD = ("radius", "pt_radius", "radius_km")


def read_reference_csv(path: Path) -> np.ndarray:
    """``(n, 3)`` lon (deg), lat (deg), radius (km) from a CSV with a ``lon,lat,radius`` header (or none)."""
    try:
        with open(path, newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    except OSError as exc:
        raise InputError(f"{path}: cannot read reference points: {exc}") from None
    if not rows:
        raise InputError(f"{path}: no reference points")
    head = [c.strip().lower() for c in rows[0]]
    cols = (0, 1, 2)
    if any(c in _LON for c in head):
        try:
            cols = tuple(next(i for i, c in enumerate(head) if c in names) for names in (_LON, _LAT, _RAD))
        except StopIteration:
            raise InputError(f"{path}: header must name lon, lat and radius columns, got {rows[0]}") from None
        rows = rows[1:]
    try:
        pts = np.array([[float(r[c]) for c in cols] for r in rows], dtype=np.float64)
    except (ValueError, IndexError) as exc:
        raise InputError(f"{path}: reference rows must be numbers lon,lat,radius(km): {exc}") from None
    if pts.size == 0 or not np.isfinite(pts).all():
        raise InputError(f"{path}: reference points are empty or not finite")
    if np.median(pts[:, 2]) > 1.0e5:
        raise InputError(f"{path}: radius must be in km (median {np.median(pts[:, 2]):.0f} looks like metres)")
    return pts


def dem_lonlat(src: DemSource) -> tuple[np.ndarray, np.ndarray]:
    """Lon/lat (degrees) of the DEM's pixel centres."""
    rows, cols = np.mgrid[0:src.heights.shape[0], 0:src.heights.shape[1]] + 0.5
    x, y = src.transform * (cols, rows)
    if src.geographic:
        return np.asarray(x), np.asarray(y)
    from rasterio.warp import transform as warp_transform

    from ..io.rasters import MOON_CRS

    lon, lat = warp_transform(src.crs, MOON_CRS, x.ravel().tolist(), y.ravel().tolist())
    return np.reshape(lon, x.shape), np.reshape(lat, x.shape)


def dem_cloud(src: DemSource):
    """DEM surface points and unit normals ``(n, 3)`` (body-fixed m) of the valid pixels."""
    lon, lat = dem_lonlat(src)
    pts_km = body_fixed(lon, lat, src.heights)
    normals = dem_normals(pts_km)
    ok = np.isfinite(pts_km).all(axis=-1) & np.isfinite(normals).all(axis=-1)
    return pts_km[ok] * 1000.0, normals[ok]


def reference_points(path: Path, dem_mode: str) -> np.ndarray:
    """Reference as lon, lat, radius (km) rows: a CSV, or every valid pixel of a reference DEM."""
    if path.suffix.lower() in (".csv", ".txt"):
        return read_reference_csv(path)
    ref = load_dems([path], dem_mode)[0]
    lon, lat = dem_lonlat(ref)
    ok = np.isfinite(ref.heights)
    return np.stack([lon[ok], lat[ok], (MOON_RADIUS_M + ref.heights[ok]) / 1000.0], axis=1)


def vertical_errors(src: DemSource, points_m: np.ndarray) -> np.ndarray:
    """Absolute radius difference (m) between points and the DEM interpolated at their lon/lat (NaN off the DEM)."""
    lon, lat, h = lonlat_height(points_m / 1000.0)
    return np.abs(h - src.sample(lon, lat))


def transformed_dem(src: DemSource, transform: np.ndarray, iterations: int = 4) -> np.ndarray:
    """Heights (m) of the DEM surface moved by ``transform``, on the source grid (fixed-point iteration)."""
    lon, lat = dem_lonlat(src)
    inv = np.linalg.inv(transform)
    h = np.where(np.isfinite(src.heights), src.heights, 0.0)
    for _ in range(iterations):
        q = apply(inv, body_fixed(lon, lat, h) * 1000.0) / 1000.0  # grid node in the source's frame
        lq, bq, _ = lonlat_height(q)
        moved = apply(transform, body_fixed(lq, bq, src.sample(lq, bq)) * 1000.0) / 1000.0
        h = lonlat_height(moved)[2]
    return h


def _matrix_text(m: np.ndarray) -> str:
    return "\n".join(" ".join(f"{v:.17g}" for v in row) for row in m) + "\n"


def _errors_csv(ref: np.ndarray, err: np.ndarray) -> str:
    rows = ["lon,lat,radius,error"] + [f"{lo:.8f},{la:.8f},{r:.6f},{e:.4f}" for (lo, la, r), e in zip(ref, err)]
    return "\n".join(rows) + "\n"


def plot_errors(path: Path, beg: np.ndarray, end: np.ndarray) -> None:
    """Histograms of the absolute errors before and after alignment (log-spaced bins)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    b, e = beg[np.isfinite(beg)], end[np.isfinite(end)]
    if b.size == 0 or e.size == 0:
        return
    lo = max(1e-3, float(min(np.percentile(b, 1), np.percentile(e, 1))))
    hi = float(max(b.max(), e.max())) * 1.1
    bins = np.geomspace(lo, hi, 60)
    fig, ax = plt.subplots(figsize=(6, 3.4))
    ax.hist(b, bins, alpha=0.6, label=f"before (median {np.median(b):.2f} m)")
    ax.hist(e, bins, alpha=0.6, label=f"after (median {np.median(e):.2f} m)")
    ax.set_xscale("log")
    ax.set_xlabel("|vertical error| to the DEM at each reference point (m)")
    ax.set_ylabel("points")
    ax.legend()
    ax.set_title("DEM vs reference before and after alignment")
    fig.tight_layout()
    save_figure(fig, path)


def _log_text(report: dict) -> str:
    out = [f"source DEM: {report['source']}", f"reference: {report['reference']} ({report['reference_points']} points "
           f"over the DEM of {report.get('reference_points_given', report['reference_points'])}, "
           f"{report['inliers']} within --max-displacement {report['max_displacement']} m)",
           f"method: {report['method']}{' (translation only)' if report['translation_only'] else ''}; "
           f"{report['iterations']} iterations, converged: {report['converged']}; {report['points_per_second']:,.0f} points/s"]
    for tag in ("before", "after"):
        s = report[tag]
        out.append(f"{tag.capitalize()}: error percentile of smallest errors (meters): 16%: {s['p16']:.4g}, "
                   f"50%: {s['p50']:.4g}, 84%: {s['p84']:.4g}")
        out.append(f"{tag.capitalize()}: mean {s['mean']:.4g}, std {s['std']:.4g}, RMSE {s['rmse']:.4g}, median "
                   f"{s['median']:.4g}, NMAD {s['nmad']:.4g}; CE90 {s['ce90']:.4g} m, LE90 {s['le90']:.4g} m")
    t = report["translation_at_dem_centre"]
    out.append(f"Translation at the DEM centre (north, east, down) m: {t['north']:.3f} {t['east']:.3f} {t['down']:.3f}; "
               f"horizontal {t['horizontal']:.3f} m")
    return "\n".join(out) + "\n"


def _over_dem(src: DemSource, ref: np.ndarray, reference: Path, source: Path) -> np.ndarray:
    """The reference rows over the source DEM (finite height under them), evenly subsampled to at most
    :data:`MAX_REFERENCE_POINTS`; :class:`InputError` when fewer than :data:`MIN_POINTS`."""
    over = np.isfinite(src.sample(ref[:, 0], ref[:, 1]))
    if over.sum() < MIN_POINTS:
        raise InputError(f"{reference}: only {int(over.sum())} of its {len(ref)} points lie over the DEM {source} "
                         f"(need at least {MIN_POINTS}): the two do not overlap")
    ref = ref[over]
    if len(ref) > MAX_REFERENCE_POINTS:
        ref = ref[np.linspace(0, len(ref) - 1, MAX_REFERENCE_POINTS).astype(int)]
    return ref


def align_files(source: str | Path, reference: str | Path, prefix: str | Path, max_displacement: float = np.inf,
                method: str = "point-to-plane", translation_only: bool = False, outlier_ratio: float = 0.75,
                dem_mode: str = "auto", on_iteration=None) -> dict:
    """Align a DEM onto reference points (LOLA shots or a reference DEM) and write ``pc_align``-like outputs.

    ASP ``pc_align``, as the ASP LRO-NAC notes use it: the reference points over the DEM
    (at most :data:`MAX_REFERENCE_POINTS`, an even subsample) are matched to the DEM's
    surface points by iterative closest point (:func:`lunaralbedo.nac.align.icp`), giving
    the rigid transform that moves the DEM onto the reference.  Writes, atomically and only
    when the alignment succeeds: ``PREFIX-transform.txt`` / ``-inverse-transform.txt``
    (4x4, Moon body-fixed metres), ``-beg_errors.csv`` / ``-end_errors.csv``
    (``lon,lat,radius,error`` per used point that meets the DEM: degrees, km, and the
    absolute vertical distance in metres to the bilinearly interpolated DEM),
    ``-trans_dem.tif`` (the moved DEM's heights on the source grid, metres, float32),
    ``-report.json``, ``-log.txt`` and ``-errors.png``.

    Parameters
    ----------
    source : str or Path
        The DEM to move (GeoTIFF or ISIS DEM cube).
    reference : str or Path
        Reference: a CSV (``.csv``/``.txt``) of longitude, latitude (degrees,
        planetocentric, east-positive) and radius (km), as LOLA RDR exports, or a DEM
        whose every valid pixel is a point.
    prefix : str or Path
        Prefix of the output files.
    max_displacement : float, default inf
        Reference points farther than this from the DEM at the start are dropped for good,
        metres (``pc_align --max-displacement``).
    method : {"point-to-plane", "point-to-point"}, default "point-to-plane"
        ICP error metric (Chen & Medioni 1992, or Besl & McKay 1992).
    translation_only : bool, default False
        Solve for a translation only (no rotation).
    outlier_ratio : float, default 0.75
        Fraction (0, 1] of the closest pairs kept at each iteration (``pc_align
        --outlier-ratio``).
    dem_mode : {"auto", "radius", "height"}, default "auto"
        How to read DEM values (radius in metres, or height above 1737.4 km).
    on_iteration : callable, optional
        Called as ``on_iteration(iteration, mean inlier distance in metres)`` after each
        ICP iteration (progress).

    Returns
    -------
    dict
        The report (also ``PREFIX-report.json``): ``source``, ``reference``;
        ``reference_points`` (used, over the DEM) and ``reference_points_given``;
        ``inliers``; the options ``max_displacement``, ``method``, ``translation_only``,
        ``outlier_ratio``; ``iterations``, ``converged``, ``seconds``,
        ``points_per_second``; ``before`` and ``after`` (absolute vertical errors in metres
        as ``pc_align`` prints them: ``count``, ``p16``, ``p50``, ``p84``, ``mean``,
        ``std``, ``rmse``, ``median``, ``nmad``, and ``ce90``/``le90``);
        ``translation_at_dem_centre`` (``north``, ``east``, ``down``, ``horizontal``,
        metres); ``ce90_le90`` (their definition) and ``transform`` (4x4 nested list,
        body-fixed metres, DEM onto reference).

    Raises
    ------
    InputError
        Exit 2, nothing written: the reference missing or unreadable, an invalid
        ``max_displacement``/``outlier_ratio``/``method``, inputs that do not overlap, fewer
        than :data:`MIN_POINTS` points over the DEM (before or after the alignment), or
        degenerate geometry.
    OSError
        An output cannot be written (what was written is removed); the CLI reports a full
        disk as :class:`~lunaralbedo.errors.DiskFullError`, exit 3.
    """
    from scipy.spatial import cKDTree

    source, reference, prefix = Path(source), Path(reference), Path(prefix)
    if not reference.is_file():
        raise InputError(f"{reference}: reference file not found")
    if not (max_displacement > 0):
        raise InputError(f"--max-displacement must be > 0 m, got {max_displacement}")
    if not 0 < outlier_ratio <= 1:
        raise InputError(f"--outlier-ratio must be in (0, 1], got {outlier_ratio}")
    src = load_dems([source], dem_mode)[0]
    ref_all = reference_points(reference, dem_mode)
    ref = _over_dem(src, ref_all, reference, source)
    ref_m = body_fixed(ref[:, 0], ref[:, 1], ref[:, 2] * 1000.0 - MOON_RADIUS_M) * 1000.0
    pts, normals = dem_cloud(src)
    if len(pts) < MIN_POINTS:
        raise InputError(f"{source}: only {len(pts)} DEM pixels with a surface normal (need at least {MIN_POINTS})")
    t0 = time.perf_counter()
    tree = cKDTree(pts)
    res = icp(ref_m, pts, normals, method, max_displacement, outlier_ratio, translation_only, tree=tree,
              on_iteration=on_iteration)
    seconds = time.perf_counter() - t0
    used, used_m = ref[res.inliers], ref_m[res.inliers]
    beg = vertical_errors(src, used_m)
    moved = apply(res.inverse, used_m)  # reference points in the source DEM's frame
    end = vertical_errors(src, moved)
    meets = np.isfinite(beg) & np.isfinite(end)  # pc_align lists only the points that meet the DEM
    used, used_m, moved, beg, end = used[meets], used_m[meets], moved[meets], beg[meets], end[meets]
    if len(used) < MIN_POINTS:
        raise InputError(f"{reference}: the alignment moved the reference points off the DEM {source} ({len(used)} of "
                         f"{len(ref)} still on it, need {MIN_POINTS}): too few points over the DEM to fix a rigid "
                         "transform; use a denser reference, --translation-only or --max-displacement")
    before, after = error_stats(beg), error_stats(end)
    before["ce90"], before["le90"] = ce90_le90(used_m, pts, normals, tree)
    after["ce90"], after["le90"] = ce90_le90(moved, pts, normals, tree)
    centre = pts.mean(axis=0)
    shift = apply(res.transform, centre) - centre
    up = centre / np.linalg.norm(centre)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    report = {
        "source": str(source), "reference": str(reference), "reference_points": int(len(ref)),
        "reference_points_given": int(len(ref_all)),
        "inliers": int(res.inliers.sum()), "max_displacement": float(max_displacement), "method": method,
        "translation_only": translation_only, "outlier_ratio": outlier_ratio, "iterations": res.iterations,
        "converged": res.converged, "seconds": seconds, "points_per_second": len(ref) * res.iterations / seconds,
        "before": before, "after": after,
        "translation_at_dem_centre": {"north": float(shift @ north), "east": float(shift @ east),
                                      "down": float(-shift @ up), "horizontal": float(np.hypot(shift @ north, shift @ east))},
        "ce90_le90": "90th percentiles of the horizontal and vertical parts of each reference point's offset "
                     "from the tangent plane at its nearest DEM point",
        "transform": res.transform.tolist(),
    }
    trans_dem = transformed_dem(src, res.transform).astype(np.float32)
    paths = [Path(f"{prefix}{suffix}") for suffix in _OUTPUTS]
    try:
        atomic_write_text(paths[0], _matrix_text(res.transform))
        atomic_write_text(paths[1], _matrix_text(res.inverse))
        atomic_write_text(paths[2], _errors_csv(used, beg))
        atomic_write_text(paths[3], _errors_csv(used, end))
        write_geotiff(paths[4], trans_dem, src.transform, src.crs, nodata=np.nan, dtype="float32")
        plot_errors(paths[5], beg, end)
        atomic_write_text(paths[6], json.dumps(report, indent=1) + "\n")
        atomic_write_text(paths[7], _log_text(report))
    except BaseException:
        for p in paths:
            p.unlink(missing_ok=True)
        raise
    return report
