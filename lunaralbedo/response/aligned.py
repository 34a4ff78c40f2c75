"""``lunaralbedo response``: the aligned case of Kim et al. (section 3) (a co-registered stack of one scene).

Reads the images (band 1 DN, the GDAL mask as the paper's D_j), fits g, r and (unless
given) t by :func:`lunaralbedo.response.smoothing.fit_regularised` on a deterministic
subsample of pixels, computes the radiance of every pixel by eq. 10, and writes into
OUTDIR: ``response.csv``, ``radiance.tif``, ``exposure.csv`` (when estimated),
``report.json`` and the plots ``response.png`` (the paper's fig. 8), ``exposure.png`` (fig. 9),
``loglik.png`` and ``residuals.png``.  Nothing is written before the fit succeeded.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..io import outputs
from . import io as rio
from ..io.geotiff import write_geotiff
from .fit import ResponseFit
from .model import observations_from_stack, radiance_map
from .smoothing import fit_regularised


@dataclass
class Stack:
    """An aligned stack: DN (n, h, w) int16, validity, names, georeferencing of the first image."""

    dn: np.ndarray
    valid: np.ndarray
    names: list[str]
    transform: object
    crs: object


def read_stack(paths: Sequence[str | Path]) -> Stack:
    """Band 1 of every image (integer DN 0..255) and its mask; all must share one grid."""
    import rasterio

    if len(paths) < 2:
        raise InputError("the response needs at least two images of the same scene")
    dns, masks = [], []
    transform = crs = shape = None
    for p in paths:
        try:
            with rasterio.open(p) as ds:
                v = ds.read(1)
                m = ds.read_masks(1) > 0
                if shape is None:
                    shape, transform, crs = v.shape, ds.transform, ds.crs
                elif v.shape != shape:
                    raise InputError(f"{p}: {v.shape[1]}x{v.shape[0]} px, but {paths[0]} is {shape[1]}x{shape[0]}; "
                                     "the aligned case needs co-registered images on one grid")
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{p}: cannot read as a raster ({exc})") from None
        if not np.issubdtype(v.dtype, np.integer) or (m.any() and (v[m].min() < 0 or v[m].max() > 255)):
            raise InputError(f"{p}: band 1 must hold 8-bit DN (integers 0..255), found {v.dtype}")
        dns.append(v.astype(np.int16))
        masks.append(m)
    return Stack(np.stack(dns), np.stack(masks), [str(p) for p in paths], transform, crs)


def exposures_for(names: Sequence[str], table: dict[str, float], source: Path) -> np.ndarray:
    """Exposure time of each image from a table keyed by the file name as given (or its base name)."""
    out = []
    for n in names:
        t = table.get(n, table.get(Path(n).name))
        if t is None:
            raise InputError(f"{source}: no exposure for image {n!r}")
        out.append(t)
    return np.array(out, np.float64)


def subsample(n_pixels: int, max_pixels: int, seed: int = 0) -> np.ndarray:
    """A fixed random subset of pixel indices (sorted), all of them when there are few."""
    if n_pixels <= max_pixels:
        return np.arange(n_pixels)
    return np.sort(np.random.default_rng(seed).choice(n_pixels, max_pixels, replace=False))


def fit_stack(stack: Stack, exposure: np.ndarray | None, min_count: int = 20, max_pixels: int = 200_000,
              exclude=(0, 255)) -> ResponseFit:
    """Fit the response to (a subsample of) the stack's pixels."""
    n, h, w = stack.dn.shape
    pick = subsample(h * w, max_pixels)
    dn = stack.dn.reshape(n, -1)[:, pick]
    obs = observations_from_stack(dn, stack.valid.reshape(n, -1)[:, pick])
    return fit_regularised(obs, exposure, min_count=min_count, exclude=exclude)


