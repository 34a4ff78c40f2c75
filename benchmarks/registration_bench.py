"""`make bench` item 14: the cost of the image-to-DEM registration (REGISTER_IMAGES 1).

A strip shaped like real work (12 images of 1000 x 1000 px at 0.002 deg = 61 m, half overlapping, fresh craters
of 10-40 px radius, each image georeferenced off by up to 2 px) is registered in a fresh process: the time of each level, the time per image per
Gauss-Newton iteration (one cost evaluation: every image resampled at its new shift, eq. 3's albedo, Q) and per
image and level set-up (the level's DEM, geometry and reflectance), the peak memory, and the offsets against the
truth.  ``--quick``: 6 images of 200 px.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from common import scene

from lunaralbedo.simulate import SceneSpec

CHILD = """
import json, sys, time
import numpy as np
from lunaralbedo.engine.registration import estimate
from lunaralbedo.engine.scene import build_scene
from lunaralbedo.settings import load_settings, replace
from lunaralbedo.simulate import read_truth
d = sys.argv[1]
t0 = time.perf_counter()
scene = build_scene(replace(load_settings(d + "/settings.txt"), register_images=1))
r = estimate(scene)
dt = time.perf_counter() - t0
truth = read_truth(d)["images"]
true = np.array([[truth[k]["offset_east_m"], truth[k]["offset_north_m"]] for k in scene.keys])
err = (r.offsets_m - true) / r.pixel_m[:, None]
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
print(json.dumps({"seconds": dt, "levels": r.levels, "factor": r.factor, "images": len(scene.keys),
                  "rms_px": float(np.sqrt(np.mean(err ** 2))), "max_px": float(np.abs(err).max()),
                  "median_se_px": float(np.median(r.se_m / r.pixel_m[:, None])),
                  "peak_mb": int(hwm.split()[1]) / 1024}))
"""


def registration_cost(root: Path, q: bool, figures: dict) -> None:
    n, px = (6, 200) if q else (12, 1000)
    spec = SceneSpec(n_images=n, image_px=px, res_deg=0.002, tile_size=1.0, misregister_px=2.0, fresh_craters=40.0,
                     dem_relief_m=300.0, seed=14)
    d = scene(root, f"registration_{px}", spec)
    res = subprocess.run([sys.executable, "-c", CHILD, str(d)], capture_output=True, text=True, check=True)
    got = json.loads(res.stdout.splitlines()[-1])
    k = got["images"]
    print(f"14. registration of {k} images of {px} x {px} px (pixels averaged {got['factor']} x {got['factor']} at the "
          f"finest level): {got['seconds']:.1f} s, peak {got['peak_mb']:.0f} MB; offsets {got['rms_px']:.3f} px RMS "
          f"(max {got['max_px']:.3f}) from the truth, median standard error {got['median_se_px']:.3f} px", flush=True)
    for lv in got["levels"]:
        lv["set_up_ms_per_image"] = 1e3 * lv["setup_s"] / k
        lv["ms_per_image_per_iteration"] = 1e3 * lv["iterate_s"] / k / max(lv["iterations"], 1)
        lv["ms_per_image_per_evaluation"] = 1e3 * lv["iterate_s"] / k / max(lv["evaluations"] + lv["iterations"], 1)
        print(f"    level {lv['pixel_factor']} px: {lv['observations']:,} observations, set-up "
              f"{lv['set_up_ms_per_image']:.0f} ms per image, {lv['iterations']} iterations ({lv['evaluations']} trial "
              f"steps), {lv['ms_per_image_per_iteration']:.0f} ms per image per iteration "
              f"({lv['ms_per_image_per_evaluation']:.0f} ms per image per resampling)", flush=True)
    figures["registration"] = got
