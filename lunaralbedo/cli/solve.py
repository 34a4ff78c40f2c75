"""``lunaralbedo solve SETTINGS``: albedo, exposures and phase coefficients."""
from __future__ import annotations

import sys
from pathlib import Path

import click

from ..engine.solve import DEFAULT_TOLERANCE, METHODS
from ._common import parallel_options, reports_errors


def _print_summary(result) -> None:
    rep = result.report
    t = rep["timings_s"]
    click.echo(f"lunaralbedo solve: {rep['method']} method on {rep['executor']}")
    click.echo(f"  images used {rep['images_used']}, skipped {len(rep['images_skipped'])}"
               + "".join(f"\n    - {k}: {v}" for k, v in list(rep["images_skipped"].items())[:10]))
    q = rep["cost_q"]
    click.echo(f"  iterations {rep['iterations']}{' (converged)' if rep['converged'] else ''}"
               + (f", Q {q[0]:.6g} -> {q[-1]:.6g}" if q else ""))
    fitted = " ".join(f"{k}={v:.6f}" for k, v in result.parameters.items())
    click.echo(f"  photometric model {rep['photometric_model']}{': ' + fitted if fitted else ''}")
    e = result.exposure
    click.echo(f"  exposures: min {e.min():.4g}, median {sorted(e)[len(e) // 2]:.4g}, max {e.max():.4g}")
    click.echo(f"  tiles {len(result.tiles)}: {', '.join(result.tiles[:6])}{' ...' if len(result.tiles) > 6 else ''}")
    if rep.get("response"):
        r = rep["response"]
        click.echo(f"  camera response: {r['source']}" + (f", DN {r['dn_range'][0]}-{r['dn_range'][1]}, "
                   f"chi2/dof {rep['residuals']['chi2_per_dof']:.3g}, "
                   + ("converged" if r["converged"] else "NOT CONVERGED") + f" ({r['convergence']})"
                   if rep.get("residuals") else ""))
        if r.get("identifiability"):
            from .response import identifiability_line, smoothing_line

            click.echo("    " + identifiability_line(r["identifiability"]))
            if r.get("smoothing"):
                click.echo("    " + smoothing_line(r["smoothing"]))
        for w in r.get("warnings", []):
            click.echo(f"    WARNING: {w}")
    click.echo("  time " + ", ".join(f"{k} {v:.2f}s" for k, v in t.items()))
    click.echo(f"  results in {result.out_dir}/ (albedo/, error/, exposure.csv, phase.csv, report.json, *.png)")


@click.command("solve")
@click.argument("settings", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder (default: albedo_<settings stem> in the current folder).")
@click.option("--method", type=click.Choice(METHODS), default="overlap", show_default=True,
              help="overlap: exposures initialised from image overlaps and damped phase step; seed: the manual's plain updates.")
@click.option("--legacy", is_flag=True, help="Follow PhotometryTK's conventions exactly (uint8 tiles, legacy output tree).")
@parallel_options("NUM_PROCESSES capped at the CPU count")
@click.option("--cluster", type=click.Choice(["pbs", "slurm"]), default=None, help="Start workers as batch jobs (dask-jobqueue).")
@click.option("--queue", default=None, help="Batch queue / partition (with --cluster).")
@click.option("--cores", type=int, default=None, help="Cores per batch job (with --cluster).")
@click.option("--memory", default=None, help="Memory per batch job, e.g. 16GB (with --cluster).")
@click.option("--walltime", default=None, help="Wall time per batch job, e.g. 02:00:00 (with --cluster).")
@click.option("--jobs", type=int, default=1, show_default=True, help="Number of batch jobs (with --cluster).")
@click.option("--account", default=None, help="Account / project to charge (with --cluster).")
@click.option("--resume", is_flag=True, help="Continue an interrupted run in OUTDIR (same settings and inputs).")
@click.option("--skip-missing", is_flag=True, help="Leave out DRGs without a Sun/spacecraft position (listed in the report).")
@click.option("--max-iter", type=int, default=None, help="Override MAX_NUM_ITER.")
@click.option("--tolerance", type=float, default=DEFAULT_TOLERANCE, show_default=True,
              help="Stop when the cost Q changes by at most this fraction between iterations (0: run MAX_NUM_ITER).")
@click.option("--response", default=None, metavar="estimate|FILE",
              help="Camera response (seed 002): 'estimate' fits g with the albedo; FILE reuses a response.csv. Default: linear DN.")
@click.option("--exposure-times", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="CSV key,exposure (the solver's exposure.csv format) that fixes the exposures.")
@click.option("--quiet", is_flag=True, help="No progress bars.")
@reports_errors
def command(settings, out, method, legacy, workers, scheduler, cluster, queue, cores, memory, walltime, jobs, account,
            resume, skip_missing, max_iter, tolerance, response, exposure_times, quiet):
    """Solve for the albedo of SETTINGS (legacy PhotometryTK settings file or TOML)."""
    from ..settings import load_settings

    s = load_settings(settings)
    if legacy:
        from ..engine.solve import default_out_dir
        from ..legacy import solve_legacy

        summary = solve_legacy(s, Path(out).resolve() if out else default_out_dir(s), progress=not quiet and sys.stderr.isatty())
        c = summary["phase_coefficients"][-1]
        click.echo(f"lunaralbedo solve --legacy (PhotometryTK conventions)\n"
                   f"  images used {len(summary['images'])}, skipped {len(summary['images_skipped'])}\n"
                   f"  phase coefficients c1={c[0]:.6f} c2={c[1]:.6f}\n"
                   f"  tiles written: {', '.join(summary['tiles_written'])}\n"
                   f"  time {summary['timings_s']['total']:.2f}s\n"
                   f"  results in {summary['out_dir']}/ (legacy tree: albedo/, exposure/, phase/, ...)")
        return
    from ..engine.solve import solve

    opts = dict(queue=queue, cores=cores, memory=memory, walltime=walltime, jobs=jobs, account=account)
    result = solve(s, out=out, method=method, workers=workers, scheduler=scheduler, cluster=cluster,
                   cluster_options=opts, resume=resume, skip_missing=skip_missing, max_iter=max_iter, tolerance=tolerance,
                   progress=not quiet and sys.stderr.isatty(), response=response, exposure_times=exposure_times)
    _print_summary(result)
