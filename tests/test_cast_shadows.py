"""Cast shadows from the DEM (issue 13): against a brute-force ray cast on the continuous terrain, and the Moon's curvature."""
from __future__ import annotations

import math

import numpy as np
import pytest
from rasterio.transform import Affine

from lunaralbedo.constants import MOON_RADIUS_KM
from lunaralbedo.model import geometry
from lunaralbedo.model.cast_shadows import cast_shadow_mask, shadow_reach_km, sun_elevation
from lunaralbedo.simulate import truth_dem


def _sun(lon_deg, lat_deg, incidence_deg, azimuth_deg=90.0):
    """Sun 1 AU away, ``incidence_deg`` from the zenith of (lon, lat), from azimuth (clockwise from north)."""
    up = geometry.body_fixed(lon_deg, lat_deg, 0.0) / MOON_RADIUS_KM
    lo, la = np.radians(lon_deg), np.radians(lat_deg)
    east = np.array([-np.sin(lo), np.cos(lo), 0.0])
    north = np.array([-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)])
    az, inc = np.radians(azimuth_deg), np.radians(incidence_deg)
    d = np.cos(inc) * up + np.sin(inc) * (np.sin(az) * east + np.cos(az) * north)
    return d * 1.496e8


def _brute_force(fn, lon, lat, sun, step_km, reach_km, hmax):
    """Ray cast on the continuous terrain ``fn(lon, lat)`` (metres), every ``step_km``, all pixels at once."""
    p = geometry.body_fixed(lon, lat, fn(lon, lat))
    l = sun - p
    l /= np.linalg.norm(l, axis=-1, keepdims=True)
    shadow = np.zeros(lon.shape, bool)
    active = np.ones(lon.shape, bool)
    for s in np.arange(step_km, reach_km, step_km):
        q = p[active] + s * l[active]
        lo, la, hray = geometry.lonlat_height(q)
        blocked = hray < fn(lo, la)
        idx = np.flatnonzero(active)
        shadow.flat[idx[blocked]] = True
        done = blocked | (hray > hmax)
        active.flat[idx[done]] = False
        if not active.any():
            break
    return shadow


def _bilinear(dem, transform):
    """The DEM as the solver sees it: bilinear between pixel centres (a continuous function of lon, lat)."""
    from scipy.interpolate import RegularGridInterpolator

    h, w = dem.shape
    lats = transform.f + transform.e * (np.arange(h) + 0.5)
    lons = transform.c + transform.a * (np.arange(w) + 0.5)
    f = RegularGridInterpolator((lats[::-1], lons), dem[::-1], bounds_error=False, fill_value=-1e9)
    return lambda lo, la: f(np.stack([la, lo], axis=-1))


@pytest.mark.parametrize("incidence, azimuth", [(74.0, 90.0), (78.0, 240.0)])
def test_mask_agrees_with_a_ray_cast_on_the_continuous_terrain(incidence, azimuth):
    res = 0.0025  # degrees (76 m): the smallest craters (0.6 km radius) span 8 pixels
    extent = (10.0, 11.2, -5.0, -4.0)

    def fn(lo, la):  # hills plus fresh craters with ~39-degree walls
        return truth_dem(lo, la, extent, 300.0, fresh_per_square_degree=100.0)

    margin = 40  # px (3 km): a 0.5 km rim-to-floor drop casts at most 2.4 km with the Sun 12 degrees high
    h, w = 90, 120
    transform = Affine(res, 0, 10.45 - margin * res, 0, -res, -4.4 + margin * res)
    lon, lat = geometry.lonlat_grid(transform, (h + 2 * margin, w + 2 * margin))
    dem = fn(lon, lat)
    sun = _sun(10.6, -4.5, incidence, azimuth)
    mask = cast_shadow_mask(dem, transform, sun, (margin, margin + h, margin, margin + w))
    inner = (slice(margin, margin + h), slice(margin, margin + w))
    hmax = np.max(dem) + 1
    # 1. the marching itself: the same (bilinear) terrain, ray cast every 8 m
    same = _brute_force(_bilinear(dem, transform), lon[inner], lat[inner], sun, 0.008, 40.0, hmax)
    assert 0.08 < same.mean() < 0.6  # a real low-Sun scene: shadows are common, not everywhere
    assert np.mean(mask == same) >= 0.995, (np.mean(mask == same), same.mean(), mask.mean())
    # 2. against the continuous terrain the DEM samples (rims are cusps the grid rounds off a little)
    truth = _brute_force(fn, lon[inner], lat[inner], sun, 0.008, 40.0, hmax)
    agree = np.mean(mask == truth)
    assert agree >= 0.98, (agree, truth.mean(), mask.mean())
    assert abs(mask.mean() - truth.mean()) < 0.025


