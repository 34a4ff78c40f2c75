"""Pure math of lunaralbedo.model: reflectance (eq. 2), weights, updates (eqs. 3-7), exposure init."""
from __future__ import annotations

import platform

import numpy as np
import pytest

from lunaralbedo.model import exposure_init, geometry, photometry, updates, weights
from lunaralbedo.model.photometry import lunar_lambert

import oracles  # noqa: E402  (tests/oracles.py: the NumPy forms of the equations)


def test_lunar_lambert_weight_polynomial_in_degrees():
    assert lunar_lambert.weight(0.0) == pytest.approx(1.0)
    a = 60.0
    assert lunar_lambert.weight(a) == pytest.approx(1 - 0.019 * a + 0.000242 * a**2 - 0.00000146 * a**3)


def test_lunar_lambert_reflectance_matches_eq2_and_limits():
    ci, ce, al = 0.8, 0.9, np.radians(30.0)
    L = lunar_lambert.weight(30.0)
    expect = (np.exp(-1.4 * al) + 0.5) * ((1 - L) * ci + 2 * L * ci / (ci + ce))
    assert photometry.get(2).reflectance(ci, ce, al, (1.4, 0.5)) == pytest.approx(expect)
    # unlit / unseen pixels reflect nothing
    assert photometry.get("lunar-lambert").reflectance(-0.1, 0.9, al) == 0.0
    assert photometry.get(1).reflectance(0.7, 0.2, al, ()) == pytest.approx(0.7)
    assert photometry.get(0).reflectance(0.7, 0.2, al, ()) == pytest.approx(1.0)


def test_lunar_lambert_caches_the_bracket_rounded_once_to_float32():
    """The cached layer ``geometric`` is float32: the float64 bracket rounded once (no float64 array in between),
    zero where cos i or cos e is not positive; the phase angle is handed on as it came."""
    rng = np.random.default_rng(4)
    ci, ce, al = rng.uniform(-0.2, 1.0, 5000), rng.uniform(-0.2, 1.0, 5000), rng.uniform(0.0, 2.0, 5000)
    got = lunar_lambert.layers(ci, ce, al)
    assert got["geometric"].dtype == np.float32 and got["alpha"] is al
    full = lunar_lambert.geometric(ci, ce, al)
    assert full.dtype == np.float64 and np.array_equal(got["geometric"], full.astype(np.float32))
    assert np.all(got["geometric"][(ci <= 0) | (ce <= 0)] == 0) and np.count_nonzero(got["geometric"]) > 2500
    # eq. 2 in float64 (the forward model renders with it) takes the bracket as computed, not as cached
    r = lunar_lambert.reflectance(ci, ce, al)
    assert r.dtype == np.float64
    assert np.array_equal(r, lunar_lambert.reflectance_from({"geometric": full, "alpha": al}, (1.4, 0.5)))
    assert not np.array_equal(r, lunar_lambert.reflectance_from(got, (1.4, 0.5)))


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="checks x86 packed instructions")
def test_the_bracket_loop_is_vectorised():
    """The prepare step's bracket loop has no Python zero-division check (its divisor cos i + cos e is > 0 where it
    divides): with the check, compiled into the inlined bracket, LLVM kept the loop scalar (2-4 ns per observation
    instead of 1).  A fresh compile with the functions' own options (numba cannot show cached code)."""
    import re

    from numba import njit

    for f in (lunar_lambert._bracket_nb, lunar_lambert._polynomial_nb, lunar_lambert._geometric_over):
        assert f.targetoptions.get("error_model") == "numpy", f
    fresh = njit(**{k: v for k, v in lunar_lambert._geometric_over.targetoptions.items() if k != "nopython"})(
        lunar_lambert._geometric_over.py_func)
    x = np.linspace(0.1, 1.0, 64)
    fresh(x, x, x, np.empty(64, np.float32))
    assert "division by zero" not in fresh.inspect_llvm(fresh.signatures[0])
    assert re.search(r"\bvdivpd\s[^\n]*%[yz]mm", fresh.inspect_asm(fresh.signatures[0]))  # 4 or 8 at a time


