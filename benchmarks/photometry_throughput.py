#!/usr/bin/env python3
"""`make bench-photometry`: backplane and photometric-correction throughput (pixels/s) on real cameras.

Geometry: the real LRO NAC crop (line scanner, sphere) and the real LRO WAC-VIS cube
(push-frame, reduced GLD100 DEM with ISIS's image-neighbour local normals), each
evaluated on a dense grid of fractional pixel coordinates with the pixel count of a
realistic image (NAC: 2048 x 2048 = 4.2 Mpx; WAC: 704 x 2856 = 2.0 Mpx, one VIS band
of 204 framelets).  Photometry: LROC empirical and HapkeLROC-with-parameter-map
corrections on 4.2 Mpx of angles.  Needs ../shared/realdata.  Writes
docs/photometry_throughput.png and prints a table (figures in docs/photometry.md).
"""
from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
ISIS = Path(os.environ.get("LUNARALBEDO_SHARED", REPO.parent / "shared")) / "realdata/isis"

from lunaralbedo.backplanes.compute import pixel_geometry  # noqa: E402
from lunaralbedo.backplanes.shape import resolve_shape  # noqa: E402
from lunaralbedo.camera.build import build_camera  # noqa: E402
from lunaralbedo.ingest.observation import open_observation  # noqa: E402
from lunaralbedo.phocorr.hapkemap import hapke_map_correction, read_parameter_map  # noqa: E402
from lunaralbedo.phocorr.params import load_hapke_map, load_lroc_empirical  # noqa: E402


def geometry_rate(cube: str, grid: tuple[int, int], ellipsoid: bool, block: int = 262144):
    """Pixels/s of :func:`pixel_geometry` over a ``grid`` (samples, lines) of fractional pixel coordinates."""
    path = ISIS / cube
    with open_observation(path, path.stem[:11]) as obs:
        cam = build_camera(obs.label, obs.ephemeris, obs.code, band=1)
        shape = resolve_shape(obs.label, ellipsoid=ellipsoid)
        s, l = np.meshgrid(np.linspace(1, cam.samples, grid[0]), np.linspace(1, cam.lines, grid[1]))
        s, l = s.ravel(), l.ravel()
        t0 = time.perf_counter()
        for k in range(0, s.size, block):
            pixel_geometry(cam, obs.ephemeris, shape, s[k:k + block], l[k:k + block])
        return s.size / (time.perf_counter() - t0), shape.name


def photometry_rates(n: int = 2048 * 2048):
    rng = np.random.default_rng(0)
    inc, em, ph = rng.uniform(20, 80, n), rng.uniform(0, 40, n), rng.uniform(20, 100, n)
    lat, lon = rng.uniform(-60, 60, n), rng.uniform(0, 360, n)
    (lroc,), ref = load_lroc_empirical(ISIS / "NAC_PHO_LROC_Empirical.0003.pvl", [600.0])
    t0 = time.perf_counter()
    lroc.correction(inc, em, ph, ref)
    r_lroc = n / (time.perf_counter() - t0)
    pmap = read_parameter_map(ISIS / "1x1_70NS_7b_wbhs_albflt_grid_geirist_tcorrect.reduced.cub")
    params = load_hapke_map(ISIS / "hapke_full_reformatted.pvl", pmap.band_names)
    t0 = time.perf_counter()
    hapke_map_correction(params, pmap, inc, em, ph, lat, lon, 415.0)
    return r_lroc, n / (time.perf_counter() - t0)


def main() -> None:
    if not ISIS.is_dir():
        sys.exit(f"needs {ISIS} (../shared/realdata beside the repository)")
    rows = []
    rate, _ = geometry_rate("M143947267L.cal.echo.crop.cub", (2048, 2048), ellipsoid=True)
    rows.append(("backplanes NAC line scanner, sphere (4.2 Mpx)", rate))
    rate, _ = geometry_rate("M1181493219CE.vis.odd.reduced.cub", (704, 2856), ellipsoid=False)
    rows.append(("backplanes WAC push-frame, DEM + local normals (2.0 Mpx)", rate))
    r_lroc, r_hapke = photometry_rates()
    rows.append(("photometry lroc-empirical (4.2 Mpx of angles)", r_lroc))
    rows.append(("photometry hapke-map, HapkeLROC (4.2 Mpx of angles)", r_hapke))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, 1 process")
    for name, rate in rows:
        print(f"{name:60s} {rate:14,.0f} px/s")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 2.6))
    ax.barh([r[0] for r in rows][::-1], [r[1] for r in rows][::-1], color="0.4")
    ax.set_xscale("log")
    ax.set_xlabel("pixels per second (one process)")
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(REPO / "docs/photometry_throughput.png", dpi=90)


if __name__ == "__main__":
    main()