def test_curvature_shortens_a_long_shadow_as_the_sphere_does():
    """A 1 km wall, Sun 2 degrees high over it: the shadow ends where the sphere says, not where a plane would."""
    res, wall_h = 0.005, 1000.0
    lon_w = 12.0
    n_west = 400  # 2 degrees of ground west of the wall
    transform = Affine(res, 0, lon_w - n_west * res, 0, -res, 3 * res / 2)
    lon, lat = geometry.lonlat_grid(transform, (3, n_west + 10))
    dem = np.where((lon >= lon_w) & (lon < lon_w + 3 * res), wall_h, 0.0)
    eps_w = np.radians(2.0)
    sun = _sun(lon_w, 0.0, 90.0 - 2.0)
    mask = cast_shadow_mask(dem, transform, sun, (1, 2, 0, n_west))[0]
    west_of_wall = np.flatnonzero(~mask)
    tip = west_of_wall.max()  # last lit pixel west of the wall: the shadow runs from it to the wall
    length_deg = lon_w - lon[1, tip + 1]
    # exact on the sphere: a point theta west of the wall sees the wall's top at elevation above
    # the Sun's while cos(eps_w - theta) > R cos(eps_w) / (R + H)
    r = MOON_RADIUS_KM
    theta = eps_w - math.acos((r + wall_h / 1000) * math.cos(eps_w) / r)
    # within 5 pixels (1.6 % of the 300-pixel shadow): near its tip the ray grazes the wall's top for less
    # than one half-pixel march step (2 px), and the bilinear wall is not a sharp edge (a dense ray cast
    # on it ends 1.7 px short too)
    assert length_deg == pytest.approx(math.degrees(theta), abs=5 * res)
    # the same from the tip's own horizon: s tan(eps) + s^2 / 2R = H (what shadow_reach_km computes)
    eps_tip = float(sun_elevation(geometry.body_fixed(lon[1, tip + 1], 0.0, 0.0), sun))
    s_km = math.radians(length_deg) * r
    assert shadow_reach_km(wall_h, eps_tip) == pytest.approx(s_km, rel=0.03)
    flat = wall_h / 1000 / math.tan(eps_tip)  # a plane would put the tip 2.5 times farther
    assert flat > 2 * s_km


def test_nan_heights_block_nothing_and_have_no_shadow():
    transform = Affine(0.01, 0, 0, 0, -0.01, 0.5)
    dem = np.zeros((50, 50))
    dem[:, 20:23] = 2000.0
    dem[:, 21] = np.nan
    dem[10, :] = np.nan
    sun = _sun(0.25, 0.25, 80.0)
    m = cast_shadow_mask(dem, transform, sun)
    assert not m[10].any()
    assert m[30, 10:20].all()  # still shadowed by the wall's finite columns
    assert not m[30, 23:].any()


@pytest.mark.parametrize("lat, res, incidence, azimuth, relief", [
    (0.0, 0.0025, 80.0, 90.0, 600.0),    # low Sun over fresh craters: long shadows, many steps skipped
    (-60.0, 0.002, 70.0, 200.0, 900.0),  # high latitude: longitude pixels a half of latitude ones
    (10.0, 0.01, 30.0, 300.0, 3000.0),   # high Sun over steep relief: the slope bound does not apply
    (0.0, 0.0025, 40.0, 45.0, 300.0),    # high Sun, gentle terrain: every ray is cut short by the slope bound
])
def test_shortcuts_do_not_change_the_mask(lat, res, incidence, azimuth, relief):
    """The slope bound and the block-maximum skipping give exactly the plain march's mask."""
    rng = np.random.default_rng(int(incidence))
    n = 160
    transform = Affine(res, 0, 20.0 - n * res / 2, 0, -res, lat + n * res / 2)
    lon, lat_g = geometry.lonlat_grid(transform, (n, n))
    extent = (lon.min(), lon.max(), lat_g.min(), lat_g.max())
    dem = truth_dem(lon, lat_g, extent, relief, fresh_per_square_degree=2.0 / res) + rng.normal(0, relief / 50, (n, n))
    dem[rng.random((n, n)) < 0.002] = np.nan  # holes: block nothing, get no answer
    sun = _sun(20.0, lat, incidence, azimuth)
    window = (30, n - 30, 30, n - 30)
    fast = cast_shadow_mask(dem, transform, sun, window)
    plain = cast_shadow_mask(dem, transform, sun, window, skip=False)
    assert 0 <= plain.mean() < 0.9
    if incidence >= 70:
        assert plain.mean() > 0.05  # the low-Sun cases really cast shadows
    assert np.array_equal(fast, plain), f"{np.count_nonzero(fast != plain)} pixels differ"