def test_phase_derivatives_match_finite_differences():
    """dR/dc1, dR/dc2 of eq. 2 with the bracket G = 1 are the phase factor's derivatives."""
    al = np.radians(np.array([10.0, 40.0, 80.0]))
    d1, d2 = lunar_lambert.derivatives_from({"alpha": al, "geometric": np.ones_like(al)}, (1.4, 0.5))
    h = 1e-6
    fd1 = (lunar_lambert.phase_factor(al, 1.4 + h, 0.5) - lunar_lambert.phase_factor(al, 1.4 - h, 0.5)) / (2 * h)
    fd2 = (lunar_lambert.phase_factor(al, 1.4, 0.5 + h) - lunar_lambert.phase_factor(al, 1.4, 0.5 - h)) / (2 * h)
    np.testing.assert_allclose(d1, fd1, rtol=1e-6)
    np.testing.assert_allclose(d2, fd2, rtol=1e-6)


def test_normals_of_a_sphere_are_radial_and_flat_sun_gives_incidence():
    from rasterio.transform import Affine

    t = Affine(0.01, 0, 30.0, 0, -0.01, 60.0)  # high latitude: 3-D normals must still be radial
    lon, lat = geometry.lonlat_grid(t, (20, 20))
    pts = geometry.body_fixed(lon, lat, np.zeros((20, 20)))
    n = geometry.dem_normals(pts)
    radial = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    assert np.max(np.abs(np.sum(n * radial, axis=-1) - 1)) < 1e-7  # < 0.03 degrees off radial
    sun = radial[10, 10] * 1.5e8
    ci, ce, al = geometry.illumination(pts, n, sun, radial[10, 10] * 1837.4)
    assert ci[10, 10] == pytest.approx(1.0, abs=1e-6) and al[10, 10] == pytest.approx(0.0, abs=1e-3)
    lo, la, h = geometry.lonlat_height(pts)
    np.testing.assert_allclose(lo, lon, atol=1e-9)
    np.testing.assert_allclose(h, 0, atol=1e-6)


def test_mask_profiles_are_each_rows_and_columns_first_and_last_valid_pixel():
    """profile_from_mask (one pass, numba) against the definition written with NumPy's argmax, on random masks
    with empty rows and columns, an empty mask and a full one."""
    def reference(valid):
        h, w = valid.shape
        any_r, any_c = valid.any(axis=1), valid.any(axis=0)
        return (np.where(any_r, valid.argmax(axis=1), w), np.where(any_r, w - 1 - valid[:, ::-1].argmax(axis=1), -1),
                np.where(any_c, valid.argmax(axis=0), h), np.where(any_c, h - 1 - valid[::-1, :].argmax(axis=0), -1))

    rng = np.random.default_rng(3)
    masks = [rng.random((37, 53)) < p for p in (0.02, 0.3, 0.97)] + [np.zeros((5, 7), bool), np.ones((6, 4), bool)]
    masks[1][:, 10:14] = False  # empty columns
    masks[1][20:22] = False  # empty rows
    for mask in masks:
        got = weights.profile_from_mask(mask)
        for a, b in zip((got.row_first, got.row_last, got.col_first, got.col_last), reference(mask)):
            assert a.dtype == np.int32 and np.array_equal(a, b)


