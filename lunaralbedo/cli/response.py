"""``lunaralbedo response IMAGES... -o OUTDIR``: camera response of an aligned image stack (Kim et al.)."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import reports_errors


def identifiability_line(ident: dict) -> str:
    """One line on how the exponential ambiguity was resolved (shared with ``solve``)."""
    if ident["exposures_known"]:
        return "exposure times given: g identified up to the one global scale"
    geo = ident.get("geometry") or {}
    if ident.get("gauge") == "geometry":
        how = "fitted under it" if ident.get("mode") == "constraint" else "its power applied to the prior's curve"
        return f"exposure times estimated; gamma from the reflectance geometry ({how}): {geo['reason']}"
    why = f" (geometry not used: {geo['reason']})" if geo else ""
    return f"exposure times estimated; exponential ambiguity fixed by the prior: {ident['prior']}{why}"


def smoothing_line(sm: dict) -> str:
    """One line on the roughness weight and how much of g the exposure ratios determine (shared with ``solve``)."""
    d = sm.get("exposure_ratios") or {}
    seen = (f"; exposure ratios: waves of period x{d['worst_period_ratio']:.2f} in exposure are "
            f"{d['min_visibility']:.0%} visible to the data" if d else "")
    return f"smoothing weight {sm['weight_per_observation']:g} per observation ({sm['rule']}){seen}"


@click.command("response")
@click.argument("images", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (response.csv, radiance.tif, exposure.csv, report.json, plots).")
@click.option("--exposure-times", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="CSV image,exposure (file name as given); without it the exposures are estimated too.")
@click.option("--min-count", type=int, default=20, show_default=True,
              help="DN values with fewer observations are interpolated, not fitted.")
@click.option("--max-pixels", type=int, default=200_000, show_default=True,
              help="Pixels used for the fit (a fixed random subset); the radiance uses all.")
@click.option("--no-plots", is_flag=True, help="Skip the PNG plots.")
@reports_errors
def command(images, out_dir, exposure_times, min_count, max_pixels, no_plots):
    """Recover the inverse camera response g, the radiance and the exposure times of co-registered IMAGES."""
    from ..response.aligned import recover_response

    rep = recover_response(images, out_dir, exposure_times, min_count=min_count, max_pixels=max_pixels,
                           plots=not no_plots)
    ident = rep["identifiability"]
    click.echo(f"lunaralbedo response: {len(images)} images, DN {rep['dn_range'][0]}-{rep['dn_range'][1]} "
               f"({rep['free_levels']} free levels, {rep['interpolated_levels']} interpolated), {rep['normalisation']}")
    click.echo("  " + identifiability_line(ident))
    click.echo("  " + smoothing_line(rep["smoothing"]))
    r = rep["residuals"]
    click.echo(f"  fit: chi2/dof {r['chi2_per_dof']:.3g}, log residual RMS {r['rms_log']:.3g}, {r['n_obs']} observations; "
               + ("converged" if rep["converged"] else "NOT CONVERGED") + f" ({rep['convergence']})")
    for w in rep["warnings"]:
        click.echo(f"  WARNING: {w}")
    click.echo(f"  results in {out_dir}/")
