"""Orthoprojection by coarse exact grid + interpolation equals the exact per-pixel projection."""
from __future__ import annotations

import numpy as np
import pytest

from lunaralbedo.camera.optics import LroNacDistortion
from lunaralbedo.simulate import mission as sim
from lunaralbedo.ingest.approx import exact_coordinates, image_coordinates
from lunaralbedo.model.grid import Grid, aligned_grid, mpp_to_degrees
from lunaralbedo.ingest.orthoproject import footprint, orthoproject


def _nac_like(kind: str, lines: int, samples: int, margin_deg: float = 0.0):
    """A NAC-like camera (0.5 m/px from 50 km, LRO NAC distortion) over a cratered DEM with 30 m ripples."""
    rng = np.random.default_rng(11)
    scene = sim.make_scene(rng, shape=(300, 300), west=4.5, north=-4.5, res=0.01)
    shot = sim.Shot(key="N", kind=kind, et=sim.ET_BASE, exposure=1.0, aim_lon=6.0, aim_lat=-6.0, sun_azimuth=90,
                    sun_elevation=30, view_azimuth=30, view_zenith=12, altitude_km=50, lines=lines, samples=samples,
                    line_rate=3.125e-4)
    cam = sim.shot_camera(scene, shot, focal_mm=699.6, pitch_mm=0.007, distortion=LroNacDistortion(1.8e-5))
    lon, lat = footprint(cam, scene.height)
    m = margin_deg
    grid = aligned_grid((mpp_to_degrees(0.5),) * 2, (lon.min() - m, lat.min() - m, lon.max() + m, lat.max() + m))
    lo, la = grid.lonlat()
    heights = scene.height(lo, la) + 30.0 * np.sin(lo * 2000.0) * np.cos(la * 1500.0)
    image = rng.uniform(0.0, 1.0, (lines, samples)).astype(np.float32)
    return cam, grid, heights, image


@pytest.mark.parametrize("kind", ["line", "frame"])
def test_interpolated_coordinates_within_a_tenth_of_a_pixel_of_the_exact_ones(kind):
    cam, grid, heights, _ = _nac_like(kind, 300, 600, margin_deg=0.002)
    h = heights[:160]
    s, l, refined = image_coordinates(cam, grid.transform, 0, h)
    rows, cols = np.indices(h.shape)
    es, el = exact_coordinates(cam, grid.transform, rows, cols, h)
    inside = (es > 0.5) & (es < 600.5) & (el > 0.5) & (el < 300.5)
    assert inside.sum() > 20000 and (~inside).sum() > 1000  # the block crosses the image's edge
    err = np.hypot(s - es, l - el)[inside]
    assert np.all(np.isfinite(err))
    assert err.max() < 0.1
    assert np.isnan(s).sum() == np.isnan(es).sum()


def test_cells_that_fail_the_check_are_projected_exactly():
    cam, grid, heights, _ = _nac_like("line", 300, 600)
    h = heights[:80]
    s, l, refined = image_coordinates(cam, grid.transform, 0, h, max_error_px=1e-9)
    assert refined == pytest.approx(np.isfinite(h).mean())
    rows, cols = np.indices(h.shape)
    es, el = exact_coordinates(cam, grid.transform, rows, cols, h)
    np.testing.assert_array_equal(s, es)
    np.testing.assert_array_equal(l, el)


def test_orthoproject_same_values_as_the_exact_projection():
    cam, grid, heights, image = _nac_like("line", 300, 600)
    sub = Grid(grid.transform, (120, grid.shape[1]))
    fast = orthoproject(cam, image, grid, heights)[:120]
    exact = orthoproject(cam, image, sub, heights[:121], exact=True)
    both = np.isfinite(fast) & np.isfinite(exact)
    assert both.sum() > 15000
    assert np.sum(np.isfinite(fast) != np.isfinite(exact)) <= 0.001 * both.sum()  # only at the image's edge
    # values of random pixels: a 0.1 px shift would change them by ~0.1; here they agree to 1e-2
    assert np.max(np.abs(fast[both] - exact[both])) < 1e-2


def test_sample_visible_refuses_heights_with_more_rows_than_latitudes():
    """The numba pass reads latitudes unchecked: a DEM one row longer than the grid's latitudes used to
    read past their end (the last row's normal from whatever lay there: test above, 1 run in 3)."""
    from lunaralbedo.ingest.sampling import sample_visible

    heights = np.zeros((3, 4))
    out = np.empty((2, 4))
    s = l = np.ones((2, 4))
    with pytest.raises(ValueError, match="latitudes"):
        sample_visible(np.ones((2, 2)), s, l, np.arange(4.0), np.arange(2.0), heights, 0, (1800.0, 0, 0), out)
