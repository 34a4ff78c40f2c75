"""The prepare step's kernels against the NumPy formulas they replace (issue 15).

Geometry (points, normals, cos i, cos e, phase angle), the pair sums of the overlap
exposure initialisation, the direct copy of DRGs on the tile grid and the cast-shadow
march on pixel lists each give the numbers of the reference implementation.
"""
from __future__ import annotations

import numpy as np
import pytest
from rasterio.transform import Affine

from lunaralbedo.constants import MOON_RADIUS_KM
from lunaralbedo.model import exposure_init, geometry


def _dem(rng, h, w):
    dem = rng.normal(0, 300, (h, w)).astype(np.float32)
    dem[3, 4] = np.nan  # no DEM here: height 0 for the neighbours' normals, no observation itself
    return dem


def test_surface_block_gives_the_bytes_of_body_fixed_and_dem_normals():
    rng = np.random.default_rng(1)
    tr = Affine(0.002, 0, 8.0, 0, -0.002, -4.0)
    dem = _dem(rng, 41, 57)
    lon, lat = geometry.lonlat_axes(tr, dem.shape)
    lr, br = np.radians(lon), np.radians(lat)
    pts, nrm = geometry.surface_block(np.cos(lr), np.sin(lr), np.cos(br), np.sin(br), dem, MOON_RADIUS_KM)
    assert pts.shape == (3, 41, 57) and nrm.shape == (3, 39, 55)  # x, y, z planes
    ref = geometry.body_fixed(*geometry.lonlat_grid(tr, dem.shape), np.nan_to_num(dem, nan=0.0))
    assert np.array_equal(np.moveaxis(pts, 0, -1), ref)
    assert np.array_equal(np.moveaxis(nrm, 0, -1), geometry.dem_normals(ref)[1:-1, 1:-1])


def _illumination_numpy(p, n, sun, sc):
    """The former NumPy formula of Nefian et al. (LPSC), eqs. 4-5 (unit vectors, dot products, arccos)."""
    l = np.asarray(sun) - p
    l = l / np.sqrt(np.einsum("...i,...i->...", l, l))[..., None]
    v = np.asarray(sc) - p
    v = v / np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]
    dot = lambda a, b: np.einsum("...i,...i->...", a, b)  # noqa: E731
    return dot(n, l), dot(n, v), np.arccos(np.clip(dot(l, v), -1, 1))


def test_illumination_kernel_equals_the_numpy_formula():
    rng = np.random.default_rng(2)
    tr = Affine(0.01, 0, 20.0, 0, -0.01, 5.0)
    dem = _dem(rng, 30, 30)
    pts = geometry.body_fixed(*geometry.lonlat_grid(tr, dem.shape), np.nan_to_num(dem))
    nrm = geometry.dem_normals(pts)
    sun = geometry.body_fixed(60.0, 10.0, 0.0) * 1e5
    sc = geometry.body_fixed(20.2, 4.7, 100e3)
    got = geometry.illumination(pts, nrm, sun, sc)
    want = _illumination_numpy(pts, nrm, sun, sc)
    for g, w in zip(got, want):
        assert g.shape == dem.shape
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-14)
    assert 0.2 < np.mean(got[0]) < 0.9 and np.all(got[2] > 0)  # a real geometry, not zeros


def test_observe_window_selects_what_the_masks_select():
    """From the heights alone, the candidates and the bytes of cos i, cos e and alpha at surface_block's points and
    normals (with a NaN height inside the window, which its neighbours' normals count as 0)."""
    rng = np.random.default_rng(3)
    tr = Affine(0.01, 0, 20.0, 0, -0.01, 5.0)
    dem = _dem(rng, 32, 40) * 8  # steep: some pixels face away from the Sun
    dem[9, 12] = np.nan  # inside the window: no observation there, height 0 for its neighbours' normals
    lon, lat = geometry.lonlat_axes(tr, dem.shape)
    lr, br = np.radians(lon), np.radians(lat)
    trig = (np.cos(lr), np.sin(lr), np.cos(br), np.sin(br))
    pts, nrm = geometry.surface_block(*trig, dem, MOON_RADIUS_KM)
    inner = dem[1:-1, 1:-1]
    sun = geometry.body_fixed(20.2 + 60, 4.8, 0.0) * 1e5  # low Sun from the east
    sc = geometry.body_fixed(20.2, 4.8, 100e3)
    use = rng.random((10, 12)) > 0.2  # a window at block row 5, column 7
    rows, cols, ci, ce, al = geometry.observe_window(use, dem, *trig, MOON_RADIUS_KM, 5, 7, sun, sc, 0.087)
    p, n = np.moveaxis(pts[:, 6:16, 8:20], 0, -1), np.moveaxis(nrm[:, 5:15, 7:19], 0, -1)
    wci, wce, wal = geometry.illumination(p, n, sun, sc)
    mask = use & np.isfinite(inner[5:15, 7:19]) & (wci >= 0.087) & (wce > 0)
    assert 0 < mask.sum() < use.sum()
    r, c = np.nonzero(mask)
    assert np.array_equal(rows, r) and np.array_equal(cols, c)
    assert np.array_equal(ci, wci[mask]) and np.array_equal(ce, wce[mask]) and np.array_equal(al, wal[mask])