def test_sample_grid_coordinates_without_trig_equal_atan2_asin():
    """The march's lon/lat of each sample (series, no libm call) is the atan2/asin conversion within 1e-9 px,
    along rays of every azimuth, 0-60 degrees high, to MAX_REACH_KM, at 0-60 degrees of latitude."""
    from lunaralbedo.model.cast_shadows import MAX_REACH_KM
    from lunaralbedo.model.march import _sample_xy, _sample_xy_exact, _trig_tables

    rng = np.random.default_rng(3)
    worst = 0.0
    for lat in (0.0, -25.0, 45.0, 60.0):
        res = 0.002
        lon0, lat0, n = 20.0 - 2000 * res, lat + 2000 * res, 4000
        cos_lon, sin_lon, cos_lat, sin_lat = _trig_tables(lon0, res, n, lat0, -res, n)
        for _ in range(40):
            i, j = rng.integers(1500, 2500, 2)
            h = rng.uniform(-5000, 5000)
            r = MOON_RADIUS_KM + h / 1000.0
            p = r * np.array([cos_lat[i] * cos_lon[j], cos_lat[i] * sin_lon[j], sin_lat[i]])
            sun = _sun(lon0 + (j + 0.5) * res, lat0 - (i + 0.5) * res, rng.uniform(30, 90), rng.uniform(0, 360))
            l = (sun - p) / np.linalg.norm(sun - p)
            kx, ky = 1 / np.radians(res), -1 / np.radians(res)
            for s in np.r_[np.geomspace(0.01, MAX_REACH_KM, 60)]:
                q = p + s * l
                x, y = _sample_xy(q[0], q[1], q[2], cos_lon[j], sin_lon[j], cos_lat[i], sin_lat[i], i, j, kx, ky)
                xe, ye = _sample_xy_exact(q[0], q[1], q[2], lon0, res, lat0, -res, lon0 + res * n / 2)
                worst = max(worst, abs(x - xe), abs(y - ye))
    assert worst < 1e-9, worst


def test_a_hole_voids_the_slope_bound():
    """Gentle ground, then a NaN gap, then a 3 km plateau that ends in NaN: no finite neighbours are steep, but
    the plateau shadows the ground (the former global bound, ignoring the hole, called every pixel lit)."""
    from lunaralbedo.model.cast_shadows import slope_bound

    rng = np.random.default_rng(1)
    transform = Affine(0.01, 0, 0, 0, -0.01, 0.5)
    dem = rng.normal(0, 1.0, (50, 60))
    dem[:, 30] = np.nan
    dem[:, 31:35] = 3000.0
    dem[:, 35:] = np.nan
    assert slope_bound(dem, transform) == 0.0
    dem_no_hole = dem[:, :30]
    assert 0 < slope_bound(dem_no_hole, transform) < 100  # m/km: a Sun 40 degrees high would be above it
    sun = _sun(0.25, 0.25, 50.0, 90.0)  # 40 degrees high, from the east
    m = cast_shadow_mask(dem, transform, sun)
    ref = cast_shadow_mask(dem, transform, sun, skip=False, exact=True)
    assert np.array_equal(m, ref)
    assert m[:, 25:30].all() and not m[:, :15].any()  # a 3 km wall under a 40-degree Sun: ~3.6 km (12 px) of shadow