def test_tent_weights_are_one_at_centre_zero_at_boundary_and_follow_the_mask():
    mask = np.zeros((9, 11), bool)
    mask[1:8, 2:11] = True
    prof = weights.profile_from_mask(mask)
    w = weights.window_weights(prof, 0, 0, 9, 11)
    assert w[4, 6] == pytest.approx(1.0)  # centre of rows 1..7 and cols 2..10
    assert w[4, 2] == 0 and w[4, 10] == 0 and w[1, 6] == 0 and w[7, 6] == 0
    assert np.all(w[~mask] == 0)
    # strips merge into the same profile
    parts = [(0, weights.profile_from_mask(mask[:4])), (4, weights.profile_from_mask(mask[4:]))]
    merged = weights.merge_profiles(parts, 9, 11)
    np.testing.assert_array_equal(weights.window_weights(merged, 0, 0, 9, 11), w)
    # a window reads the same numbers as the full image
    np.testing.assert_array_equal(weights.window_weights(prof, 3, 4, 4, 5), w[3:7, 4:9])


def test_source_weights_are_the_tents_product_bit_for_bit_at_edges_and_zero_widths():
    """The per-pixel blending weight is eq. 1's row tent times column tent of ``tent_about`` (the one
    implementation), rounded once to float32, 0 where not valid: the same bits for ragged profiles,
    rows and columns of zero half-width, and a window that hangs over the image (the edge profiles)."""
    rng = np.random.default_rng(5)
    h, w = 300, 90
    rf = rng.integers(0, 15, h).astype(np.int32)
    rl = (w - 1 - rng.integers(0, 15, h)).astype(np.int32)
    cf = rng.integers(0, 40, w).astype(np.int32)
    cl = (h - 1 - rng.integers(0, 40, w)).astype(np.int32)
    rf[17] = rl[17] = 30  # a row of zero half-width
    cf[11] = cl[11] = 150  # a column of zero half-width
    prof = weights.WeightProfile(rf, rl, cf, cl)
    r0, c0, wh, ww = -5, -7, 320, 110  # beyond every edge
    valid = rng.random((wh, ww)) > 0.2
    got = weights.source_weights(prof, r0, c0, valid)
    rows = np.arange(r0, r0 + wh)[:, None]
    cols = np.arange(c0, c0 + ww)[None, :]
    rc, cc = np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)
    row_tent = weights.tent(cols.astype(float), rf[rc], rl[rc])
    col_tent = weights.tent(rows.astype(float), cf[cc], cl[cc])
    want = np.where(valid, (row_tent * col_tent).astype(np.float32), np.float32(0))
    assert got.dtype == np.float32 and 0.3 < (got > 0).mean() < 0.9
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32))


def _stack(seed=0, k=3, shape=(6, 7)):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.5, 1.5, shape)
    t = rng.uniform(0.6, 1.4, k)
    r = rng.uniform(0.3, 1.0, (k, *shape))
    w = rng.uniform(0.1, 1.0, (k, *shape)).astype(np.float32)
    return a, t, r.astype(np.float32), w


def test_albedo_eq3_is_exact_for_noise_free_data_and_eq6_lands_on_it():
    a, t, r, w = _stack()
    img = (a[None] * t[:, None, None] * r).astype(np.float32)
    tr = (t[:, None, None] * r).astype(np.float32)
    est = oracles.albedo(img, tr, w)
    np.testing.assert_allclose(est, a, rtol=1e-5)
    # eq. 6 from an arbitrary start gives eq. 3 (Q is quadratic in A)
    a0 = np.full_like(a, 3.0)
    res = img - a0[None] * tr
    eq6 = a0 + np.sum(res * tr * w, 0) / np.sum(tr * tr * w, 0)
    np.testing.assert_allclose(eq6, est, rtol=1e-5)


def test_exposure_update_eq4_recovers_exposure_given_true_albedo():
    a, t, r, w = _stack(1)
    img = (a[None] * t[:, None, None] * r).astype(np.float32)
    num, den = oracles.exposure_sums(img, a.astype(np.float32), r, w)
    np.testing.assert_allclose(updates.exposure_update(np.ones(3), num, den), t, rtol=1e-5)
    # images without data keep their exposure
    assert updates.exposure_update(np.array([2.0]), np.array([0.0]), np.array([0.0]))[0] == 2.0


