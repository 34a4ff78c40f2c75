"""Camera models: optics round trips, the real LRO NAC crop (tables) and the Apollo 15 Metric frame (kernels)."""
from __future__ import annotations

import numpy as np
import pytest
import spiceypy

from lunaralbedo.camera.build import build_camera
from lunaralbedo.camera.intersect import ray_sphere
from lunaralbedo.camera.optics import ApolloMetricDistortion, FocalPlane, LroNacDistortion, RadialOdk
from lunaralbedo.ingest.observation import open_observation
from lunaralbedo.model.geometry import lonlat_height
from lunaralbedo.spice.interp import interp_hermite, interp_quaternions, poly_function, quat_to_matrix
from lunaralbedo.spice.kernels import expand_kernel_args


@pytest.fixture(autouse=True)
def clean_pool():
    spiceypy.kclear()
    yield
    spiceypy.kclear()


@pytest.mark.parametrize("dist", [
    LroNacDistortion(1.81e-5), RadialOdk((0.0, -2e-5, 3e-9)),
    ApolloMetricDistortion((-0.006, -0.002), (-1.3361854e-06, 5.2261757e-10, -5.0728336e-14), (-5.5e-07, -4.6e-11, 2.97)),
])
def test_distortion_inverse_round_trip(dist):
    x, y = np.meshgrid(np.linspace(-55, 55, 11), np.linspace(-55, 55, 11))
    ux, uy = dist.undistort(x, y)
    bx, by = dist.distort(ux, uy)
    np.testing.assert_allclose(bx, x, atol=1e-9)
    np.testing.assert_allclose(by, y, atol=1e-9)


def test_focal_plane_look_and_project_are_inverse():
    fp = FocalPlane(699.62, (0, 0, 0.007), (0, 0.007, 0), (0, 0, 142.857142857), (0, 142.857142857, 0), 2548.0, 0.0,
                    LroNacDistortion(1.81e-5))
    ds, dl = np.meshgrid(np.linspace(-2500, 2500, 7), np.linspace(-3, 3, 3))
    bs, bl = fp.project(fp.look(ds, dl))
    np.testing.assert_allclose(bs, ds, atol=1e-6)
    np.testing.assert_allclose(bl, dl, atol=1e-6)


def test_quaternion_and_hermite_interpolation():
    q = np.array([spiceypy.m2q(spiceypy.rotate(a, 3)) for a in (0.1, 0.3)])
    mid = quat_to_matrix(interp_quaternions([0.0, 2.0], q, 1.0))
    np.testing.assert_allclose(mid, spiceypy.rotate(0.2, 3), atol=1e-12)
    t = np.array([0.0, 1.0, 2.0])
    pos = np.stack([t**3, t, 0 * t], axis=1)
    vel = np.stack([3 * t**2, 1 + 0 * t, 0 * t], axis=1)
    np.testing.assert_allclose(interp_hermite(t, pos, vel, 1.5), [1.5**3, 1.5, 0.0], atol=1e-12)
    # ISIS PolyFunction cache: sum_k c_k ((et - base) / scale)^k per axis
    coeffs = np.array([[1.0, 2.0, 3.0], [0.5, 0.0, -1.0], [0.25, 1.0, 0.0]])
    np.testing.assert_allclose(poly_function(coeffs, 10.0, 2.0, 14.0), [1 + 0.5 * 2 + 0.25 * 4, 2 + 4, 3 - 2])


def test_nac_crop_footprint_consistent_with_tables(realdata):
    """Footprint of M143947267L crop from its tables: size = range x IFOV x pixels, round trip to 1e-3 px."""
    with open_observation(realdata / "isis/M143947267L.cal.echo.crop.cub", "M143947267L") as obs:
        cam = build_camera(obs.label, obs.ephemeris, obs.code)
        assert cam.is_line_scanner
        s = np.array([1.0, 400.0, 1.0, 400.0, 200.5])
        l = np.array([1.0, 1.0, 400.0, 400.0, 200.5])
        origins, dirs = cam.rays(s, l)
        pts = ray_sphere(origins, dirs, 1737.4)
        bs, bl = cam.ground_to_image(pts)
        np.testing.assert_allclose(bs, s, atol=2e-3)
        np.testing.assert_allclose(bl, l, atol=2e-3)
        lon, lat, _ = lonlat_height(pts)
        assert lon[4] == pytest.approx(102.6011, abs=1e-3) and lat[4] == pytest.approx(35.9800, abs=1e-3)
        rng = np.linalg.norm(pts[4] - obs.spacecraft)
        width = np.linalg.norm(pts[1] - pts[0])  # across the 400 samples of line 1
        expected = rng * 399 * 0.007 / 699.62
        assert width == pytest.approx(expected, rel=0.1)  # ~0.22 km; oblique view stretches it a little
        # the look direction of the centre pixel is within 15 degrees of nadir (the NAC was slewed ~10 deg)
        nadir = -obs.spacecraft / np.linalg.norm(obs.spacecraft)
        assert np.degrees(np.arccos(dirs[4] @ nadir)) < 15.0


def test_apollo_metric_frame_camera_from_kernels(realdata):
    a15 = realdata / "apollo15_metric"
    kernels = expand_kernel_args([realdata / "kernels/generic", a15])
    with open_observation(a15 / "AS15-M-1450_isis3.lbl", "AS15-M-1450", kernels) as obs:
        cam = build_camera(obs.label, obs.ephemeris, obs.code)
        assert not cam.is_line_scanner and cam.focal.z_direction == -1.0
        origins, dirs = cam.rays(np.array([12899.0, 1.0, 25798.0]), np.array([12678.0, 25356.0, 1.0]))
        pts = ray_sphere(origins, dirs, 1737.4)
        lon, lat, _ = lonlat_height(pts)
        assert lon[0] == pytest.approx(119.507, abs=0.01) and lat[0] == pytest.approx(-15.362, abs=0.01)
        assert np.isnan(pts[2]).all()  # that corner of this oblique frame looks past the limb
        bs, bl = cam.ground_to_image(pts[:2])
        np.testing.assert_allclose(bs, [12899.0, 1.0], atol=1e-3)
        np.testing.assert_allclose(bl, [12678.0, 25356.0], atol=1e-3)