@pytest.mark.parametrize("lat, incidence, azimuth, distance_km, hole, most_left", [
    (0.0, 35.0, 90.0, 1.496e8, True, 0.7),     # the strip of make bench item 6: high Sun, a hole voids the global bound
    (75.0, 30.0, 180.0, 1.496e8, False, 1.0),  # high latitude: the blocks' verticals spread the most in longitude
    (-30.0, 87.0, 270.0, 1.496e8, True, 1.0),  # Sun 3 degrees high: long shadows, marched
    (10.0, 45.0, 0.0, 3000.0, True, 0.7),      # a light 3000 km away: its direction turns across a block
    (10.0, 30.0, 0.0, 3000.0, False, 0.1),     # ... answered by the global slope bound
])
def test_blocks_known_lit_give_the_answers_of_the_march(lat, incidence, azimuth, distance_km, hole, most_left):
    """The per-block test (blocks of 8 px whose every pixel the march would find lit before its first sample)
    changes no answer: the mask equals the march of every pixel, and that of every step of every ray; at a high
    Sun it answers a share of the pixels (the march runs for the rest only)."""
    from lunaralbedo.model.cast_shadows import MarchGrid

    rng = np.random.default_rng(11)
    n, res = 192, 0.002
    transform = Affine(res, 0, 20.0 - n * res / 2, 0, -res, lat + n * res / 2)
    lon, lat_g = geometry.lonlat_grid(transform, (n, n))
    dem = truth_dem(lon, lat_g, (lon.min(), lon.max(), lat_g.min(), lat_g.max()), 600.0, fresh_per_square_degree=0)
    dem += rng.normal(0, 2.0, (n, n))
    if hole:
        dem[90:97, 60:140] = np.nan
    sun = _sun(20.0, lat, incidence, azimuth)
    if distance_km < 1e8:  # that far from the ground, in that direction
        sun = sun / np.linalg.norm(sun) * distance_km + geometry.body_fixed(20.0, lat, 0.0)
    grid = MarchGrid(dem, transform)
    rows, cols = (a.ravel() for a in np.mgrid[20:n - 20, 20:n - 20])
    fast = grid.march(sun, rows, cols)
    each = grid.march(sun, rows, cols, cells=False)
    assert np.array_equal(fast, each), f"{np.count_nonzero(fast != each)} pixels differ"
    full = cast_shadow_mask(dem, transform, sun, (20, n - 20, 20, n - 20), skip=False, exact=True).ravel()
    assert np.array_equal(fast, full)
    flags, bi0, bj0, shift = grid._lit_flags(np.asarray(sun, float), rows, cols, 0)
    left = np.mean(flags[(rows >> shift) - bi0, (cols >> shift) - bj0] == 0)  # the share of pixels marched
    assert left <= most_left, left
    if incidence > 80:
        assert full.mean() > 0.2  # the low Sun casts shadows, and their pixels are marched


