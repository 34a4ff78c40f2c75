"""Hapke as the solver's reflectance (issue 13): hand-computed values, ISIS truth, PVL forms, a forward scene."""
from __future__ import annotations

import math

import numpy as np
import pytest

from lunaralbedo.engine.photometry import bind
from lunaralbedo.errors import SettingsError
from lunaralbedo.isis.pvlfile import read_object
from lunaralbedo.model import photometry
from lunaralbedo.model.photometry.hapke_model import EXAMPLE as HAPKE_DEFAULTS
from lunaralbedo.model.photometry.hapke_model import HapkeModel, setup
from lunaralbedo.model.photometry.hapke_model import pvl_text as hapke_pvl_text

LROC_NAMES = ("W", "B", "C", "BCO", "HC", "BSO", "HS", "THETA", "PHI")


def load_solver_hapke(pvl, pmap=None, center=None):
    """``(HapkeModel, per-point parameters)`` of a parameter file, as the solver reads it."""
    from lunaralbedo.isis.parameter_map import read_parameter_map

    return setup(read_object(pvl, "PhotometricModel"), str(pvl), center, pmap and read_parameter_map(pmap), pmap)


def bound(pvl, pmap=None, center=None):
    """The registry's hapke model bound to its files, as the solver and the forward model use it."""
    return bind(photometry.get("hapke"), {"HAPKE_PARAMETERS": pvl, "HAPKE_PARAMETER_MAP": pmap, "HAPKE_BAND_CENTER": center})


def _h(x, w):
    """Hapke (2002) H-function, by hand."""
    r0 = (1 - math.sqrt(1 - w)) / (1 + math.sqrt(1 - w))
    return 1 / (1 - w * x * (r0 + (1 - 2 * r0 * x) / 2 * math.log((1 + x) / x)))


def _p(g, b, c):
    cg = math.cos(g)
    return (1 + c) / 2 * (1 - b * b) / (1 - 2 * b * cg + b * b) ** 1.5 + (1 - c) / 2 * (1 - b * b) / (1 + 2 * b * cg + b * b) ** 1.5


def test_smooth_hapke_lroc_by_hand():
    w, b, c, bc0, hc, bs0, hs = 0.3, 0.25, 0.6, 0.9, 0.06, 1.6, 0.07
    i, e, g = map(math.radians, (30.0, 20.0, 45.0))
    mu0, mu = math.cos(i), math.cos(e)
    bs = 1 / (1 + math.tan(g / 2) / hs)
    x = math.tan(g / 2) / hc
    bc = (1 + (1 - math.exp(-x)) / x) / (2 * (1 + x) ** 2)
    expect = w / 4 * mu0 / (mu0 + mu) * (_p(g, b, c) * (1 + bs0 * bs) + _h(mu0, w) * _h(mu, w) - 1) * (1 + bc0 * bc)
    m = HapkeModel("HapkeLROC", (60.0, 0.0, 60.0), dict(zip(LROC_NAMES, (w, b, c, bc0, hc, bs0, hs, 0.0, 0.0))))
    assert m.reflectance(30.0, 20.0, 45.0) == pytest.approx(expect, rel=1e-12)


def test_rough_hapke_lroc_at_normal_incidence_by_hand():
    """At i = 0 Hapke's (1984) roughness reduces to mu0e = chi, mue = eta(e), S = 1 (and K from the porosity)."""
    w, b, c, theta, phi = 0.3, 0.25, 0.6, math.radians(20.0), 0.4
    e, g = math.radians(30.0), math.radians(30.0)
    t = math.tan(theta)
    chi = 1 / math.sqrt(1 + math.pi * t * t)
    cot_t, cot_e = 1 / t, 1 / math.tan(e)
    e1 = math.exp(-2 / math.pi * cot_t * cot_e)
    e2 = math.exp(-1 / math.pi * cot_t**2 * cot_e**2)
    eta_e = chi * (math.cos(e) + math.sin(e) * t * e2 / (2 - e1))
    ck = 1.209 * phi ** (2 / 3)
    k = -math.log(1 - ck) / ck
    expect = k * w / 4 * chi / (chi + eta_e) * (_p(g, b, c) + _h(chi / k, w) * _h(eta_e / k, w) - 1)
    m = HapkeModel("HapkeLROC", (60.0, 0.0, 60.0), dict(zip(LROC_NAMES, (w, b, c, 0, 0.06, 0, 0.07, 20.0, phi))))
    assert m.reflectance(0.0, 30.0, 30.0) == pytest.approx(expect, rel=1e-9)
    assert m.normalised(1.0, math.cos(e), g) == pytest.approx(expect / m.reflectance(60.0, 0.0, 60.0), rel=1e-9)


@pytest.mark.parametrize("angles, truth", [((0.0, 0.0, 0.0), 0.0965097), ((45.0, 30.0, 60.0), 0.0832883)])
def test_hapke_hen_isis_truth_through_the_solver_model(angles, truth):
    m = HapkeModel("HapkeHen", (0, 0, 0), {"WH": 0.5, "B0": 0.0, "HH": 0.0, "THETA": 0.0, "HG1": 0.0, "HG2": 0.0})
    assert m.reflectance(*angles) == pytest.approx(truth, abs=5e-7)  # (i, e, g): the model orders ISIS's (g, i, e)


