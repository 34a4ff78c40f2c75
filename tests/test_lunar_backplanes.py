"""`lunaralbedo backplanes` on each lunar instrument's label (Kaguya MI: tests/test_lunar_cameras.py).

Truth: Kaguya TC and Clementine UVVIS, the angles that ale's ISD gives at chosen pixels (its ground
point read as ISIS does, its spacecraft and Sun positions: ``tests/ale_isd.py``); Chandrayaan-2
TMC-2, whose CK slice is not kept, a simulated cube (``simulate --instrument chandrayaan2-tmc2``)
against the renderer's own geometry (spacecraft moving along its line, its head-frame lines of sight).
"""
from __future__ import annotations

import numpy as np
import pytest
import rasterio
import spiceypy
from click.testing import CliRunner

from ale_isd import body_vector, ground_point, load_isd
from lunaralbedo.camera.intersect import ray_sphere
from lunaralbedo.cli import main
from lunaralbedo.simulate import lunar_missions as lm
from lunaralbedo.simulate.mission import shot_geometry

from test_lunar_cameras import _cases, generic  # noqa: F401 - the fixture

PIXELS = [(1.0, 1.0), (101.0, 37.0), (250.0, 80.0)]  # ISIS (sample, line), inside every cube used here


@pytest.fixture(autouse=True)
def clean_pool():
    spiceypy.kclear()
    yield
    spiceypy.kclear()


def _angles(point, sun, spacecraft):
    """(phase, emission, incidence) degrees on the sphere (normal = radial) at body-fixed ``point`` (km)."""
    n = point / np.linalg.norm(point)
    s, v = (u / np.linalg.norm(u) for u in (sun - point, spacecraft - point))
    return tuple(float(np.degrees(np.arccos(np.clip(a @ b, -1, 1)))) for a, b in ((s, v), (v, n), (s, n)))


def _backplanes(cube, tmp_path, *args):
    out = tmp_path / "bp.tif"
    res = CliRunner().invoke(main, ["backplanes", str(cube), "--ellipsoid", *map(str, args), "-o", str(out)])
    assert res.exit_code == 0, res.output
    with rasterio.open(out) as ds:
        return ds.read()


@pytest.mark.parametrize("name", ["kaguya_tc", "clementine_uvvis"])
def test_backplanes_on_the_label_match_ale_isd(realdata, generic, tmp_path, name):
    """Phase, emission and incidence at three pixels within 0.002 degree of the ISD's. Measured: TC 3.4e-4 degree
    (our spacecraft from the label's kernels is 11.6 m from ale's, the ground point ~10 m: 3.3e-4 degree of arc
    on the Moon), UVVIS 1e-6 degree."""
    label, kernels, isd_path, _ = _cases(realdata, generic)[name]
    isd = load_isd(isd_path)
    a = _backplanes(label, tmp_path, *[x for k in kernels for x in ("--kernels", k)])
    for s, l in PIXELS:
        p, t = ground_point(isd, l - 0.5, s - 0.5, isis_conventions=True)
        want = _angles(p, body_vector(isd, "sun_position", t), body_vector(isd, "instrument_position", t))
        got = tuple(float(a[k, int(l) - 1, int(s) - 1]) for k in range(3))
        print(f"{name} ({s:g}, {l:g}): ours {got} ISD {want}")
        assert got == pytest.approx(want, abs=0.002)


@pytest.mark.usefixtures("clean_spice_pool")
def test_backplanes_on_a_tmc2_cube(tmp_path):
    """TMC-2 (summed crop, flown backwards): phase, emission and incidence at three pixels equal the renderer's
    (spacecraft at each line's time on its straight track, the pixel's ray onto the sphere) to 1e-3 degree.
    Measured: phase 2e-6, incidence 3.0e-4 degree: ingest reads the spacecraft with the LT+S correction seen
    from the Moon's centre (as ISIS), 6 ms of light time at 1.6 km/s = 10 m = 3.3e-4 degree of arc."""
    name, seed = "chandrayaan2_tmc2", 4601
    scene_dir = tmp_path / "scene"
    truth = lm.build(scene_dir, name, seed=seed, n_images=1)
    (_key, im), = truth["images"].items()
    a = _backplanes(scene_dir / im["cube"], tmp_path)
    _rng, scene, (shot,) = lm.plan(name, seed, 1)
    p0, vel, m, _ = shot_geometry(scene, shot)
    sun = np.array(im["sun_km"])
    for s, l in [(1.0, 1.0), (60.0, 80.0), (120.0, 160.0)]:
        t = (l - 0.5) * shot.line_rate - shot.lines * shot.line_rate / 2.0
        look = lm.tmc_look(lm.TMC_SUMMING * (s + lm.TMC_CROP_SAMPLE - 0.5) - 0.5) @ (m @ lm.TMC_HEAD_TO_SC).T
        sc = p0 + vel * t
        want = _angles(ray_sphere(sc, look, 1737.4), sun, sc)
        got = tuple(float(a[k, int(l) - 1, int(s) - 1]) for k in range(3))
        assert got == pytest.approx(want, abs=1e-3)
