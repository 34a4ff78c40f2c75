#!/usr/bin/env python3
"""Camera response (Kim et al.): accuracy vs OpenCV on synthetic stacks, and time per million observations.

    python benchmarks/response_bench.py [--figures docs] [--apollo ../shared/photk_tests]

Prints, per synthetic stack (film S curve, 8 bit, photon noise): log-RMS error of g over
DN 10-245 after one global scale for ours (known exposure times), OpenCV calibrateDebevec
and calibrateRobertson; then the fit time for ~0.1, 0.5 and 1 million observations.
With --figures, writes the comparison plot of the first stack to FOLDER/response_vs_opencv.png.
With --apollo PHOTK_TESTS (and --figures), the real Apollo 15/16 DRGs of settings 1: the response
pass and fit (CPU time, convergence, residuals), then ``solve`` with that response.csv and with a
linear response, and the figures response_apollo15_{curve,residuals,loglik,albedo}.png.
With --apollo PHOTK_TESTS --halves NAME=response.csv ...: the albedo solved on the even and on the odd DRGs
with each curve (and linear), and how well the two independent halves agree.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # response_compare: the OpenCV reference

from lunaralbedo.response.fit import fit_response  # noqa: E402
from lunaralbedo.response.model import observations_from_stack  # noqa: E402
from lunaralbedo.response.smoothing import fit_regularised  # noqa: E402
from lunaralbedo.response.synthetic import FilmCurve, render_stack  # noqa: E402
from response_compare import curve_error, opencv_response  # noqa: E402

STACKS = {
    "8 exp. x32, 3000 ph": dict(),
    "5 exp., 300 ph (noisy)": dict(n_images=5, photons=300),
    "4 exp. x10, 200x200": dict(n_images=4, exposure_ratio=10, shape=(200, 200)),
    "8 exp., 30000 ph (quantisation)": dict(photons=30000, seed=3),
    # nearly geometric exposure ratios (1.67-1.75): the data barely see waves of that period
    "6 exp. 40-600 ms, seed 7": dict(exposures=(40, 70, 120, 200, 350, 600), seed=7),
    "6 exp. 40-600 ms, contrast 2.0": dict(exposures=(40, 70, 120, 200, 350, 600), curve=FilmCurve(k=2.0), seed=5),
    "6 exp. 40-600 ms, contrast 2.5, radiance x200": dict(exposures=(40, 70, 120, 200, 350, 600),
                                                          curve=FilmCurve(k=2.5), radiance_ratio=200, seed=5),
    # added after the quantisation weights were built, to check them on curves they were not developed on
    "contrast 3.0, 30-520 ms, radiance x100": dict(exposures=(30, 55, 95, 170, 300, 520), curve=FilmCurve(k=3.0),
                                                   radiance_ratio=100, seed=21),
    "contrast 1.0, 7 exp. x64": dict(n_images=7, exposure_ratio=64, curve=FilmCurve(k=1.0), seed=22),
    "contrast 2.0, 1000 ph, ratio 2 (10-160 ms)": dict(exposures=(10, 20, 40, 80, 160), curve=FilmCurve(k=2.0),
                                                      photons=1000, seed=23),
    "fog 8 %, contrast 1.8, 6 exp. x20": dict(n_images=6, exposure_ratio=20, curve=FilmCurve(a=0.08, b=0.9, k=1.8),
                                             seed=24),
}


def accuracy(figures: Path | None) -> None:
    print(f"{'stack':46s} {'unpenalised':>11s} {'ours':>8s} {'Debevec':>8s} {'Robertson':>9s}  weight/obs  fit CPU s")
    for i, (name, kw) in enumerate(STACKS.items()):
        s = render_stack(**kw)
        obs = observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool))
        plain = fit_response(obs, s["exposure"])
        c0 = time.process_time()
        fit = fit_regularised(obs, s["exposure"])
        cpu = time.process_time() - c0
        cv = {m: opencv_response(s["dn"], s["exposure"], m) for m in ("debevec", "robertson")}
        errs = [curve_error(plain.lut(), s["curve"])[0], curve_error(fit.lut(), s["curve"])[0]]
        errs += [curve_error(cv[m], s["curve"])[0] for m in cv]
        print(f"{name:46s} " + " ".join(f"{100 * e:7.2f}%" for e in errs)
              + f"  {fit.smoothing['weight_per_observation']:10g}  {cpu:6.1f}", flush=True)
        if figures and i == 0:
            plot(figures / "response_vs_opencv.png", s, fit, cv)
            from lunaralbedo.response.io import plot_loglik

            plot_loglik(figures / "response_loglik.png", fit.loglik, fit.n_juggle)


def plot(path: Path, s, fit, cv) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.arange(10, 246)
    truth = s["curve"].inverse(z)
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for label, lut in (("ours (penalised ML, eq. 8)", fit.lut()), ("OpenCV Debevec", cv["debevec"]), ("OpenCV Robertson", cv["robertson"])):
        est = np.asarray(lut, float)[z]
        d = np.log(est) - np.log(truth)
        ax.plot(z, 100 * (d - np.nanmean(d)), label=label, lw=1)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("DN")
    ax.set_ylabel("ln g - ln g_true (%), one scale removed")
    ax.set_title("Recovered inverse response vs truth (8 exposures over 32x)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def timing(shapes=((120, 120), (250, 250), (350, 350))) -> list[dict]:
    """Fit time (known exposure times) of 8-image stacks of the given shapes; also called by run_all.py."""
    rows = []
    for shape in shapes:
        s = render_stack(n_images=8, shape=shape)
        obs = observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool))
        t0 = time.process_time()  # CPU time: the machine is shared
        fit = fit_response(obs, s["exposure"])
        dt = time.process_time() - t0
        n = fit.residuals["n_obs"]
        rows.append({"observations": n, "cpu_seconds": dt, "cpu_seconds_per_million": dt / n * 1e6,
                     "newton_iterations": fit.newton})
        print(f"{n:9d} observations: {dt:6.2f} s CPU, {dt / n * 1e6:6.2f} s per million (known t), "
              f"{rows[-1]['newton_iterations']} Newton iterations", flush=True)
    return rows


def apollo(photk: Path, figures: Path | None, work: Path = Path("/tmp/response_apollo")) -> dict:
    """Response of the settings-1 DRGs: fit figures, then the albedo solved with and without it."""
    import shutil

    from lunaralbedo.engine.response_pass import response_observations
    from lunaralbedo.engine.scene import build_scene
    from lunaralbedo.engine.solve import solve
    from lunaralbedo.parallel import make_executor
    from lunaralbedo.response.aligned import longest_flat_run, write_outputs
    from lunaralbedo.settings import load_settings

    settings = photk / "photometry_settings_1.txt"
    shutil.rmtree(work, ignore_errors=True)
    (work / "fit").mkdir(parents=True)
    ex = make_executor(1, None, None, None, False)
    try:
        scene = build_scene(load_settings(settings), False, map_fn=lambda f, xs: ex.map(f, xs, "masks"))
        obs = response_observations(scene, ex)
    finally:
        ex.close()
    before = fit_response(obs, None)  # Kim et al. unpenalised: the curve of the earlier releases
    c0 = time.process_time()
    fit = fit_regularised(obs, None)
    cpu = time.process_time() - c0
    write_outputs(work / "fit", fit, scene.keys, plots=True, exposure_given=False)
    res = fit.residuals
    row = {"observations": res["n_obs"], "fit_cpu_s": cpu, "converged": fit.converged, "message": fit.message,
           "newton_iterations": fit.newton, "passes": fit.passes,
           "pooled_steps": int(np.sum(np.diff(fit.g) == 0)), "levels": len(fit.g), "chi2_per_dof": res["chi2_per_dof"],
           "rms_log": res["rms_log"], "gauge": fit.gamma.get("gauge"), "geometry": fit.gamma.get("geometry"),
           "smoothing": fit.smoothing, "longest_flat_run_dn": longest_flat_run(fit.g),
           "before": {"pooled_steps": int(np.sum(np.diff(before.g) == 0)), "longest_flat_run_dn": longest_flat_run(before.g),
                      "chi2_per_dof": before.residuals["chi2_per_dof"], "rms_log": before.residuals["rms_log"]}}
    print(row, flush=True)
    out = {}
    for name, kw in (("linear", {}), ("response", {"response": work / "fit" / "response.csv"})):
        solve(settings, out=work / name, workers=1, plots=False, **kw)
        out[name] = _mosaic(work / name / "albedo")
    for name, a in out.items():
        v = a[np.isfinite(a)]
        print(f"albedo {name}: {v.size} px, relative spread (std/mean) {np.std(v) / np.mean(v):.4f}", flush=True)
    if figures:
        shutil.copyfile(work / "fit" / "response.png", figures / "response_apollo15_curve.png")
        shutil.copyfile(work / "fit" / "residuals.png", figures / "response_apollo15_residuals.png")
        _plot_albedo(figures / "response_apollo15_albedo.png", out)
        shutil.copyfile(work / "fit" / "loglik.png", figures / "response_apollo15_loglik.png")
        _plot_before_after(figures / "response_apollo15_before_after.png", before, fit)
    return row


def apollo_halves(photk: Path, curves: dict, work: Path = Path("/tmp/response_apollo_halves")) -> dict:
    """Albedo consistency without a truth: settings 1 solved on the even and on the odd DRGs (no image in both),
    each with every curve of ``curves`` (name -> response.csv, None = linear), compared where both cover."""
    import os
    import shutil

    from lunaralbedo.engine.solve import solve

    tifs = sorted((photk / "DIM_input_1280mpp_masked").glob("*.tif"))
    maps, rows = {}, {}
    for half in (0, 1):
        d = work / f"half{half}"
        shutil.rmtree(d, ignore_errors=True)
        (d / "DIM_input_1280mpp_masked").mkdir(parents=True)
        for k, t in enumerate(tifs):
            if k % 2 == half:
                os.symlink(t, d / "DIM_input_1280mpp_masked" / t.name)
        for x in ("DEM_tiles_sub64", "meta"):
            os.symlink(photk / x, d / x)
        shutil.copyfile(photk / "photometry_settings_1.txt", d / "settings.txt")
        for name, resp in curves.items():
            solve(d / "settings.txt", out=d / name, workers=1, plots=False, **({} if resp is None else {"response": resp}))
            maps[name, half] = _mosaic(d / name / "albedo")
    for name in curves:
        a, b = maps[name, 0], maps[name, 1]
        ok = np.isfinite(a) & np.isfinite(b) & (a > 0) & (b > 0)
        la, lb = np.log(a[ok]), np.log(b[ok])
        dif = la - lb
        rms = float(np.sqrt(np.mean((dif - dif.mean()) ** 2)))
        spread = float(np.sqrt(0.5 * (np.var(la) + np.var(lb))))
        rows[name] = {"pixels": int(ok.sum()), "std_log_albedo": spread, "rms_log_ratio": rms,
                      "rms_over_spread": rms / spread, "correlation": float(np.corrcoef(la, lb)[0, 1])}
        print(name, rows[name], flush=True)
    return rows


def _plot_before_after(path: Path, before, after) -> None:
    """The Apollo curve of the unpenalised fit and of the cross-validated penalised one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    for label, f, style in (("before: Kim et al. unpenalised", before, "--"),
                            (f"after: penalised, weight {after.smoothing['weight_per_observation']:g}/obs", after, "-")):
        ax.semilogy(f.levels.dn, f.g, style, lw=1.2, label=f"{label} ({int(np.sum(np.diff(f.g) == 0))} flat steps)")
    ax.set_xlabel("DN")
    ax.set_ylabel("g(z), g(128) = 1")
    ax.set_title("Apollo 15/16 DRGs (settings 1): inverse response")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def ambiguity(path: Path) -> None:
    """The figure of docs/response.md: which waves the exposures leave unseen, and the fits they allow."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lunaralbedo.response.smoothing import PERIODS, exposure_diagnosis

    near = (40, 70, 120, 200, 350, 600)
    s = render_stack(exposures=near, curve=FilmCurve(k=2.0), seed=5)
    obs = observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool))
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.8))
    for label, t in (("40-600 ms (ratios 1.67-1.75)", np.array(near, float)), ("40, 90, 130, 300, 420, 600 ms", np.array([40, 90, 130, 300, 420, 600.0]))):
        vis = [exposure_diagnosis(obs, t, np.array([p]))["min_visibility"] for p in PERIODS[::4]]
        a1.plot(np.exp(PERIODS[::4]), vis, lw=1, label=label)
    a1.set_xscale("log")
    a1.set_xlabel("period of a wave in g, as an exposure ratio")
    a1.set_ylabel("visibility (0: the data cannot see it)")
    a1.set_title("What the exposure ratios determine")
    a1.legend(fontsize=8)
    a1.grid(alpha=0.3)
    z = np.arange(10, 246)
    truth = np.log(s["curve"].inverse(z))
    fits = {"Kim et al. unpenalised": fit_response(obs, s["exposure"]), "penalised, cross-validated": fit_regularised(obs, s["exposure"])}
    for label, f in fits.items():
        d = np.log(f.lut()[z].astype(float)) - truth
        a2.plot(z, 100 * (d - d.mean()), lw=1, label=label)
    d = np.log(opencv_response(s["dn"], s["exposure"], "debevec")[z]) - truth
    a2.plot(z, 100 * (d - d.mean()), lw=1, label="OpenCV Debevec")
    a2.axhline(0, color="k", lw=0.5)
    a2.set_xlabel("DN")
    a2.set_ylabel("ln g - ln g_true (%)")
    a2.set_title("Film curve of contrast 2, exposures 40-600 ms")
    a2.legend(fontsize=8)
    a2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _mosaic(folder: Path) -> np.ndarray:
    import rasterio
    from rasterio.merge import merge

    sources = [rasterio.open(p) for p in sorted(folder.glob("*.tif"))]
    try:
        arr, _ = merge(sources, nodata=np.nan)
    finally:
        for s in sources:
            s.close()
    return arr[0].astype(np.float64)


def _plot_albedo(path: Path, mosaics: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h, w = next(iter(mosaics.values())).shape
    fig, axes = plt.subplots(1, len(mosaics), figsize=(3.4 * len(mosaics), 3.4 * h / w + 0.4))
    for ax, (name, a) in zip(axes, mosaics.items()):
        v = a / np.nanmean(a)
        lo, hi = np.nanpercentile(v, [1, 99])
        ax.imshow(v, cmap="gray", vmin=lo, vmax=hi)
        ax.set_title(f"{name} (std/mean {np.nanstd(v):.3f})", fontsize=9)
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--figures", type=Path, default=None)
    ap.add_argument("--apollo", type=Path, default=None, help="../shared/photk_tests: the real-data figures only")
    ap.add_argument("--halves", nargs="*", metavar="NAME=RESPONSE.csv",
                    help="with --apollo: only the even/odd-DRG albedo consistency, linear and with these curves")
    a = ap.parse_args()
    if a.apollo and a.halves is not None:
        apollo_halves(a.apollo.resolve(), {"linear": None, **{n: Path(f).resolve() for n, f in (h.split("=", 1) for h in a.halves)}})
    elif a.apollo:
        apollo(a.apollo.resolve(), a.figures)
    else:
        accuracy(a.figures)
        if a.figures:
            ambiguity(a.figures / "response_ambiguity.png")
        timing()