def test_pair_sums_equal_a_pixel_by_pixel_count():
    rng = np.random.default_rng(4)
    width, k = 60, 5
    pix, image, r, start = [], [], [], [0]
    for a in range(k):  # image a covers columns 8a .. 8a+19 of 30 rows, with holes (and image 2 rows 10-14 not at all)
        rows, cols = np.mgrid[0:30, 8 * a:8 * a + 20]
        p = (rows * width + cols).ravel()
        p = p[(rng.random(p.size) > 0.1) & ((a != 2) | (rows.ravel() < 10) | (rows.ravel() > 14))]
        pix.append(p)
        image.append(rng.uniform(10, 200, p.size).astype(np.float32))
        r.append(rng.uniform(0.1, 1.0, p.size).astype(np.float32))
        start.append(start[-1] + p.size)
    index = np.array([7, 3, 9, 1, 4])
    got = exposure_init.pair_sums(np.concatenate(pix), np.array(start), np.concatenate(image), np.concatenate(r),
                                  index, width)
    logq = [(np.log(i) - np.log(x)).astype(np.float32) for i, x in zip(image, r)]
    want = {}
    for a in range(k):
        for b in range(a + 1, k):
            da = dict(zip(pix[a].tolist(), logq[a]))
            common = [(da[p], q) for p, q in zip(pix[b].tolist(), logq[b]) if p in da]
            if common:
                d = float(np.sum([np.float32(x - y) for x, y in common], dtype=np.float64))
                j, i = int(index[a]), int(index[b])
                want[(min(j, i), max(j, i))] = (len(common), d if j < i else -d)
    assert got.keys() == want.keys() and len(want) == 7  # neighbours and next-but-one neighbours overlap
    for key in want:
        assert got[key][0] == want[key][0]
        assert got[key][1] == pytest.approx(want[key][1], rel=1e-12, abs=1e-9)
    assert exposure_init.pair_sums(np.concatenate(pix), np.array(start), np.concatenate(image), np.concatenate(r),
                                   index) == got  # without the column test: the same


def test_aligned_drg_is_copied_with_the_warper_values(tmp_path, monkeypatch):
    """A DRG on the tile grid: the direct copy gives GDAL's bilinear values; only weight-zero edges differ."""
    from lunaralbedo.io import drgs, rasters
    from lunaralbedo.io.geotiff import write_geotiff
    from lunaralbedo.model.weights import WeightProfile

    rng = np.random.default_rng(5)
    h, w = 40, 30
    dn = rng.integers(1, 255, (h, w)).astype(np.uint8)
    alpha = np.full((h, w), 255, np.uint8)
    alpha[:, :2] = 0  # an invalid margin, as orthoprojected DRGs have
    tr = Affine(0.002, 0, 10.0 + 3 * 0.002, 0, -0.002, -1.0 - 5 * 0.002)
    path = tmp_path / "A_drg.tif"
    write_geotiff(path, np.stack([dn, alpha]), tr, rasters.MOON_CRS)
    info = rasters.raster_info(path)
    profile = WeightProfile.full(h, w)
    dst = Affine(0.002, 0, 10.0, 0, -0.002, -1.0)  # the tile grid: the DRG starts at column 3, row 5
    got = drgs.read_drg_onto_grid(info, profile, dst, (60, 50), rasters.MOON_CRS, 10.0)
    assert rasters.aligned_offset(info.transform, dst, (60, 50)) == (-5, -3)
    monkeypatch.setattr(rasters, "ALIGNED_TOLERANCE_PX", -1.0)  # force GDAL's warper
    ref = drgs.read_drg_onto_grid(info, profile, dst, (60, 50), rasters.MOON_CRS, 10.0)
    assert np.array_equal(got[1], ref[1]) and np.array_equal(got[3], ref[3])  # valid, lit
    assert np.array_equal(got[0], ref[0])  # values
    np.testing.assert_allclose(got[2], ref[2], rtol=1e-6, atol=1e-9)  # weights
    assert got[1][5:45, 5:33].all() and not got[1][5:45, 3:5].any() and not got[1][:5].any()


