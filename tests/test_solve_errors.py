"""Bad input: a clear message naming the file, exit status 2, and no OUTDIR left behind."""
from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.simulate import SceneSpec, render_scene, score


@pytest.fixture(scope="module")
def base_scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("base")
    render_scene(d, SceneSpec(n_images=3, image_px=40, max_num_iter=2, seed=3))
    return d


@pytest.fixture
def scene(base_scene, tmp_path):
    d = tmp_path / "scene"
    shutil.copytree(base_scene, d)
    return d


def run(scene, *extra, out=None):
    out = out or scene.parent / "out"
    res = CliRunner().invoke(main, ["solve", str(scene / "settings.txt"), "-o", str(out), "--workers", "1", "--quiet", *extra])
    return res, out


def assert_fails(res, out, *words):
    assert res.exit_code == 2, res.output
    msg = res.output
    assert msg.startswith("error: ")
    for w in words:
        assert str(w) in msg, msg
    assert not out.exists(), "a failed run must not leave a partial OUTDIR"


def test_good_scene_runs(scene):
    """The control of every case below: the scene they break solves, and to its truth (measured: albedo 1.2 %,
    exposures 0.05 %, 93 % of the truth's pixels after the scene's 2 passes)."""
    res, out = run(scene)
    assert res.exit_code == 0, res.output
    sc = score(out, scene)
    assert sc["images_compared"] == 3 and sc["coverage"] > 0.9, sc
    assert sc["albedo_rel_rmse"] < 0.025 and sc["exposure_max_rel_err"] < 0.01, sc


def test_duplicate_lookup_key_names_both_files(scene):
    src = scene / "DRG" / "SIM-IMG-000_drg.tif"
    dup = scene / "DRG" / "SIM-IMG-000_copy.tif"
    shutil.copy(src, dup)
    res, out = run(scene)
    assert_fails(res, out, "SIM-IMG-000", src.name, dup.name)


def test_missing_position_names_key_and_file_and_skip_missing_reports(scene):
    sun = scene / "meta" / "sunpos.txt"
    sun.write_text("\n".join(l for l in sun.read_text().splitlines() if not l.startswith("SIM-IMG-001")) + "\n")
    res, out = run(scene)
    assert_fails(res, out, "SIM-IMG-001", str(sun), "--skip-missing")
    res, out = run(scene, "--skip-missing")
    assert res.exit_code == 0, res.output
    rep = json.loads((out / "report.json").read_text())
    assert rep["images_skipped"] == {"SIM-IMG-001": "no position in sunpos.txt"}
    assert "SIM-IMG-001" in res.output


def test_malformed_position_line(scene):
    sc = scene / "meta" / "spacecraftpos.txt"
    sc.write_text(sc.read_text() + "SIM-IMG-009 1.0 two 3.0\n")
    res, out = run(scene)
    assert_fails(res, out, str(sc), ":4", "not numbers")


def test_corrupt_drg_names_the_file(scene):
    bad = scene / "DRG" / "SIM-IMG-002_drg.tif"
    bad.write_bytes(b"this is not a GeoTIFF")
    res, out = run(scene)
    assert_fails(res, out, bad, "cannot open raster")


def test_missing_dem_folder(scene):
    shutil.rmtree(scene / "DEM")
    res, out = run(scene)
    assert_fails(res, out, scene / "DEM", "DEM folder not found")


def test_no_image_over_the_box(scene):
    s = scene / "settings.txt"
    s.write_text(s.read_text().replace("SIMULATION_BOX", "SIMULATION_BOX            100:101:50:51\n# was"))
    res, out = run(scene)
    assert_fails(res, out, "no DRG overlaps")


def test_output_inside_an_input_folder_is_refused(scene):
    res, out = run(scene, out=scene / "DRG" / "results")
    assert_fails(res, out, "must not be inside the input folder")


def test_unrelated_nonempty_output_folder_is_left_alone(scene):
    out = scene.parent / "precious"
    out.mkdir()
    (out / "thesis.tex").write_text("keep me")
    res, _ = run(scene, out=out)
    assert res.exit_code == 2 and "not a lunaralbedo output" in res.output
    assert (out / "thesis.tex").read_text() == "keep me"


def test_bad_settings_value_exits_2(scene):
    s = scene / "settings.txt"
    s.write_text(s.read_text().replace("SHADOW_TYPE               1", "SHADOW_TYPE               7"))
    res, out = run(scene)
    assert_fails(res, out, "SHADOW_TYPE", "one of 0, 1, 2, 3", s)


def test_no_writes_into_input_folders(scene):
    before = sorted(p.relative_to(scene) for p in scene.rglob("*"))
    res, _ = run(scene)
    assert res.exit_code == 0
    assert sorted(p.relative_to(scene) for p in scene.rglob("*")) == before


def test_bad_input_does_not_destroy_a_previous_result(scene):
    res, out = run(scene)
    assert res.exit_code == 0
    before = (out / "exposure.csv").read_text()
    (scene / "DRG" / "SIM-IMG-002_drg.tif").write_bytes(b"broken")
    res, _ = run(scene)
    assert res.exit_code == 2 and "cannot open raster" in res.output
    assert (out / "exposure.csv").read_text() == before and (out / "albedo").is_dir()


def test_outputs_are_readable_by_others_under_the_usual_umask(scene):
    import os
    import stat

    old = os.umask(0o022)
    try:
        res, out = run(scene)
    finally:
        os.umask(old)
    assert res.exit_code == 0
    for p in [out / "exposure.csv", out / "report.json", *sorted((out / "albedo").glob("*.tif"))]:
        assert stat.S_IMODE(p.stat().st_mode) == 0o644, p
