"""One model binding: every registered photometric model solves through the model the scene carries.

The engine uses :attr:`Scene.model` (the registry's model bound to its settings' files) everywhere: the
default solve, the camera-response pass of ``--response estimate`` and tile tasks on other processes
(the scene is pickled without the bound model and each worker binds it again).  A Hapke strip with
``--response estimate`` used to stop with "use the model bound to the settings" because the response
pass reached the unbound model of the settings."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from lunaralbedo.engine.scene import build_scene
from lunaralbedo.engine.solve import solve
from lunaralbedo.model.photometry import REGISTRY
from lunaralbedo.settings import load_settings
from lunaralbedo.simulate import SceneSpec, render_scene, score, true_exposures

#: Gains keep each model's DN inside 8 bits (Hapke's normalised R is larger than Lambert's).
GAIN = {"hapke": 45.0}


@pytest.fixture(scope="module", params=sorted(REGISTRY, key=lambda n: REGISTRY[n].code))
def strip(request, tmp_path_factory):
    name = request.param
    d = tmp_path_factory.mktemp(name)
    truth = render_scene(d, SceneSpec(reflectance_type=REGISTRY[name].code, n_images=4, image_px=80, seed=5,
                                      gain=GAIN.get(name, 120.0), max_num_iter=8))
    (d.parent / f"{name}_times.csv").write_text("key,exposure\n" + "".join(
        f"{k},{t}\n" for k, t in true_exposures(truth).items()))
    return name, d


def test_the_scene_carries_the_bound_model_and_rebinds_it_after_pickling(strip):
    name, d = strip
    scene = build_scene(load_settings(d / "settings.txt"))
    assert scene.model.name == name and scene.model.configure is None  # bound (a model with files is configured)
    back = pickle.loads(pickle.dumps(scene))
    assert back.model.name == name and back.model.configure is None
    ci, ce, al = np.array([0.8]), np.array([0.9]), np.array([0.3])
    params = scene.settings.initial_params
    np.testing.assert_array_equal(back.model.reflectance(ci, ce, al, params), scene.model.reflectance(ci, ce, al, params))


def test_every_model_solves_by_default_and_with_an_estimated_response_on_two_workers(strip, tmp_path):
    name, d = strip
    plain = score(solve(d / "settings.txt", out=tmp_path / "plain", workers=1, plots=False).out_dir, d)
    assert plain["coverage"] > 0.95 and plain["albedo_rel_rmse"] < 0.03, (name, plain)
    times = d.parent / f"{name}_times.csv"  # the aligned case (exposure times known): the response pass is tested
    res = solve(d / "settings.txt", out=tmp_path / "resp", workers=2, plots=False, response="estimate",
                exposure_times=times)
    est = score(res.out_dir, d)
    # the scene's DN are linear in A T R: the estimated response must not cost more than a little accuracy;
    # DN outside the fitted levels' range have no g and drop out (~90 % of the pixels stay on these strips)
    assert est["coverage"] > 0.85 and est["albedo_rel_rmse"] < 0.05, (name, est)
    assert res.report["photometric_model"] == name
    assert "response" in res.report