@pytest.mark.parametrize("lat, light_km", [(0.0, 1.496e8), (70.0, 1.496e8), (70.0, 40.0), (-45.0, 15.0)])
def test_sine_floor_bounds_the_sun_elevation_of_every_pixel_of_a_block(lat, light_km):
    """The lower bound of sin(elevation) that decides a block of 8 x 8 px (:func:`lunaralbedo.model.march.sine_floor`)
    is below every pixel's own value, as the march computes it, and close to the lowest of them; also for a light
    15-40 km above the ground, whose direction turns by degrees across a block, and at high latitude."""
    from lunaralbedo.model.march import _corner_angle, sine_floor

    rng = np.random.default_rng(int(light_km) % 97)
    res, cell = 0.01, 8
    lons, lats = 20.0 + res * (np.arange(cell) + 0.5), lat + res * (np.arange(cell) + 0.5)
    heights = rng.uniform(-2000.0, 2000.0, (cell, cell))
    lo, top = heights.min(), heights.max()
    lon_c, lat_c = np.radians(20.0 + res * cell / 2), np.radians(lat + res * cell / 2)
    theta = 1.01 * _corner_angle(lat_c, np.radians(res * (cell - 1) / 2), np.radians(res * (cell - 1) / 2)) + 1e-12
    u = np.array([np.cos(lat_c) * np.cos(lon_c), np.cos(lat_c) * np.sin(lon_c), np.sin(lat_c)])
    for _ in range(50):
        sun = _sun(20.0, lat, rng.uniform(0.0, 80.0), rng.uniform(0.0, 360.0))
        if light_km < 1e8:
            sun = sun / np.linalg.norm(sun) * light_km + geometry.body_fixed(20.0 + res * 4, lat + res * 4, 0.0)
        r = MOON_RADIUS_KM + heights / 1000.0
        lo_g, la_g = np.meshgrid(np.radians(lons), np.radians(lats))
        p = r[..., None] * np.stack([np.cos(la_g) * np.cos(lo_g), np.cos(la_g) * np.sin(lo_g), np.sin(la_g)], -1)
        l = sun - p
        l /= np.linalg.norm(l, axis=-1, keepdims=True)
        sin_e = np.einsum("...i,...i", p, l) / r
        d = (top - lo) / 1000.0 + (MOON_RADIUS_KM + top / 1000.0) * theta
        floor = sine_floor(*u, MOON_RADIUS_KM + lo / 1000.0, sun, theta, d)
        assert floor <= sin_e.min()
        # a bound, not a blanket no: within twice its own margins of the lowest pixel
        assert sin_e.min() - floor <= 2 * (theta + 2 * d / (np.linalg.norm(sun - p, axis=-1).min() - d)) + 1e-3


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (8, 8), (9, 17), (33, 20), (64, 65)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_block_extremes_equal_their_definition(shape, dtype):
    """The pyramid's finest level (highest height, largest neighbour differences, lowest height, per 8 x 8 block)
    equals its definition taken block by block with NumPy, NaN heights and ragged edges included."""
    from lunaralbedo.model.cast_shadows import CELL_PX, _blocks

    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    dem = rng.normal(0.0, 300.0, shape).astype(dtype)
    dem[rng.random(shape) < 0.05] = np.nan
    h, w = shape
    ni, nj = -(-h // CELL_PX), -(-w // CELL_PX)
    top, gx, gy, low = np.full((ni, nj), -np.inf), np.zeros((ni, nj)), np.zeros((ni, nj)), np.full((ni, nj), np.inf)
    d = dem.astype(np.float64)
    for bi in range(ni):
        for bj in range(nj):
            i0, j0 = bi * CELL_PX, bj * CELL_PX
            box = d[i0:min(i0 + CELL_PX, h - 1) + 1, j0:min(j0 + CELL_PX, w - 1) + 1]  # with the next row and column
            own = d[i0:i0 + CELL_PX, j0:j0 + CELL_PX]
            if np.isfinite(box).any():
                top[bi, bj] = np.nanmax(box)
            if np.isfinite(own).any():
                low[bi, bj] = np.nanmin(own)
            if np.isnan(box).any():
                gx[bi, bj] = gy[bi, bj] = np.inf
                continue
            gx[bi, bj] = np.abs(np.diff(box, axis=1)).max(initial=0.0)
            gy[bi, bj] = np.abs(np.diff(box, axis=0)).max(initial=0.0)
    got = _blocks(dem, CELL_PX)
    for name, a, b in zip(("top", "gx", "gy", "low"), got, (top, gx, gy, low)):
        assert np.array_equal(a, b), name


def test_the_march_skips_exactly_the_pixels_of_blocks_flagged_lit(monkeypatch):
    """The march takes the per-block flags as they are: given a checkerboard of 8 x 8 blocks flagged lit (whatever
    the terrain says), the pixels of flagged blocks come out lit and every other pixel gets its own march's answer."""
    from lunaralbedo.model.cast_shadows import CELL_PX, MarchGrid

    n, res = 160, 0.002
    transform = Affine(res, 0, 20.0 - n * res / 2, 0, -res, 5.0 + n * res / 2)
    lon, lat = geometry.lonlat_grid(transform, (n, n))
    dem = truth_dem(lon, lat, (lon.min(), lon.max(), lat.min(), lat.max()), 900.0, fresh_per_square_degree=0)
    grid = MarchGrid(dem, transform)
    sun = _sun(20.0, 5.0, 84.0, 250.0)  # a low Sun: long shadows
    rows, cols = (a.ravel() for a in np.mgrid[3:n - 5, 6:n - 2])
    each = grid.march(sun, rows, cols, cells=False)
    assert 0.1 < each.mean() < 0.9
    bi0, bj0 = 3 // CELL_PX, 6 // CELL_PX
    nb = n // CELL_PX + 1
    checker = ((np.arange(nb)[:, None] + np.arange(nb)[None, :]) % 2).astype(np.int8)
    monkeypatch.setattr(grid, "_lit_flags", lambda *a: (checker, bi0, bj0, 3))
    got = grid.march(sun, rows, cols)
    flagged = checker[(rows >> 3) - bi0, (cols >> 3) - bj0] == 1
    assert 0.4 < flagged.mean() < 0.6
    assert not got[flagged].any() and each[flagged].any()
    assert np.array_equal(got[~flagged], each[~flagged])