def test_pixels_on_grid_are_the_only_ones_the_reader_makes_valid(tmp_path):
    """The box a DRG on the tile grid covers is exact: the reader gives no valid pixel outside it, and reading just
    the box gives the same bands as reading the padded window; off the grid (warped) there is no such box."""
    from lunaralbedo.io import drgs, rasters
    from lunaralbedo.io.geotiff import write_geotiff
    from lunaralbedo.model.weights import WeightProfile

    rng = np.random.default_rng(6)
    h, w = 40, 30
    dn = rng.integers(1, 255, (h, w)).astype(np.uint8)
    tr = Affine(0.002, 0, 10.0 + 3 * 0.002, 0, -0.002, -1.0 - 5 * 0.002)
    path = tmp_path / "B_drg.tif"
    write_geotiff(path, np.stack([dn, np.full((h, w), 255, np.uint8)]), tr, rasters.MOON_CRS)
    info, profile = rasters.raster_info(path), WeightProfile.full(h, w)
    dst = Affine(0.002, 0, 10.0, 0, -0.002, -1.0)
    assert drgs.pixels_on_grid(info, dst, (60, 50), rasters.MOON_CRS) == (5, 45, 3, 33)
    assert drgs.pixels_on_grid(info, dst, (20, 20), rasters.MOON_CRS) == (5, 20, 3, 20)  # cut by the grid too
    padded = drgs.read_drg_onto_grid(info, profile, dst, (60, 50), rasters.MOON_CRS, 10.0)
    assert padded[1][5:45, 3:33].all() and padded[1].sum() == h * w  # valid exactly inside the box
    box = drgs.read_drg_onto_grid(info, profile, dst * Affine.translation(3, 5), (40, 30), rasters.MOON_CRS, 10.0)
    for a, b in zip(box, padded):
        assert np.array_equal(a, b[5:45, 3:33])
    half = Affine(0.002, 0, 10.0 + 0.001, 0, -0.002, -1.0)  # half a pixel off: warped, may reach a pixel more
    assert drgs.pixels_on_grid(info, half, (60, 50), rasters.MOON_CRS) is None


@pytest.mark.parametrize("sun_deg, lat, nan", [((80.0, 4.7), 5.0, True), ((20.3, -60.0), 5.0, True),
                                               ((40.0, 30.0), 5.0, True), ((80.0, 4.7), 5.0, False),
                                               ((70.0, 15.0), 55.0, False), ((-70.0, -10.0), -40.0, True)])
def test_pixel_march_and_skipping_march_equal_the_full_march(sun_deg, lat, nan):
    """Low Suns from the east, south and west, higher ones, rough terrain, at 5-55 degrees of latitude, with and
    without a hole (the global slope bound applies only without): the same mask as every step of every ray with
    each sample's lon/lat from atan2/asin."""
    from lunaralbedo.model.cast_shadows import MarchGrid, _skip_steps, cast_shadow_mask

    rng = np.random.default_rng(6)
    tr = Affine(0.01, 0, 20.0, 0, -0.01, lat)
    dem = (rng.normal(0, 1, (150, 150)).cumsum(0).cumsum(1) * 20).astype(np.float64)
    if nan:
        dem[40:44, 50:53] = np.nan
    sun = geometry.body_fixed(20.7 + sun_deg[0], lat - 0.7 + sun_deg[1], 0.0) * 1e5
    win = (10, 140, 10, 140)
    full = cast_shadow_mask(dem, tr, sun, win, skip=False, exact=True)
    assert 0.02 < full.mean() < 0.95
    assert np.array_equal(cast_shadow_mask(dem, tr, sun, win, skip=False), full)  # the series lon/lat
    assert np.array_equal(cast_shadow_mask(dem, tr, sun, win), full)
    rows, cols = np.mgrid[10:140, 10:140]
    assert np.array_equal(MarchGrid(dem, tr).march(sun, rows.ravel(), cols.ravel()), full.ravel())  # pixel by pixel
    d32 = dem.astype(np.float32)  # the solver marches float32 heights: the answers of their float64 values
    assert np.array_equal(MarchGrid(d32, tr).march(sun, rows.ravel(), cols.ravel()),
                          cast_shadow_mask(d32.astype(np.float64), tr, sun, win, skip=False, exact=True).ravel())
    grid = MarchGrid(dem, tr)
    assert (grid.slope > 0) == (not nan)  # a hole voids the global bound; the pyramid's cells away from it keep theirs
    assert list(grid.pyramid()[4]) == [3, 6]  # cells of 8 and 64 px
    skips = grid.pyramid()[5]  # the march does skip: 7 and 63 px of the narrower (longitude) pixels
    assert skips[0] == _skip_steps(tr, dem.shape, grid.step_km, 8) >= 5 and skips[1] >= 60


