#!/usr/bin/env python3
"""Camera response (seed 002): accuracy vs OpenCV on synthetic stacks, and time per million observations.

    python benchmarks/response_bench.py [--figures docs]

Prints, per synthetic stack (film S curve, 8 bit, photon noise): log-RMS error of g over
DN 10-245 after one global scale for ours (known exposure times), OpenCV calibrateDebevec
and calibrateRobertson; then the fit time for ~0.1, 0.5 and 1 million observations.
With --figures, writes the comparison plot of the first stack to FOLDER/response_vs_opencv.png.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lunaralbedo.model.response import observations_from_stack  # noqa: E402
from lunaralbedo.model.response_fit import fit_response  # noqa: E402
from lunaralbedo.response.compare import curve_error, opencv_response  # noqa: E402
from lunaralbedo.response.synthetic import render_stack  # noqa: E402

STACKS = {
    "8 exp. x32, 3000 ph": dict(),
    "5 exp., 300 ph (noisy)": dict(n_images=5, photons=300),
    "4 exp. x10, 200x200": dict(n_images=4, exposure_ratio=10, shape=(200, 200)),
    "8 exp., 30000 ph (quantisation)": dict(photons=30000, seed=3),
}


def accuracy(figures: Path | None) -> None:
    print(f"{'stack':34s} {'ours':>8s} {'Debevec':>8s} {'Robertson':>9s}")
    for i, (name, kw) in enumerate(STACKS.items()):
        s = render_stack(**kw)
        fit = fit_response(observations_from_stack(s["dn"], np.ones(s["dn"].shape, bool)), s["exposure"])
        cv = {m: opencv_response(s["dn"], s["exposure"], m) for m in ("debevec", "robertson")}
        errs = [curve_error(fit.lut(), s["curve"])[0]] + [curve_error(cv[m], s["curve"])[0] for m in cv]
        print(f"{name:34s} " + " ".join(f"{100 * e:7.2f}%" for e in errs), flush=True)
        if figures and i == 0:
            plot(figures / "response_vs_opencv.png", s, fit, cv)


def plot(path: Path, s, fit, cv) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.arange(10, 246)
    truth = s["curve"].inverse(z)
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for label, lut in (("ours (ML, eq. 8)", fit.lut()), ("OpenCV Debevec", cv["debevec"]), ("OpenCV Robertson", cv["robertson"])):
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
        t0 = time.perf_counter()
        fit = fit_response(obs, s["exposure"])
        dt = time.perf_counter() - t0
        n = fit.residuals["n_obs"]
        rows.append({"observations": n, "seconds": dt, "seconds_per_million": dt / n * 1e6,
                     "newton_iterations": len(fit.loglik) - fit.n_juggle})
        print(f"{n:9d} observations: {dt:6.2f} s, {dt / n * 1e6:6.2f} s per million (known t), "
              f"{rows[-1]['newton_iterations']} Newton iterations", flush=True)
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--figures", type=Path, default=None)
    a = ap.parse_args()
    accuracy(a.figures)
    timing()
