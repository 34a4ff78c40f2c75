"""``lunaralbedo solve SETTINGS``: albedo, exposures and phase coefficients."""
from __future__ import annotations

import sys
from pathlib import Path

import click

from ..engine.options import DEFAULT_TOLERANCE, METHODS
from ._common import SOLVER_KERNELS, announce_compiling, check_number, cli_runtime, parallel_options, reports_errors


#: The solver's options that PhotometryTK's pipeline (``--legacy``) has no counterpart of: it runs in one
#: process with its own updates, MAX_NUM_ITER passes and linear DN, and keeps no checkpoint.
NOT_LEGACY = ("method", "scheduler", "cluster", "queue", "cores", "memory", "walltime", "jobs", "account", "nodefile", "resume",
              "skip_missing", "max_iter", "tolerance", "response", "exposure_times")


def _check_legacy_options(workers) -> None:
    """InputError (exit 2) naming each option given with ``--legacy`` that it would silently ignore."""
    from click.core import ParameterSource

    from ..errors import InputError

    ctx = click.get_current_context()
    given = [max(p.opts, key=len) for p in ctx.command.params
             if p.name in NOT_LEGACY and ctx.get_parameter_source(p.name) is ParameterSource.COMMANDLINE]
    if workers not in (None, 1):
        given.insert(0, f"--workers {workers}")
    if given:
        raise InputError(f"--legacy runs PhotometryTK's pipeline in one process and cannot honour {', '.join(given)}: "
                         "leave it out or drop --legacy")


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
    if rep.get("registration"):
        click.echo(f"  images registered to the DEM: {result.out_dir}/image_offsets.csv")
    if rep.get("haze"):
        h = list(rep["haze"].values())
        sig = [v for v in (rep.get("haze_sigma") or {}).values() if v is not None]
        worst = f", standard error up to {max(sig):.3g} (report.json haze_sigma)" if sig else ""
        click.echo(f"  haze: min {min(h):.4g}, max {max(h):.4g} (haze.csv){worst}")
    for key in rep.get("haze_inseparable", []):
        click.echo(f"  WARNING: image {key}: its haze and exposure cannot be separated (too little contrast); "
                   "its haze.csv value is not reliable", err=True)
    if rep.get("outliers"):
        click.echo(f"  outliers: {100 * rep['outliers']['rejected_fraction']:.3f} % of the observations rejected (outliers/)")
    if rep.get("refine_dem"):
        d = rep["refine_dem"]
        how = "estimated" if d.get("input_blur_fit") else "stated"
        sig = f", median standard error {d['dem_sigma_median_m']:.3g} m" if d.get("dem_sigma_median_m") is not None else ""
        click.echo(f"  heights refined (REFINE_DEM, docs/sfs.md): {len(d['rounds'])} round(s) in {d['seconds']:.1f}s, "
                   f"input DEM's blur {d['input_blur_px']:.3g} px ({how}), change {d['dem_change_rms_m']:.3g} m RMS{sig} "
                   "(dem_change/, dem_lit/, dem_sigma/, dem_input/)")
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
@click.option("--nodefile", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help='Start --workers processes on every host of this PBS node file (inside a job: --nodefile "$PBS_NODEFILE").')
@click.option("--resume", is_flag=True, help="Continue an interrupted run in OUTDIR (same settings and inputs).")
@click.option("--skip-missing", is_flag=True, help="Leave out DRGs without a Sun/spacecraft position (listed in the report).")
@click.option("--max-iter", type=int, default=None, help="Override MAX_NUM_ITER.")
@click.option("--tolerance", type=float, default=DEFAULT_TOLERANCE, show_default=True,
              help="Stop when the cost Q changes by at most this fraction between iterations (0: run MAX_NUM_ITER).")
@click.option("--response", default=None, metavar="estimate|FILE",
              help="Camera response (Kim et al.): 'estimate' fits g with the albedo; FILE reuses a response.csv. Default: linear DN.")
@click.option("--exposure-times", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="CSV key,exposure (the solver's exposure.csv format) that fixes the exposures.")
@click.option("--quiet", is_flag=True, help="No progress bars.")
@reports_errors
def command(settings, out, method, legacy, workers, scheduler, cluster, queue, cores, memory, walltime, jobs, account,
            nodefile, resume, skip_missing, max_iter, tolerance, response, exposure_times, quiet):
    """Solve for the albedo of SETTINGS (legacy PhotometryTK settings file or TOML)."""
    from ..settings import load_settings

    check_number("--max-iter", max_iter, 0)
    check_number("--tolerance", tolerance, 0)
    for name, v in (("--cores", cores), ("--jobs", jobs)):
        check_number(name, v, 1)
    if legacy:
        _check_legacy_options(workers)
    runtime = cli_runtime(nodefile=str(nodefile) if nodefile else None)  # its variables checked before any work
    s = load_settings(settings)
    if legacy and s.register_images:
        from ..errors import SettingsError

        raise SettingsError(f"{s.source}: REGISTER_IMAGES 1 is not a PhotometryTK feature; run without --legacy")
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

    announce_compiling(SOLVER_KERNELS)
    opts = dict(queue=queue, cores=cores, memory=memory, walltime=walltime, jobs=jobs, account=account)
    result = solve(s, out=out, method=method, workers=workers, scheduler=scheduler, cluster=cluster,
                   cluster_options=opts, resume=resume, skip_missing=skip_missing, max_iter=max_iter, tolerance=tolerance,
                   progress=not quiet and sys.stderr.isatty(), response=response, exposure_times=exposure_times,
                   runtime=runtime, warn=lambda m: click.echo(f"warning: {m}", err=True))
    _print_summary(result)