def recover_response(images: Sequence[str | Path], out_dir: str | Path, exposure_times: str | Path | None = None,
                     min_count: int = 20, max_pixels: int = 200_000, plots: bool = True) -> dict:
    """Recover the camera response, exposure times and radiance of a co-registered image stack.

    The aligned case of Kim et al. (section 3): with :math:`x_n = g(z_n)` the exposure of
    observation :math:`n` (pixel :math:`i` in image :math:`j`, digital number :math:`z_n`,
    :math:`g` the inverse camera response), Poisson with mean :math:`r_i t_j`, the fit
    maximises the likelihood (their eq. 8) under :math:`g` non-decreasing (eq. 7) by
    :func:`lunaralbedo.response.fit.fit_response` on a fixed subsample of pixels; then the
    radiance of every pixel is :math:`r = \\sum_j g(z_j) / \\sum_j t_j` over its valid DN
    (eq. 10).  Writes into ``out_dir``: ``response.csv`` (``g`` per DN with its standard
    error), ``radiance.tif`` (float32, the first image's georeference, NaN where no image
    has a usable DN), ``exposure.csv`` (when estimated), ``report.json`` and, with
    ``plots``, ``response.png``, ``exposure.png``, ``loglik.png``, ``residuals.png``.
    Nothing is written before the fit succeeded.

    Parameters
    ----------
    images : sequence of str or Path
        At least two rasters of one scene on one grid; band 1 holds 8-bit DN (integers
        0..255), its GDAL mask marks the valid pixels.
    out_dir : str or Path
        Folder to write.
    exposure_times : str or Path, optional
        CSV with a header holding an ``exposure`` column, the first column naming the
        image (as given, or its base name): the exposure times are then known (any unit;
        only ratios matter).  None: they are estimated, with geometric mean 1.
    min_count : int, default 20
        Observations a DN level needs to be a free level of ``g`` (the others are
        interpolated in :math:`\\ln g`).
    max_pixels : int, default 200000
        Pixels fitted at most (a fixed random subsample beyond; the radiance covers all).
    plots : bool, default True
        Write the PNG plots.

    Returns
    -------
    dict
        The report (also ``report.json``): ``dn`` and ``g`` (the curve over the fitted DN
        range, normalised to ``g(128) = 1``), ``dn_range``, ``free_levels``,
        ``interpolated_levels``, ``normalisation``, ``exposures`` (image name to exposure),
        ``identifiability`` (the gauge of the exponential ambiguity when exposures are
        estimated), ``converged``, ``convergence`` (message), ``flat_steps``, ``warnings``
        (plain-language, e.g. a largely flat curve), ``loglik`` (eq. 8 per iteration),
        ``iterations``, ``residuals`` (per-DN ``dn``, ``bias_log``, ``std_log``, ``count``;
        ``chi2_per_dof``, ``rms_log``, ``n_obs``, ``n_params``) and
        ``radiance_valid_pixels``.

    Raises
    ------
    InputError
        Exit 2: fewer than two images, an unreadable image, images on different grids,
        band 1 not 8-bit DN, an exposure table without an ``exposure`` column or without a
        row for an image, or fewer than three DN levels with ``min_count`` observations.
    """
    stack = read_stack(images)
    t_known = None
    if exposure_times is not None:
        t_known = exposures_for(stack.names, rio.read_exposure_table(exposure_times), Path(exposure_times))
    fit = fit_stack(stack, t_known, min_count=min_count, max_pixels=max_pixels)
    radiance = radiance_map(stack.dn, stack.valid, fit.lut(), fit.exposure)
    out = Path(out_dir)
    write_outputs(out, fit, stack.names, plots, exposure_given=t_known is not None)
    write_geotiff(out / "radiance.tif", radiance, stack.transform, stack.crs, nodata=float("nan"))
    report = fit_report(fit, stack.names)
    report["radiance_valid_pixels"] = int(np.isfinite(radiance).sum())
    outputs.write_json(out / "report.json", report)
    return report


