"""The real-data measure of tools/sfs_real_data.py (topography leaking into the albedo) on a forward scene whose
true heights are known: an albedo solved on a blurred DEM carries the lost relief's shading, one solved on the
true DEM does not, and the measure must tell them apart."""
from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

from lunaralbedo.engine.solve import solve
from lunaralbedo.simulate import SceneSpec, render_scene

TOOL = Path(__file__).resolve().parents[1] / "tools" / "sfs_real_data.py"


def _tool():
    spec = importlib.util.spec_from_file_location("sfs_real_data", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _settings(scene: Path, name: str, dem_dir: str) -> Path:
    text = [ln for ln in (scene / "settings.txt").read_text().splitlines() if ln.split()[:1] != ["DEM_DIR"]]
    path = scene / f"{name}.txt"
    path.write_text("\n".join(text + [f"DEM_DIR {dem_dir}"]) + "\n")
    return path


def test_leakage_measure_sees_the_relief_a_blurred_dem_lost(tmp_path):
    scene = tmp_path / "scene"
    render_scene(scene, SceneSpec(n_images=3, overlap=0.5, image_px=64, sun_azimuths=(60.0, 120.0), fresh_craters=40.0,
                                  tile_size=2.0, seed=3, max_num_iter=4, dem_blur_px=3.0))
    (scene / "true_dem").mkdir()
    shutil.copy(scene / "truth" / "dem.tif", scene / "true_dem" / "dem.tif")
    tool = _tool()
    got = {}
    for name, dem in (("blurred", "DEM"), ("true", "true_dem")):
        settings = _settings(scene, name, dem)
        solve(settings, out=tmp_path / name, workers=1, plots=False)
        got[name] = tool.leakage(settings, tmp_path / name)
    for g in got.values():
        assert g["pairs"] >= 3 and g["pixels"] > 3 * 1000
    # the true DEM's albedo is the rendered one, independent of the relief (measured 0.025); the blurred DEM's keeps
    # the shading of the relief the blur took away (measured 0.205)
    assert got["true"]["abs_corr"] < 0.1
    assert got["blurred"]["abs_corr"] > 2 * got["true"]["abs_corr"] + 0.1
