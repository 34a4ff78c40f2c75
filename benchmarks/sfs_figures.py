"""The figures of docs/sfs.md from the outputs of ``benchmarks/sfs_bench.py``: hillshades, height errors, albedo."""
from __future__ import annotations

import glob
from pathlib import Path

import numpy as np


def hillshade(h: np.ndarray, pixel_m: float, azimuth: float = 315.0, elevation: float = 45.0) -> np.ndarray:
    """Lambertian hillshade of heights ``h`` (metres) on pixels of ``pixel_m`` metres, light from ``azimuth``."""
    gy, gx = np.gradient(h, pixel_m)
    az, el = np.radians(azimuth), np.radians(elevation)
    n = np.stack([-gx, gy, np.ones_like(h)]) / np.sqrt(gx**2 + gy**2 + 1)
    light = np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])
    return np.clip(np.tensordot(light, n, 1), 0, 1)


def draw(root: Path, d: Path, truth_scene: Path, docs: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from common import mosaic

    like = d / "truth" / "albedo.tif"
    truth, given = mosaic([d / "truth/dem.tif"], like), mosaic([d / "DEM/dem.tif"], like)
    refined = mosaic(glob.glob(str(root / "sfs_out_refine" / "DEM" / "*.tif")), like)
    px = 0.01 * np.pi / 180 * 1737400.0
    fig, ax = plt.subplots(3, 1, figsize=(10, 7.5))
    for a, (title, h) in zip(ax, (("given DEM (truth blurred by 3 px)", given), ("refined (REFINE_DEM 1)", refined),
                                  ("truth", truth))):
        a.imshow(hillshade(np.nan_to_num(h, nan=np.nanmean(h)), px), cmap="gray", vmin=0, vmax=1)
        a.set_title(title, fontsize=9)
        a.set_axis_off()
    fig.tight_layout()
    fig.savefig(docs / "sfs_hillshade.png", dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(10, 5.5))
    lim = float(np.nanpercentile(np.abs(given - truth), 99))
    for a, (title, e) in zip(ax, (("given - truth (m)", given - truth), ("refined - truth (m)", refined - truth))):
        im = a.imshow(e, cmap="RdBu_r", vmin=-lim, vmax=lim)
        rms = float(np.sqrt(np.nanmean(e**2)))
        a.set_title(f"{title}: RMS {rms:.1f} m", fontsize=9)
        a.set_axis_off()
        for x in range(100, e.shape[1], 100):  # 1-degree tile edges
            a.axvline(x - 0.5, color="k", lw=0.4, ls=":")
        a.axhline(19.5, color="k", lw=0.4, ls=":")  # the tile edge at latitude -4
        fig.colorbar(im, ax=a, shrink=0.8)
    fig.tight_layout()
    fig.savefig(docs / "sfs_height_error.png", dpi=90)
    plt.close(fig)

    ta = mosaic([like], like)
    fig, ax = plt.subplots(2, 1, figsize=(10, 5.5))
    for a, (title, out) in zip(ax, (("albedo error, plain solve on the blurred DEM", "sfs_out_plain"),
                                    ("albedo error, REFINE_DEM 1", "sfs_out_refine"))):
        alb = mosaic(glob.glob(str(root / out / "albedo" / "*.tif")), like)
        ok = np.isfinite(alb)
        s = np.sum(alb[ok] * ta[ok]) / np.sum(alb[ok] ** 2)
        rel = (s * alb - ta) / ta
        im = a.imshow(100 * rel, cmap="RdBu_r", vmin=-8, vmax=8)
        a.set_title(f"{title}: {100 * np.sqrt(np.nanmean(rel ** 2)):.2f} % RMS", fontsize=9)
        a.set_axis_off()
        fig.colorbar(im, ax=a, shrink=0.8, label="%")
    fig.tight_layout()
    fig.savefig(docs / "sfs_albedo.png", dpi=90)
    plt.close(fig)