def test_cost_and_error_are_zero_for_a_perfect_model_and_positive_otherwise():
    a, t, r, w = _stack(2)
    tr = (t[:, None, None] * r).astype(np.float32)
    img = (a[None] * tr).astype(np.float32)
    res = oracles.residuals(img, a.astype(np.float32), tr, w)
    assert oracles.cost(res, w) == pytest.approx(0.0, abs=1e-8)
    e = oracles.error_map(img, a.astype(np.float32), tr, w, w)
    assert np.nanmax(e) < 1e-10
    noisy = img * np.float32(1.1)
    assert oracles.cost(oracles.residuals(noisy, a.astype(np.float32), tr, w), w) > 0


def test_phase_steps_seed_and_damped():
    rng = np.random.default_rng(4)
    k, shape = 4, (10, 10)
    al = rng.uniform(0.3, 1.2, (k, *shape)).astype(np.float32)
    g = rng.uniform(0.4, 0.9, (k, *shape)).astype(np.float32)
    a = rng.uniform(0.5, 1.5, shape).astype(np.float32)
    t = np.ones(k)
    w = np.ones((k, *shape), np.float32)
    true_c = (1.2, 0.45)
    img = a[None] * (np.exp(-true_c[0] * al) + true_c[1]) * g
    c = np.array([1.4, 0.5])
    p = (np.exp(-c[0] * al) + c[1]).astype(np.float32)
    res = oracles.residuals(img, a, (t[:, None, None] * p * g).astype(np.float32), w)
    dr = lunar_lambert.derivatives_from({"alpha": al, "geometric": g}, c)
    jtj, jtr = updates.phase_sums(res, a, t, dr, (p * g).astype(np.float32), w)
    seed = updates.phase_update_seed(c, jtj, jtr)
    # eq. 5 written out: c_l + sum(r * A T dR/dc_l w) / sum((A T dR/dc_l)^2 w)
    j1 = a[None] * dr[0]
    j2 = a[None] * g
    assert seed[0] == pytest.approx(c[0] + np.sum(res * j1) / np.sum(j1 * j1), rel=1e-5)
    assert seed[1] == pytest.approx(c[1] + np.sum(res * j2) / np.sum(j2 * j2), rel=1e-5)
    damped = updates.phase_update_damped(c, jtj, jtr, (0.3, 1.2), lunar_lambert.MODEL.phase_curve, max_rel_change=0.02)
    al_grid = np.linspace(0.3, 1.2, 9)
    change = (np.exp(-damped[0] * al_grid) + damped[1]) / (np.exp(-c[0] * al_grid) + c[1]) - 1
    assert np.max(np.abs(change)) <= 0.02 + 1e-9  # the step is capped
    assert np.any(damped != c)


def _log_ratio_sums(image, r, usable, index):
    """``exposure_init.pair_sums`` of image stacks ``(K, H, W)``: the stacks reduced to compact observations."""
    parts = [np.flatnonzero(u) for u in usable]
    pix = np.concatenate(parts)
    start = np.concatenate([[0], np.cumsum([len(p) for p in parts])])
    flat = usable.reshape(len(usable), -1)
    return exposure_init.pair_sums(pix, start, image.reshape(flat.shape)[flat], r.reshape(flat.shape)[flat], index)


def test_overlap_exposure_recovers_exposures_from_log_ratios():
    rng = np.random.default_rng(5)
    t_true = np.array([1.4, 0.7, 1.0, 1.2, 0.6])
    shape = (30, 30)
    a = rng.uniform(0.5, 1.5, shape)
    r = rng.uniform(0.4, 1.0, (5, *shape))
    img = a[None] * t_true[:, None, None] * r
    usable = np.zeros((5, *shape), bool)
    for k in range(5):  # a strip: image k overlaps k+1
        usable[k, :, 5 * k : 5 * k + 10] = True
    pairs = _log_ratio_sums(img, r, usable, np.arange(5))
    assert set(pairs) == {(0, 1), (1, 2), (2, 3), (3, 4)}
    t0 = np.ones(5)
    t = exposure_init.overlap_exposure(pairs, np.log(t0))
    ratio = t / t_true
    np.testing.assert_allclose(ratio / ratio.mean(), 1.0, rtol=1e-6)
    assert np.mean(np.log(t)) == pytest.approx(0.0, abs=1e-12)  # scale pinned to the seed's