def write_outputs(out: Path, fit: ResponseFit, names: Sequence[str], plots: bool, exposure_given: bool) -> None:
    """response.csv, exposure.csv (when estimated) and the plots."""
    lev, res = fit.levels, fit.residuals
    free = np.isin(lev.dn, lev.knots)
    rio.write_response_csv(out / "response.csv", lev.dn, fit.g, res["se_log_g"], lev.counts[lev.dn], free)
    if not exposure_given:
        rio.write_exposure_table(out / "exposure.csv", names, fit.exposure)
    if plots:
        rio.plot_response(out / "response.png", lev.dn, fit.g, fit.g_initial, res["se_log_g"])
        if not exposure_given:
            outputs.plot_exposures(out / "exposure.png", [Path(n).stem[-24:] for n in names], fit.exposure,
                                   np.ones_like(fit.exposure))
        rio.plot_loglik(out / "loglik.png", fit.loglik, fit.n_juggle)
        rio.plot_residuals(out / "residuals.png", lev.dn, res)


#: More than this fraction of flat steps of g (eq. 7 active) and the report warns that the data do not determine g.
FLAT_WARNING = 0.25


def warnings_for(fit: ResponseFit) -> list[str]:
    """Plain-language warnings of a fit: not converged, largely flat (pooled) curve."""
    out = []
    if not fit.converged:
        out.append(f"the response fit did not converge ({fit.message})")
    flat = int(np.sum(np.diff(fit.g) == 0))
    if flat > FLAT_WARNING * max(len(fit.g) - 1, 1):
        out.append(f"{flat} of {len(fit.g) - 1} steps of g are flat (eq. 7 active): the data do not determine the "
                   "response there (chi2/dof {:.3g}); do not use this curve for science".format(fit.residuals["chi2_per_dof"]))
    return out


def longest_flat_run(g: np.ndarray) -> int:
    """The most consecutive DN that share one g (0: strictly increasing)."""
    run = best = 0
    for flat in np.diff(g) == 0:
        run = run + 1 if flat else 0
        best = max(best, run)
    return best + 1 if best else 0


def fit_report(fit: ResponseFit, names: Sequence[str]) -> dict:
    """The fit as JSON: the curve (``dn``, ``g`` first: the web panel plots the first two
    equal-length number lists), scalars, and ``residuals`` (summary and per-DN lists over
    the DN with observations; no NaN, which JSON cannot carry)."""
    res, dn = fit.residuals, fit.levels.dn
    seen = np.isfinite(res["bias_log"]) & np.isfinite(res["std_log"])
    per_dn = {k: np.asarray(res[k])[seen].tolist() for k in ("bias_log", "std_log")}
    return {
        "dn": dn.tolist(),
        "g": np.asarray(fit.g, np.float64).tolist(),
        "dn_range": [fit.levels.lo, fit.levels.hi],
        "free_levels": len(fit.levels.knots),
        "interpolated_levels": int(len(fit.levels.dn) - len(fit.levels.knots)),
        "normalisation": f"g({fit.z_ref}) = 1",
        "exposures": dict(zip(names, fit.exposure.tolist())),
        "identifiability": fit.gamma,
        "converged": fit.converged,
        "convergence": fit.message,
        "flat_steps": int(np.sum(np.diff(fit.g) == 0)),
        "longest_flat_run_dn": longest_flat_run(fit.g),
        "smoothing": fit.smoothing,
        "warnings": warnings_for(fit),
        "loglik": fit.loglik,
        "iterations": {"alternation": fit.n_juggle, "newton": fit.newton,
                       "active_set_passes": fit.passes},
        "residuals": {"dn": dn[seen].tolist(), **per_dn, "count": np.asarray(res["count"])[seen].astype(int).tolist(),
                      **{k: res[k] for k in ("chi2_per_dof", "rms_log", "n_obs", "n_params")}},
    }
