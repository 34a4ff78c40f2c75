"""The one forward model: both scene kinds share the Sun geometry, A*T*R and the truth format.

``lunaralbedo simulate`` renders a DRG strip for ``solve`` (default) or ISIS cubes, kernels
and a DEM for ``ingest`` (``--format isis``); either way ``truth/truth.json`` has the same
keys and ``simulate.score`` compares a solve with it.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
import spiceypy

from bad_input_common import assert_clean_failure, cli
from lunaralbedo.errors import InputError
from lunaralbedo.io.positions import read_positions
from lunaralbedo.model import geometry
from lunaralbedo.simulate import SceneSpec, forward, read_truth, render_scene, score, true_exposures


@pytest.fixture(autouse=True)
def clean_pool():
    spiceypy.kclear()
    yield
    spiceypy.kclear()


@pytest.mark.parametrize("lon, lat, az, el", [(10.0, -5.0, 90.0, 55.0), (200.0, 30.0, 0.0, 20.0), (-45.0, -60.0, 225.0, 70.0)])
def test_sun_position_is_at_the_asked_azimuth_and_elevation(lon, lat, az, el):
    point = geometry.body_fixed(lon, lat, 1234.0)
    sun = forward.sun_position(point, az, el)
    east, north, up = forward.local_frame(point)
    d = (sun - point) / np.linalg.norm(sun - point)
    assert np.degrees(np.arcsin(np.dot(sun / np.linalg.norm(sun), up))) == pytest.approx(el, abs=1e-9)
    assert np.degrees(np.arcsin(d @ up)) == pytest.approx(el, abs=0.01)  # the Sun is 1 AU away: parallax < 0.01 deg
    assert (np.degrees(np.arctan2(d @ east, d @ north)) - az + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=0.01)
    assert np.linalg.norm(sun) == pytest.approx(forward.SUN_DISTANCE_KM)


def test_strip_truth_is_the_common_format_and_matches_the_scene_files(tmp_path):
    truth = render_scene(tmp_path / "s", SceneSpec(n_images=3, image_px=40, seed=4))
    assert read_truth(tmp_path / "s") == json.loads(json.dumps(truth))
    assert truth["reflectance_type"] == 2 and (truth["c1"], truth["c2"]) == (1.4, 0.5)
    sun = read_positions(tmp_path / "s/meta/sunpos.txt")
    sc = read_positions(tmp_path / "s/meta/spacecraftpos.txt")
    assert sorted(truth["images"]) == sorted(sun) == sorted(sc)
    for key, im in truth["images"].items():
        np.testing.assert_allclose(sun[key], im["sun_km"], rtol=1e-12)
        np.testing.assert_allclose(sc[key], im["spacecraft_km"], rtol=1e-12)
        assert (tmp_path / "s" / im["drg"]).is_file()
    # incidence on the sphere below the spacecraft (0.08 degrees off the image centre): the spec's 35 +- 3 degrees
    cos_i = [np.dot(np.array(im["sun_km"]) / np.linalg.norm(im["sun_km"]),
                    np.array(im["spacecraft_km"]) / np.linalg.norm(im["spacecraft_km"])) for im in truth["images"].values()]
    assert all(32.0 - 0.2 < np.degrees(np.arccos(c)) < 38.0 + 0.2 for c in cos_i)


def test_read_truth_names_the_file(tmp_path):
    with pytest.raises(InputError, match="truth.json: no truth file"):
        read_truth(tmp_path)
    (tmp_path / "truth").mkdir()
    (tmp_path / "truth/truth.json").write_text(json.dumps({"reflectance_type": 2, "albedo": "a.tif",
                                                           "images": {"K": {"exposure": 1.0}}}))
    with pytest.raises(InputError, match=r"truth.json: not a lunaralbedo truth file \(missing images.K.sun_km"):
        read_truth(tmp_path)


@pytest.mark.slow
def test_isis_scene_ingests_and_solves_to_its_truth(tmp_path):
    """`simulate --format isis` -> `ingest` -> `solve` -> `score`: the same truth format as the strip."""
    scene, work, out = tmp_path / "mission", tmp_path / "work", tmp_path / "albedo"
    res = cli("simulate", scene, "--format", "isis", "--images", "3", "--seed", "11")
    assert res.exit_code == 0, res.stderr
    truth = read_truth(scene)
    assert sorted(p.stem for p in (scene / "cubes").glob("*.cub")) == sorted(truth["images"])
    assert truth["reflectance_type"] == 2 and len(truth["images"]) == 3
    res = cli("ingest", *sorted((scene / "cubes").glob("*.cub")), "--dem", scene / "dem", "-o", work)
    assert res.exit_code == 0, res.stderr
    res = cli("solve", work / "settings.txt", "-o", out, "--quiet")
    assert res.exit_code == 0, res.stderr
    s = score(out, scene)
    print(s)
    assert s["images_compared"] == 3
    # measured: 0.27 % albedo, 2e-5 exposures; 3 frames cover 23 % of the 300 x 300 px truth grid
    assert s["albedo_rel_rmse"] < 0.01 and s["exposure_max_rel_err"] < 0.002 and s["coverage"] > 0.15
    assert set(true_exposures(truth)) == set(truth["images"])


@pytest.mark.parametrize("args, culprit", [
    (["--size", "50"], "--size: not an option of --format isis"),
    (["--noise", "2", "--res", "0.1"], "--res, --noise: not an option"),
    (["--images", "0"], "--images"),
])
def test_isis_format_refuses_what_it_cannot_do(tmp_path, args, culprit):
    out = tmp_path / "mission"
    assert_clean_failure(cli("simulate", out, "--format", "isis", *args), 2, culprit, absent=out)


def test_sample_data_truth_is_the_common_format():
    """The committed sample_data mission (tools/make_sample_data.py) reads through the same reader."""
    from pathlib import Path

    truth = read_truth(Path(__file__).resolve().parents[1] / "sample_data")
    exp = true_exposures(truth)
    assert len(exp) == 5 and all(0.7 < e < 1.3 for e in exp.values())
    assert truth["reflectance_type"] == 2 and (truth["c1"], truth["c2"]) == (1.4, 0.5)


@pytest.mark.parametrize("instrument", ["kaguya-mi", "kaguya-tc", "clementine-uvvis", "chandrayaan2-tmc2"])
def test_instrument_option_renders_that_camera(tmp_path, instrument):
    """`simulate --instrument NAME`: cubes whose labels ingest recognises as that instrument, and a truth entry
    for exactly the DRG keys ingest will make of them (one per band for Kaguya MI) with their wavelengths."""
    from lunaralbedo.camera.instruments import instrument_of
    from lunaralbedo.ingest.keys import band_items
    from lunaralbedo.isis import read_label

    out = tmp_path / "scene"
    res = cli("simulate", out, "--instrument", instrument, "--images", "1", "--seed", "5")
    assert res.exit_code == 0, res.stderr
    cubes = sorted((out / "cubes").glob("*.cub"))
    assert len(cubes) == 1 and instrument_of(read_label(cubes[0])) == instrument.replace("-", "_")
    truth = read_truth(out)
    items = band_items(cubes)
    assert sorted(key for _p, key, _b, _c in items) == sorted(truth["images"])
    assert all(truth["images"][key]["band_center_nm"] == pytest.approx(c) for _p, key, _b, c in items)
    assert truth["seed"] == 5 and truth["instrument"] == instrument.replace("-", "_")


@pytest.mark.parametrize("args, culprit", [
    (["--instrument", "kaguya-tc", "--size", "50"], "--size: not an option of --instrument"),
    (["--instrument", "kaguya-mi", "--format", "drg"], "--format drg"),
    (["--instrument", "chandrayaan2-tmc2", "--images", "0"], "--images"),
])
def test_instrument_option_refuses_what_it_cannot_do(tmp_path, args, culprit):
    out = tmp_path / "mission"
    assert_clean_failure(cli("simulate", out, *args), 2, culprit, absent=out)


def test_unknown_instrument_is_a_usage_error_naming_the_option(tmp_path):
    res = cli("simulate", tmp_path / "scene", "--instrument", "tmc2")
    assert res.exit_code == 2 and "'--instrument'" in res.stderr and "chandrayaan2-tmc2" in res.stderr
    assert "Traceback" not in res.stderr and not (tmp_path / "scene").exists()