def test_seed_exposure_is_tr_const_over_mean_reflectance():
    t = exposure_init.seed_exposure(1.5, np.array([10.0, 0.0]), np.array([20.0, 0.0]))
    np.testing.assert_allclose(t, [3.0, 1.5])


def test_legacy_numerics_are_options_of_the_same_formulas():
    """Backward-difference normals, the float32 tent and the float32 seed exposure agree with the defaults."""
    from rasterio.transform import Affine

    t = Affine(0.01, 0, 30.0, 0, -0.01, 60.0)
    lon, lat = geometry.lonlat_grid(t, (12, 15))
    heights = 300.0 * np.sin(np.radians(lon) * 40) * np.cos(np.radians(lat) * 30)
    km = geometry.body_fixed(lon, lat, heights)
    m = geometry.body_fixed(lon, lat, heights, unit="m")
    np.testing.assert_allclose(m / 1000.0, km, rtol=1e-14)
    central, backward = geometry.dem_normals(km), geometry.dem_normals(m, differences="backward")
    assert np.isnan(backward[0]).all() and np.isnan(backward[:, 0]).all()  # no upper/left neighbour
    cosang = np.sum(central[1:-1, 1:-1] * backward[1:-1, 1:-1], axis=-1)
    assert cosang.min() > np.cos(np.radians(1.0))  # half a pixel apart on a smooth DEM: < 1 degree
    with pytest.raises(ValueError):
        geometry.dem_normals(km, differences="forward")
    x = np.linspace(-2.0, 12.0, 57)
    w64 = weights.tent_about(x, 5.0, 4.0)
    w32 = weights.tent_about(x, 5.0, 4.0, dtype=np.float32)
    assert w32.dtype == np.float32 and w64[np.argmin(np.abs(x - 5.0))] == 1.0
    np.testing.assert_allclose(w32, w64, atol=1e-6)
    assert np.all(weights.tent_about(x, 5.0, 0.0, dtype=np.float32) == 0)  # zero extent: no weight
    t32 = exposure_init.seed_exposure(1.5, np.array([7.0]), np.array([3]), dtype=np.float32)
    assert t32.dtype == np.float32 and t32[0] == np.float32(np.float32(1.5) / np.float32(7.0 / 3))


def test_one_tile_naming_and_grid_rule_with_the_legacy_spelling_as_an_option():
    from lunaralbedo.engine.tiles import make_tiles, tile_name, tile_starts

    assert tile_name(4.0, -8.0) == tile_name(4.0, -8.0, legacy=True) == "tile_4E8S"
    assert tile_name(4.5, -8.0) == "tile_4p5E8S" and tile_name(4.5, -8.0, legacy=True) == "tile_4.5E8S"
    assert tile_name(-0.25, 0.0, legacy=True) == "tile_0.25W0N"
    assert tile_starts(-1.0, 9.0, 4.0) == tile_starts(-1.0, 9.0, 4.0, legacy=True) == [-4.0, 0.0, 4.0, 8.0]
    assert tile_starts(0.0, 8.0, 4.0) == [0.0, 4.0] and tile_starts(0.0, 8.0, 4.0, legacy=True) == [0.0, 4.0]
    tiles = make_tiles((0.0, 8.0, -8.0, 0.0), 4.0, (0.5, 0.5))
    assert [t.name for t in tiles] == ["tile_0E0N", "tile_4E0N", "tile_0E4S", "tile_4E4S"]