def test_unlit_and_unseen_give_zero():
    m = HapkeModel("HapkeLROC", (60.0, 0.0, 60.0), dict(HAPKE_DEFAULTS))
    assert m.normalised(np.array([-0.1, 0.5, 0.5]), np.array([0.5, -0.2, 0.8]), 0.5).tolist()[:2] == [0.0, 0.0]


def test_pvl_constants_forms(tmp_path):
    p = tmp_path / "h.pvl"
    p.write_text(hapke_pvl_text(HAPKE_DEFAULTS))
    got, points = load_solver_hapke(p)
    assert got.variant == "HAPKELROC" and got.reference == (60.0, 0.0, 60.0)
    assert got.constants == HAPKE_DEFAULTS and points is None
    model = bound(p)  # the registry model bound to the file: R = r_H / r_H(reference)
    ci, ce, al = np.cos(np.radians(30.0)), np.cos(np.radians(20.0)), np.radians(45.0)
    assert model.reflectance(ci, ce, al) == pytest.approx(got.reflectance(30.0, 20.0, 45.0) / got.reflectance(60, 0, 60))
    assert model.layers(ci, ce, al)["geometric"] == pytest.approx(model.reflectance(ci, ce, al))
    p.write_text("Object = PhotometricModel\n Units = Degrees\n Incref = 30\n Emiref = 0\n Pharef = 30\n"
                 " Group = Algorithm\n  Name = HapkeHen\n  Wh = 0.5\n  B0 = 0\n  Hh = 0\n  Theta = 0\n  Hg1 = 0\n  Hg2 = 0\n"
                 " EndGroup\nEndObject\n")
    hen, _ = load_solver_hapke(p)
    assert hen.variant == "HAPKEHEN"
    assert hen.reflectance(45.0, 30.0, 60.0) == pytest.approx(0.0832883, abs=5e-7)
    p.write_text(p.read_text().replace("HapkeHen", "Minnaert"))
    with pytest.raises(SettingsError, match="not one of HapkeLROC"):
        load_solver_hapke(p)
    p.write_text(hapke_pvl_text(HAPKE_DEFAULTS).replace("  Incref = 60\n", ""))
    with pytest.raises(SettingsError, match="Incref"):
        bound(p)
    with pytest.raises(SettingsError, match="HAPKE_PARAMETERS.*nothere.pvl"):
        bound(tmp_path / "nothere.pvl")


def test_pvl_with_the_wac_parameter_map(realdata):
    from lunaralbedo.isis.parameter_map import read_parameter_map

    pvl = realdata / "isis" / "hapke_full_reformatted.pvl"
    cube = realdata / "isis" / "1x1_70NS_7b_wbhs_albflt_grid_geirist_tcorrect.reduced.cub"
    with pytest.raises(SettingsError, match="HAPKE_BAND_CENTER"):
        load_solver_hapke(pvl, cube)
    got, points = load_solver_hapke(pvl, cube, 415.0)
    lon, lat = np.array([10.5, 200.25]), np.array([-3.2, 40.0])
    params = points(lon, lat)
    pmap = read_parameter_map(cube)
    rows, cols, inside = pmap.pixel(lat, lon)
    assert inside.all()
    for k, name in enumerate(LROC_NAMES):  # the 415 nm group holds bands 19..27
        assert params[name] == pytest.approx(pmap.data[18 + k][rows, cols])
    r = got.normalised(np.cos(np.radians(60.0)), 1.0, np.radians(60.0), {n: v[0] for n, v in params.items()})
    assert r == pytest.approx(1.0)  # the reference geometry itself
    model = bound(pvl, cube, 415.0)  # the registry model reads the map per ground point
    at_ref = model.layers(np.full(2, 0.5), np.ones(2), np.full(2, np.radians(60.0)), lon=lon, lat=lat)["geometric"]
    assert at_ref == pytest.approx([1.0, 1.0])
    with pytest.raises(SettingsError, match="longitude and latitude"):
        model.layers(0.5, 1.0, 1.0)


def test_hapke_forward_scene_is_recovered(tmp_path):
    from lunaralbedo.engine.solve import solve
    from lunaralbedo.simulate import SceneSpec, render_scene, score

    d = tmp_path / "hapke"
    render_scene(d, SceneSpec(reflectance_type=3, gain=45.0, seed=9))
    res = solve(d / "settings.txt", out=tmp_path / "out", workers=1, plots=False)
    assert res.iterations <= 10
    sc = score(tmp_path / "out", d)
    assert sc["coverage"] > 0.95
    assert sc["albedo_rel_rmse"] < 0.025, sc
    assert sc["exposure_max_rel_err"] < 0.01, sc


def test_toml_names_the_model(tmp_path):
    from lunaralbedo.settings import load_settings

    p = tmp_path / "s.toml"
    base = 'drg_dir = "d"\ndem_dir = "m"\nsun_position_file = "s"\nspacecraft_position_file = "c"\n'
    p.write_text(base + 'reflectance = "hapke"\nhapke_parameters = "h.pvl"\nhapke_parameter_map = "map.cub"\n')
    s = load_settings(p)
    assert s.reflectance_type == 3 and s.hapke_parameters == tmp_path / "h.pvl"
    assert s.hapke_parameter_map == tmp_path / "map.cub"
    p.write_text(base + 'reflectance = "hapke"\n')
    with pytest.raises(SettingsError, match="HAPKE_PARAMETERS"):
        load_settings(p)
