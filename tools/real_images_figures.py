"""The figures of docs/solver.md, section "Real images": forward-model strips with outliers and haze.

    .venv/bin/python tools/real_images_figures.py [WORKDIR]   # writes docs/solver-outliers.png, docs/solver-haze.png

Each strip is the default ``SceneSpec`` (6 images, Lunar-Lambert, 1 DN noise) with one defect,
solved with and without the feature; the scores are printed (the figures of the docs' tables).
"""
from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import rasterio  # noqa: E402
from rasterio.merge import merge  # noqa: E402

from lunaralbedo.engine.solve import solve  # noqa: E402
from lunaralbedo.simulate import SceneSpec, read_truth, render_scene, score  # noqa: E402

DOCS = Path(__file__).resolve().parent.parent / "docs"


def _settings(scene: Path, name: str, **keys) -> Path:
    lines = [ln for ln in (scene / "settings.txt").read_text().splitlines() if ln.split()[:1] not in ([k] for k in keys)]
    path = scene / f"{name}.txt"
    path.write_text("\n".join(lines + [f"{k} {v}" for k, v in keys.items()]) + "\n")
    return path


def _mosaic(folder: Path, bounds) -> np.ndarray:
    files = sorted(str(p) for p in folder.glob("*.tif"))
    with rasterio.open(files[0]) as ds:
        res = ds.res
    mos, _ = merge(files, bounds=bounds, res=res, nodata=np.nan, dtype="float32")
    return mos[0]


def _run(scene: Path, out: Path, name: str, **keys) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    solve(_settings(scene, name, **keys), out=out, workers=1, plots=False)
    sc = score(out, scene)
    print(name, {k: round(v, 5) for k, v in sc.items()})
    return sc


def outliers_figure(work: Path) -> None:
    scene = work / "outliers"
    render_scene(scene, SceneSpec(outlier_fraction=0.01, seed=17))
    _run(scene, work / "off", "off", REJECT_OUTLIERS=0, ROBUST_LOSS="none")
    _run(scene, work / "on", "on")
    truth = read_truth(scene)
    with rasterio.open(scene / truth["albedo"]) as t:
        ta, bounds = t.read(1), t.bounds
    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), constrained_layout=True)
    for ax, (title, img, kw) in zip(axes, [
        ("albedo without rejection / truth - 1", _mosaic(work / "off" / "albedo", bounds), None),
        ("albedo with the default rejection / truth - 1", _mosaic(work / "on" / "albedo", bounds), None),
        ("outliers/: fraction of each pixel's observations rejected", _mosaic(work / "on" / "outliers", bounds), "frac"),
    ]):
        if kw is None:
            ok = np.isfinite(img)
            s = np.sum(img[ok] * ta[ok]) / np.sum(img[ok] ** 2)
            im = ax.imshow(s * img / ta - 1, cmap="RdBu_r", vmin=-0.3, vmax=0.3)
        else:
            im = ax.imshow(img, cmap="magma", vmin=0, vmax=1)
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.suptitle("6-image strip, 1 % of pixels in hot spots (x1.6-3) and dropout rows (x0.3)", fontsize=10)
    fig.savefig(DOCS / "solver-outliers.png", dpi=80)
    plt.close(fig)


def haze_figure(work: Path) -> None:
    import csv

    from lunaralbedo.io.outputs import read_exposure_csv

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    for seed, marker in ((7, "o"), (8, "s"), (9, "^")):
        scene = work / f"haze{seed}"
        truth = render_scene(scene, SceneSpec(haze_dn=(5.0, 15.0), seed=seed))
        _run(scene, work / f"haze{seed}_off", f"haze{seed}_off")
        _run(scene, work / f"haze{seed}_on", f"haze{seed}_on", FLOAT_HAZE=1)
        keys = list(truth["images"])
        with open(work / f"haze{seed}_on" / "haze.csv", newline="") as f:
            got = {r["key"]: float(r["haze"]) for r in csv.DictReader(f)}
        true_h = [truth["images"][k]["haze"] for k in keys]
        axes[0].plot(true_h, [got[k] for k in keys], marker, label=f"seed {seed}")
        t_true = np.array([truth["images"][k]["exposure"] for k in keys])
        for out, style in ((f"haze{seed}_off", ":"), (f"haze{seed}_on", "-")):
            est = read_exposure_csv(work / out / "exposure.csv")
            ratio = np.array([est[k] for k in keys]) / t_true
            axes[1].plot(np.arange(len(keys)), 100 * (ratio / np.exp(np.mean(np.log(ratio))) - 1), style + marker,
                         label=f"seed {seed}, FLOAT_HAZE {0 if 'off' in out else 1}")
    axes[0].plot([5, 15], [5, 15], color="grey", lw=0.8)
    axes[0].set_xlabel("true haze, DN")
    axes[0].set_ylabel("haze.csv, DN")
    axes[0].set_title("haze per image (FLOAT_HAZE 1)")
    axes[0].legend(fontsize=7)
    axes[1].axhline(0, color="grey", lw=0.5)
    axes[1].set_xlabel("image")
    axes[1].set_ylabel("exposure error, %")
    axes[1].set_title("exposures without (dotted) and with the haze solved")
    axes[1].legend(fontsize=6, ncol=2)
    fig.suptitle("6-image strips with 5-15 DN of haze per image", fontsize=10)
    fig.savefig(DOCS / "solver-haze.png", dpi=110)
    plt.close(fig)


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    work = Path(args[0]) if args else Path(tempfile.mkdtemp(prefix="real_images_"))
    work.mkdir(parents=True, exist_ok=True)
    if "--haze-only" not in sys.argv:
        outliers_figure(work)
    haze_figure(work)


if __name__ == "__main__":
    main()
