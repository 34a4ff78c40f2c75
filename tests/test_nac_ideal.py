"""The ideal camera of the ASP LRO-NAC notes (ISIS noproj numbers for LRO NAC) on the real NAC-L crop, and its definition checks."""
from __future__ import annotations

import numpy as np
import pytest

from lunaralbedo.camera.intersect import ray_sphere
from lunaralbedo.constants import MOON_RADIUS_KM
from lunaralbedo.errors import InputError
from lunaralbedo.nac.ideal import NOPROJ_INSTRUMENTS, ideal_camera, noproj_spec
from lunaralbedo.nac.mosaic import choose_spec

NAC = "M143947267L.cal.echo.crop.cub"  # samples 3000-3399, lines 16000-16399 of the observation (AlphaCube)
SEED = NOPROJ_INSTRUMENTS["LUNAR RECONNAISSANCE ORBITER/NACL"]

pytestmark = pytest.mark.usefixtures("clean_spice_pool")


@pytest.fixture(scope="module")
def nac_l(realdata):
    from lunaralbedo.camera.build import build_camera
    from lunaralbedo.ingest.observation import open_observation

    cube = realdata / "isis" / NAC
    with open_observation(cube, cube.stem) as obs:
        le = build_camera(obs.label, obs.ephemeris, obs.code)
        spec, source = choose_spec(obs.label, le, None)
        ideal = ideal_camera(spec, obs.ephemeris, le)
        yield obs.label, le, spec, source, ideal


def test_real_nac_l_gets_the_seed_ideal_camera(nac_l):
    label, le, spec, source, _ = nac_l
    assert "the ASP LRO-NAC notes" in source
    # noproj: TransX0/TransY0 = the typed mm, pitch 7 um and axes from the NAC-L IK (x follows lines, y samples)
    assert (spec.x0, spec.y0, spec.samples, spec.pitch) == (0.6475, 16.8833, 10000, pytest.approx(0.007))
    assert spec.sample_axis == pytest.approx((0.0, 0.007)) and spec.line_axis == pytest.approx((0.007, 0.0))
    assert spec.focal_length == pytest.approx(699.62)  # INS-85600_FOCAL_LENGTH
    # ItransS/ItransL are TransY/TransX in pixels of the IK's pitch (seed: "just use the pixel pitch")
    assert -SEED["TransY"] / 0.007 == pytest.approx(SEED["ItransS"], abs=0.01)
    assert -SEED["TransX"] / 0.007 == pytest.approx(SEED["ItransL"], abs=0.01)
    # summed (SpatialSumming 2) NAC: half the samples of twice the pitch, same focal-plane position
    half = noproj_spec(le, SEED, summing=2.0)
    assert (half.samples, half.pitch, half.y0) == (5000, pytest.approx(0.014), 16.8833)


def test_seed_ideal_camera_sees_the_nac_l_columns_where_noproj_puts_them(nac_l):
    """Real IK and SPICE tables: an ideal pixel's ground point is seen by NAC-L detector column
    ``ideal sample - 5000.5 - ItransS + BORESIGHT_SAMPLE 2548`` (within 1 px: the NAC-L's radial distortion,
    which the ideal camera does not have, is 0.15-0.5 px here) and TransX's 92.5 px of along-track
    angle later (87.5 lines at this observation's line rate: within 10 %)."""
    _, le, spec, _, ideal = nac_l
    detector = np.array([3100.0, 3200.0, 3300.0, 3390.0])  # NAC-L detector samples inside the crop
    s, l = np.meshgrid(detector - 2548.0 + 5000.5 + SEED["ItransS"], [120.0, 200.0, 280.0])
    pts = ray_sphere(*ideal.rays(s, l), MOON_RADIUS_KM)
    ls, ll = le.ground_to_image(pts)
    assert np.isfinite(ls).all()
    col = ls + 2999.0  # crop -> detector sample (AlphaCube starts at 2999.5)
    assert np.abs(col - detector).max() < 1.0, col - detector
    assert np.abs(ll - l - 92.5).max() < 9.25, ll - l


def test_noproj_definitions_are_checked_and_chosen(nac_l):
    label, le, *_ = nac_l
    bad = {**SEED, "ItransS": -2400.0}
    with pytest.raises(InputError, match="ItransS = -2400.0 does not match"):
        noproj_spec(le, bad, name="NACL")
    from lunaralbedo.nac.ideal import ideal_spec

    computed, source = choose_spec(label, le, le, "computed")
    assert source.startswith("computed") and computed == ideal_spec(le, le)
    label.instrument["InstrumentId"] = "NACX"  # an unknown instrument has no noproj definition
    try:
        with pytest.raises(InputError, match="no noproj ideal-camera definition"):
            choose_spec(label, le, le, "noproj")
    finally:
        label.instrument["InstrumentId"] = "NACL"
