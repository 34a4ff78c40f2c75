#!/usr/bin/env python3
"""docs/solver-registration.png: image-to-DEM offsets found by ``REGISTER_IMAGES 1`` against the truth.

Forward-model strips (6 images of 120 px at 0.01 deg, Lunar-Lambert, 1 DN noise, fresh craters at 40 per square
degree, each DRG georeferenced off by up to 2 px), Sun from the east only or from east and west; each solved with
and without registration.  Prints the figures quoted in docs/solver.md.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from lunaralbedo.engine.offsets import read_offsets_csv  # noqa: E402
from lunaralbedo.engine.solve import solve  # noqa: E402
from lunaralbedo.settings import load_settings, replace  # noqa: E402
from lunaralbedo.simulate import SceneSpec, read_truth, render_scene, score  # noqa: E402

CASES = {"Sun from the east": (90.0,), "Sun from east and west": (90.0, 270.0)}
SEEDS = (11, 12, 13)


def main(out_png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6))
    with tempfile.TemporaryDirectory() as tmp:
        for ax, (title, az) in zip(axes, CASES.items()):
            errs, lines = [], []
            for seed in SEEDS:
                d = Path(tmp) / f"{len(az)}_{seed}"
                render_scene(d, SceneSpec(seed=seed, misregister_px=2.0, fresh_craters=40.0, sun_azimuths=az))
                s = load_settings(d / "settings.txt")
                res = {}
                for reg in (0, 1):
                    out = d / f"out{reg}"
                    solve(replace(s, register_images=reg), out=out, workers=1, plots=False)
                    res[reg] = score(out, d)["albedo_rel_rmse"]
                truth = read_truth(d)["images"]
                found = read_offsets_csv(d / "out1" / "image_offsets.csv")
                se = {ln.split(",")[0]: [float(v) for v in ln.split(",")[3:]]
                      for ln in (d / "out1" / "image_offsets.csv").read_text().splitlines()[1:]}
                spec = read_truth(d)["spec"]
                px = np.radians(spec["res_deg"]) * 1737400.0
                lat_mid = spec["lat0"] + spec["image_px"] * spec["res_deg"] / 2
                for k, im in truth.items():
                    t = np.array(im["offset_px"])
                    f = np.array(found[k]) / np.array([px * np.cos(np.radians(lat_mid)), px])  # metres per pixel east, north
                    errs.append(f - t)
                    e = np.array(se[k]) / px  # error bars: the standard errors (too small to see)
                    ax.errorbar(t[0], f[0], yerr=e[0], fmt="o", color="tab:blue", ms=4, label="east" if not lines else None)
                    ax.errorbar(t[1], f[1], yerr=e[1], fmt="s", color="tab:orange", ms=4, label="north" if not lines else None)
                    lines.append(k)
                print(f"{title}, seed {seed}: albedo rel RMSE {100 * res[0]:.2f} % unregistered, "
                      f"{100 * res[1]:.2f} % registered")
            errs = np.array(errs)
            rms = float(np.sqrt(np.mean(errs**2)))
            print(f"{title}: offsets {rms:.3f} px RMS from the truth (max {np.abs(errs).max():.3f}), "
                  f"mean error east {errs[:, 0].mean():+.3f} north {errs[:, 1].mean():+.3f} px")
            ax.plot([-2.2, 2.2], [-2.2, 2.2], "k-", lw=0.7)
            ax.set(xlim=(-2.2, 2.2), ylim=(-2.2, 2.2), aspect="equal", xlabel="true offset (px)", ylabel="offset found (px)",
                   title=f"{title}: {rms:.2f} px RMS")
            ax.legend(loc="upper left")
            ax.grid(alpha=0.3)
    fig.suptitle("REGISTER_IMAGES 1: offsets found vs truth (3 strips x 6 images, 1 px = 303 m)")
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else REPO / "docs" / "solver-registration.png")
