"""The worked example of docs/architecture.md (adding the Minnaert model) runs as written.

The model's code is taken from the fenced ``python`` block of the doc's worked example
and executed as ``lunaralbedo/model/photometry/minnaert.py`` would be, so these tests
fail when the example in the doc breaks.  The model is registered for the test only;
the registry is checked to be as it was afterwards.
"""
from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

from lunaralbedo.errors import SettingsError
from lunaralbedo.model import photometry

DOC = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"
SECTION = "## Worked example: adding a reflectance model"
ALBEDO_TOL, EXPOSURE_TOL = 0.025, 0.01  # tests/test_solve_forward.py
TRUE_K = 0.9
K_TOL = 0.02


def _example() -> tuple[str, str]:
    """The example's code block and the rest of its section (which holds the registration line)."""
    text = DOC.read_text()
    assert SECTION in text, f"{DOC} lost its section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the worked example has one code block: the model's file"
    return blocks[0], section


def _doc_module():
    """The doc's code block as the module ``lunaralbedo.model.photometry.minnaert`` (not left in sys.modules)."""
    code, _ = _example()
    spec = importlib.util.spec_from_loader("lunaralbedo.model.photometry.minnaert", loader=None)
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = "lunaralbedo.model.photometry"
    exec(compile(code, f"{DOC} (worked example)", "exec"), mod.__dict__)
    return mod


@pytest.fixture
def minnaert():
    """The doc's model, registered as step 2 of the example says, and unregistered afterwards."""
    mod = _doc_module()
    before = dict(photometry.REGISTRY)
    assert mod.MODEL.name not in before
    photometry.REGISTRY[mod.MODEL.name] = mod.MODEL
    try:
        yield mod.MODEL
    finally:
        del photometry.REGISTRY[mod.MODEL.name]
        assert photometry.REGISTRY == before  # the registry is left as it was


def test_the_doc_registers_its_model_in_one_line():
    _, section = _example()
    assert "minnaert.MODEL)}" in section and "REGISTRY = {m.name: m for m in (" in section


def test_reflectance_and_derivative_follow_the_formula(minnaert):
    assert photometry.get("minnaert") is minnaert and minnaert.parameters == ("k",)
    ci = np.array([0.9, 0.6, 0.35, 0.8])
    ce = np.array([1.0, 0.7, 0.95, 0.5])
    al = np.radians([10.0, 40.0, 70.0, 30.0])
    k = 0.8
    np.testing.assert_allclose(minnaert.reflectance(ci, ce, al, (k,)), ci**k * ce ** (k - 1), rtol=1e-12)
    assert minnaert.reflectance(-0.1, 0.9, 0.3, (k,)) == 0.0  # unlit
    arrays = minnaert.layers(ci, ce, al)
    (d,) = minnaert.derivatives_from(arrays, np.array([k]))
    h = 1e-6
    fd = (minnaert.reflectance_from(arrays, np.array([k + h])) - minnaert.reflectance_from(arrays, np.array([k - h]))) / (2 * h)
    np.testing.assert_allclose(d, fd, rtol=1e-6)


def test_settings_name_the_model_and_validate_its_key(minnaert, tmp_path):
    from lunaralbedo.settings import load_settings

    base = 'drg_dir = "d"\ndem_dir = "m"\nsun_position_file = "s"\nspacecraft_position_file = "c"\n'
    p = tmp_path / "s.toml"
    p.write_text(base + 'reflectance = "minnaert"\nminnaert_k = 0.6\n')
    s = load_settings(p)
    assert s.model is minnaert and s.reflectance_type is None and s.initial_params.tolist() == [0.6]
    p.write_text(base + 'reflectance = "minnaert"\nminnaert_k = 3\n')
    with pytest.raises(SettingsError, match="MINNAERT_K must be in"):
        load_settings(p)


def test_unregistered_the_model_is_unknown(tmp_path):
    from lunaralbedo.settings import load_settings

    assert "minnaert" not in photometry.names()
    p = tmp_path / "s.toml"
    p.write_text('drg_dir = "d"\nreflectance = "minnaert"\n')
    with pytest.raises(SettingsError, match="REFLECTANCE must be one of"):
        load_settings(p)


def test_a_forward_scene_rendered_with_the_model_is_recovered(minnaert, tmp_path):
    from lunaralbedo.engine.solve import solve
    from lunaralbedo.settings import load_settings
    from lunaralbedo.simulate import SceneSpec, render_scene, score

    d = tmp_path / "scene"
    # c1 is the first fitted parameter of the rendering model: the true k.  The solver starts from MINNAERT_K's default.
    # k is seen through the spread of cos i: three Sun azimuths over 1.5 km relief.  The damped step moves k slowly
    # (0.70 -> 0.79 after 10 passes, 0.89 after 60), hence the 60 passes.
    spec = SceneSpec(reflectance_type="minnaert", c1=TRUE_K, n_images=4, image_px=80, seed=31,
                     sun_azimuths=(90.0, 210.0, 330.0), dem_relief_m=1500.0, max_num_iter=60)
    render_scene(d, spec)
    settings = load_settings(d / "settings.txt")
    assert settings.model is minnaert and settings.initial_params.tolist() == [0.7]
    solve(d / "settings.txt", out=tmp_path / "out", workers=1, plots=False)
    sc = score(tmp_path / "out", d)
    assert sc["coverage"] > 0.95, sc
    assert sc["albedo_rel_rmse"] < ALBEDO_TOL, sc
    assert sc["exposure_max_rel_err"] < EXPOSURE_TOL, sc
    assert (tmp_path / "out" / "phase.csv").read_text().startswith("iteration,k\n0,0.7\n")
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert list(rep["parameters"]) == ["k"] and rep["photometric_model"] == "minnaert"
    k = rep["parameters"]["k"]
    assert abs(k[-1] - TRUE_K) < K_TOL, k  # 0.894 measured
    assert all(b >= a for a, b in zip(k, k[1:])), k  # towards the truth at every pass