@pytest.mark.parametrize("dtype, alpha, nodata, lut, thresh, saturation", [
    (np.uint8, True, None, False, 10.0, 255.0),     # a DRG of ingest: DN, alpha, shadow type 1, saturation
    (np.float32, False, -3.0, False, 0.7, None),    # float DN with nodata and NaN/inf; 0.7 is not a float32
    (np.uint8, True, None, True, 12.0, 255.0),      # the camera response applied to the DN (Kim et al.)
    (np.int16, False, 0.0, True, None, None),       # neither test: no usable mask
])
def test_window_pixels_equal_the_numpy_steps(dtype, alpha, nodata, lut, thresh, saturation):
    """One pass over a DRG window gives the value, valid and usable arrays of the former NumPy steps, bit for bit."""
    from lunaralbedo.model import shadows

    rng = np.random.default_rng(9)
    h, w = 37, 53
    dn = rng.integers(0, 256, (h, w)).astype(dtype) if dtype != np.float32 else \
        rng.uniform(-5, 300, (h, w)).astype(np.float32)
    if dtype == np.float32:
        dn[rng.random((h, w)) < 0.05] = np.nan
        dn[0, :3] = [np.inf, -np.inf, np.float32(0.7)]
        dn[1, :2] = -3.0
    a = (rng.random((h, w)) > 0.1).astype(dtype) * 255 if alpha else None
    table = np.linspace(0.0, 3.0, 256).astype(np.float32) if lut else None
    if lut:
        table[:5] = np.nan  # undefined below DN 5
    value, valid, usable = shadows.window_pixels(dn, a, nodata, table, thresh, saturation)
    # the former steps (io/drgs.py before the fused kernel)
    v = dn.astype(np.float32)
    ok = np.isfinite(v)
    if nodata is not None:
        ok &= v != np.float32(nodata)
    if alpha:
        ok &= a > 0
    x = v
    if lut:
        x = table[np.clip(np.nan_to_num(v), 0, len(table) - 1).astype(np.intp)]
        ok &= np.isfinite(x)
    good = ok.copy()
    with np.errstate(invalid="ignore"):
        if thresh is not None:
            good &= shadows.static_lit(v, shadows.THRESHOLD, thresh)
        if saturation is not None:
            good &= v < saturation
    x = np.where(ok, x, np.float32(0.0))
    assert np.array_equal(valid, ok) and 0 < valid.sum() < valid.size
    assert np.array_equal(value.view(np.uint32), x.astype(np.float32).view(np.uint32))
    if thresh is None and saturation is None:
        assert usable is None
    else:
        assert np.array_equal(usable, good) and 0 < good.sum() < ok.sum()


def test_compact_keeps_the_candidates_it_is_told_to():
    """The window's candidates that the cast-shadow test keeps, with their block pixel numbers, values and weights;
    when it keeps all of them (no shadow in the window) their arrays are passed on as they are, not copied."""
    from lunaralbedo.engine.observations import _compact

    rng = np.random.default_rng(5)
    val, wb = rng.uniform(1, 200, (6, 9)).astype(np.float32), rng.uniform(0, 1, (6, 9)).astype(np.float32)
    rows, cols = (a.ravel().astype(np.int64) for a in np.nonzero(rng.random((6, 9)) > 0.3))
    ci, ce, al = (rng.random(rows.size) for _ in range(3))
    for keep in (np.ones(rows.size, bool), np.zeros(0, bool), rng.random(rows.size) > 0.4):
        got = _compact(rows, cols, keep, val, wb, ci, ce, al, 2, 3, 20)
        sel = keep if keep.size else np.ones(rows.size, bool)
        r, c = rows[sel], cols[sel]
        assert np.array_equal(got[0], r) and np.array_equal(got[1], c)
        assert np.array_equal(got[2], ((r + 2) * 20 + c + 3).astype(np.int32)) and got[2].dtype == np.int32
        assert np.array_equal(got[3], val[r, c]) and np.array_equal(got[4], wb[r, c])
        assert all(np.array_equal(g, a[sel]) for g, a in zip(got[5:], (ci, ce, al)))
        assert (got[5] is ci) == bool(sel.all())  # all kept: the same arrays, no copy
