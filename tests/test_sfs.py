"""Shape from shading (REFINE_DEM 1): the cost's gradient, and the true heights recovered from a blurred DEM."""
from __future__ import annotations

import glob
import json

import numpy as np
import pytest
import rasterio
from rasterio.merge import merge

from lunaralbedo.engine import refine
from lunaralbedo.errors import ResumeError
from lunaralbedo.engine.solve import solve
from lunaralbedo.model import geometry, photometry
from lunaralbedo.model.sfs import Cost, height_uncertainty, lbfgs
from lunaralbedo.model.sfs.fidelity import Fidelity
from lunaralbedo.model.sfs.shading import Shading, interior_normals, observation, unit_up
from lunaralbedo.model.sfs.smoothness import Smoothness, laplacian
from lunaralbedo.simulate import SceneSpec, forward, render_scene, score

#: A small strip: each column seen by about 3 images, Sun azimuths spread +-40 degrees, fresh craters,
#: the DEM given blurred by 2 pixels (sigma), 6 tiles.
SMALL = dict(n_images=5, overlap=2 / 3, image_px=48, res_deg=0.0125, sun_azimuths=(50.0, 90.0, 130.0, 70.0, 110.0),
             fresh_craters=60.0, dem_relief_m=300.0, tile_size=0.5, seed=3, dem_blur_px=2.0, max_num_iter=10)
REFINE = ["REFINE_DEM 1", "REFINE_DEM_INPUT_BLUR 2", "REFINE_DEM_MARGIN 8"]


def _settings(scene, lines, name="settings_sfs.txt"):
    keys = {ln.split()[0] for ln in lines}
    text = [ln for ln in (scene / "settings.txt").read_text().splitlines() if ln.split()[:1] and ln.split()[0] not in keys]
    path = scene / name
    path.write_text("\n".join(text + lines) + "\n")
    return path


def _mosaic(files, like, nodata=np.nan):
    with rasterio.open(like) as t:
        return merge(sorted(files), bounds=t.bounds, res=t.res, nodata=nodata)[0][0]


def _height_errors(out, scene):
    """RMS of the solved DEM and of the given DEM against the truth, over the solved pixels (metres)."""
    like = scene / "truth" / "albedo.tif"
    truth, given = _mosaic([scene / "truth/dem.tif"], like), _mosaic([scene / "DEM/dem.tif"], like)
    dem = _mosaic(glob.glob(str(out / "DEM" / "*.tif")), like)
    ok = np.isfinite(dem)
    return float(np.sqrt(np.mean((dem - truth)[ok] ** 2))), float(np.sqrt(np.mean((given - truth)[ok] ** 2)))


def _window(rng, h_, w_, weights=None):
    """A window of random heights (metres) at lon 10, lat -5 and two images' ``J`` under Suns at azimuths 50 and
    130 degrees, 55 degrees from the zenith; ``weights()`` gives each image's weights (default 1)."""
    lon, lat = np.meshgrid(10 + 0.01 * np.arange(w_), -5 - 0.01 * np.arange(h_))
    h = rng.normal(0, 50, (h_, w_))
    pts = geometry.body_fixed(lon, lat, h)
    obs = [observation(rng.uniform(0.3, 0.8, (h_ - 2, w_ - 2)), weights() if weights else np.ones((h_ - 2, w_ - 2)), pts,
                       forward.sun_position(geometry.body_fixed(10.05, -5.05, 0), az, 55),
                       geometry.body_fixed(10.05, -5.05, 1e5)) for az in (50, 130)]
    return lon, lat, h, pts, obs


def test_cost_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    h_, w_ = 10, 12
    lon, lat, h, pts, obs = _window(rng, h_, w_)
    cost = Cost([Shading(1.0, unit_up(lon, lat), 1737.4, obs, photometry.get(2).reflectance, (1.4, 0.5)),
                 Smoothness(0.3, 300.0), Fidelity(0.2, 300.0, rng.normal(0, 50, (h_, w_)), 1.5)])
    g = cost(h)[1]
    for i, j in [(0, 0), (1, 1), (5, 6), (9, 11), (0, 5)]:
        e = np.zeros_like(h)
        e[i, j] = 1e-3
        assert g[i, j] == pytest.approx((cost(h + e)[0] - cost(h - e)[0]) / 2e-3, rel=1e-5, abs=1e-12)
    # the normals are those of the solver's geometry
    np.testing.assert_allclose(interior_normals(pts)[0], geometry.dem_normals(pts)[1:-1, 1:-1], atol=1e-14)


def test_height_uncertainty_is_the_gauss_newton_diagonal():
    """The diagonal of J^T J + mu L^T L + lambda S^T S against the Jacobian of the residuals by finite differences."""
    rng = np.random.default_rng(1)
    h_, w_ = 9, 11
    lon, lat, h, pts, obs = _window(rng, h_, w_, lambda: rng.uniform(0.5, 1.5, (h_ - 2, w_ - 2)))
    shading = Shading(1.0, unit_up(lon, lat), 1737.4, obs, photometry.get(2).reflectance, (1.4, 0.5), float_albedo=False)
    smooth, fid = Smoothness(0.3, 300.0), Fidelity(0.2, 300.0, rng.normal(0, 50, (h_, w_)), 1.5)
    sigma, s2 = height_uncertainty(Cost([shading, smooth, fid]), h)

    def residuals(x):  # every term's residuals, weighted so that their squares sum to the cost
        out = []
        p = shading.points(x)
        n = interior_normals(p)[0]
        for o in shading.observations:
            ci, ce = (n * o.l).sum(-1), (n * o.v).sum(-1)
            out.append((np.sqrt(o.w) * (o.j - shading.reflectance(ci, ce, o.alpha, shading.params))).ravel())
        out.append(np.sqrt(smooth.weight) * laplacian(x).ravel() / smooth.pixel_m)
        out.append(np.sqrt(fid.weight) * ((fid.smooth(x) - fid.h0) / fid.pixel_m).ravel())
        return np.concatenate(out)

    r0 = residuals(h)
    assert s2 == pytest.approx(np.sum(r0[:2 * (h_ - 2) * (w_ - 2)] ** 2) / (2 * (h_ - 2) * (w_ - 2)), rel=1e-9)
    jac = np.empty((r0.size, h.size))
    for p in range(h.size):
        e = np.zeros(h.size)
        e[p] = 1e-3
        jac[:, p] = (residuals(h + e.reshape(h.shape)) - residuals(h - e.reshape(h.shape))) / 2e-3
    np.testing.assert_allclose(sigma.ravel(), np.sqrt(s2 / np.sum(jac**2, axis=0)), rtol=1e-4)


def test_lbfgs_minimises_a_badly_scaled_quadratic():
    d = np.geomspace(1, 1e3, 500)
    x, f, _ = lbfgs(lambda x: (0.5 * float(np.sum(d * x * x)), d * x), np.ones(500), 300)
    assert f < 1e-8 * 0.5 * d.sum()


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    d = tmp_path_factory.mktemp("sfs")
    render_scene(d, SceneSpec(**SMALL))
    return d


def test_blurred_dem_scene_keeps_the_truth(small):
    with rasterio.open(small / "truth/dem.tif") as t, rasterio.open(small / "DEM/dem.tif") as g:
        truth, given = t.read(1), g.read(1)
        assert t.transform == g.transform
    assert np.sqrt(np.mean((truth - given) ** 2)) > 10.0  # the blur took away relief
    assert abs(truth.mean() - given.mean()) < 2.0  # but no height offset
    assert json.loads((small / "truth/truth.json").read_text())["dem"] == "truth/dem.tif"


def test_refine_dem_recovers_the_heights_and_the_albedo(small, tmp_path):
    plain = solve(small / "settings.txt", out=tmp_path / "plain", workers=1, plots=False)
    res = solve(_settings(small, REFINE), out=tmp_path / "sfs", workers=1, plots=False)
    err, given = _height_errors(tmp_path / "sfs", small)
    assert err <= 0.6 * given, (err, given)
    a_plain, a_sfs = score(tmp_path / "plain", small)["albedo_rel_rmse"], score(tmp_path / "sfs", small)["albedo_rel_rmse"]
    assert a_sfs < 0.8 * a_plain, (a_sfs, a_plain)
    rep = res.report["refine_dem"]
    assert len(rep["rounds"]) == 1 and rep["dem_change_rms_m"] > 0.3 * given
    assert res.report["settings"]["dem_dir"] == str(small / "DEM")  # the input DEM, not a round's
    tiles = sorted(p.name for p in (tmp_path / "sfs" / "DEM").glob("*.tif"))
    assert tiles == sorted(p.name for p in (tmp_path / "sfs" / "dem_change").glob("*.tif"))
    assert tiles == sorted(p.name for p in (tmp_path / "sfs" / "dem_lit").glob("*.tif"))
    assert tiles == sorted(p.name for p in (tmp_path / "sfs" / "dem_sigma").glob("*.tif"))
    lit = _mosaic(glob.glob(str(tmp_path / "sfs" / "dem_lit" / "*.tif")), small / "truth/albedo.tif", nodata=-1)
    assert 2 <= np.median(lit) <= 4  # each column is seen by about 3 images
    # each height's standard error: larger where the heights are worse (against the truth), and where fewer images see
    like = small / "truth/albedo.tif"
    sig = _mosaic(glob.glob(str(tmp_path / "sfs" / "dem_sigma" / "*.tif")), like)
    err = np.abs(_mosaic(glob.glob(str(tmp_path / "sfs" / "DEM" / "*.tif")), like) - _mosaic([small / "truth/dem.tif"], like))
    assert np.isfinite(sig).mean() > 0.95 and rep["dem_sigma_median_m"] > 0
    lo, hi = np.nanpercentile(sig, [33, 67])
    rms = lambda m: float(np.sqrt(np.mean(err[m] ** 2)))  # noqa: E731
    assert rms(sig <= lo) < 0.8 * rms(sig >= hi), (rms(sig <= lo), rms(sig >= hi))
    assert np.nanmedian(sig[lit >= 3]) < np.nanmedian(sig[lit <= 1])
    assert not (tmp_path / "sfs" / "sfs").exists() and not (tmp_path / "sfs" / "checkpoint").exists()
    # the web report shows the hillshade before and after
    from lunaralbedo.web.api import export_web

    web = export_web(tmp_path / "sfs", workers=1)
    assert {"hillshade", "hillshade_input"} <= set(web["layers"])
    before = sorted((tmp_path / "sfs" / "web" / "tiles" / "hillshade_input").rglob("*.png"))
    after = sorted((tmp_path / "sfs" / "web" / "tiles" / "hillshade").rglob("*.png"))
    assert before and [p.name for p in before] == [p.name for p in after]
    assert any(a.read_bytes() != b.read_bytes() for a, b in zip(before, after))  # the refined relief differs
    assert len(plain.tiles) == 6


def test_refine_dem_same_bytes_for_two_workers_after_a_kill_and_with_a_dem_with_holes(small, tmp_path, monkeypatch):
    with rasterio.open(small / "DEM/dem.tif") as ds:
        prof, h = ds.profile, ds.read(1)
    h[30:36, 40:52] = prof["nodata"]  # a hole in the given DEM: filled from the heights around it
    holed = tmp_path / "scene"
    holed.mkdir()
    for sub in ("DRG", "meta", "truth"):
        (holed / sub).symlink_to(small / sub)
    (holed / "DEM").mkdir()
    with rasterio.open(holed / "DEM/dem.tif", "w", **prof) as ds:
        ds.write(h, 1)
    (holed / "settings.txt").write_text((small / "settings.txt").read_text())
    # tiles of 40 px cut into height windows of 20 px
    path = _settings(holed, REFINE[:1] + ["REFINE_DEM_MAX_ITER 15", "REFINE_DEM_MARGIN 8", "REFINE_DEM_WINDOW 24"])
    solve(path, out=tmp_path / "w1", workers=1, plots=False)
    solve(path, out=tmp_path / "w2", workers=2, plots=False)
    real = refine.write_products

    def killed(*args, **kwargs):  # the run stops once the refined heights are written, before the last solve
        raise KeyboardInterrupt

    monkeypatch.setattr(refine, "write_products", killed)
    with pytest.raises(KeyboardInterrupt):
        solve(path, out=tmp_path / "killed", workers=1, plots=False)
    assert (tmp_path / "killed" / "sfs" / "dem_1" / "dem.tif").exists()
    monkeypatch.setattr(refine, "write_products", real)
    text = path.read_text()
    path.write_text(text.replace("REFINE_DEM_MAX_ITER 15", "REFINE_DEM_MAX_ITER 16"))  # the rounds' files are not theirs
    with pytest.raises(ResumeError, match="sfs"):
        solve(path, out=tmp_path / "killed", workers=1, plots=False, resume=True)
    path.write_text(text)
    solve(path, out=tmp_path / "killed", workers=1, plots=False, resume=True)
    for other in ("w2", "killed"):
        for sub in ("DEM", "albedo", "dem_change", "dem_lit", "dem_sigma"):
            for f in sorted((tmp_path / "w1" / sub).glob("*.tif")):
                with rasterio.open(f) as a, rasterio.open(tmp_path / other / sub / f.name) as b:
                    x, y = a.read(1), b.read(1)
                    assert np.array_equal(x, y, equal_nan=True), (other, sub, f.name)
                    if sub == "DEM":
                        assert np.isfinite(x).all()


def test_simulate_cli_rough_terrain_and_blurred_dem(tmp_path):
    from click.testing import CliRunner

    from lunaralbedo.cli import main

    args = ["simulate", str(tmp_path / "s"), "--images", "3", "--size", "32", "--overlap", "0.667", "--azimuths", "50,130",
            "--craters", "30", "--dem-blur", "2"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    truth = json.loads((tmp_path / "s/truth/truth.json").read_text())
    assert truth["spec"]["sun_azimuths"] == [50.0, 130.0] and truth["spec"]["dem_blur_px"] == 2.0
    with rasterio.open(tmp_path / "s/truth/dem.tif") as t, rasterio.open(tmp_path / "s/DEM/dem.tif") as g:
        # blurring lowers the relief's roughness: the given DEM's Laplacian is several times smaller
        lap = lambda h: np.abs(h[2:, 1:-1] + h[:-2, 1:-1] + h[1:-1, 2:] + h[1:-1, :-2] - 4 * h[1:-1, 1:-1]).mean()  # noqa
        assert lap(g.read(1).astype(float)) < 0.5 * lap(t.read(1).astype(float))
    res = CliRunner().invoke(main, ["simulate", str(tmp_path / "bad"), "--azimuths", "east"])
    assert res.exit_code == 2 and "--azimuths" in res.output and not (tmp_path / "bad").exists()


def test_fill_holes_follows_the_surrounding_heights_near_and_far():
    """Holes of the given DEM are filled from the heights around them: a hole inside a tilted plane
    gets GDAL's inverse-distance fill over the whole grid (the fill before it was split in two),
    within a third of the plane's relief across the hole; a ring of no data 350-400 px wide around the data (a small
    DEM under a big cast-shadow border) is filled everywhere, within the data's range, and near the
    data it continues the plane."""
    from lunaralbedo.engine.refine import fill_holes

    rows, cols = np.mgrid[0:1000, 0:900].astype(np.float32)
    plane = 2.0 * rows - 1.5 * cols + 100.0  # metres
    ok = np.zeros(plane.shape, bool)
    ok[400:600, 350:550] = True
    ok[490:505, 440:460] = False  # a hole inside the data
    h = np.where(ok, plane, np.nan).astype(np.float32)
    out = fill_holes(h, ok)
    assert out.dtype == np.float32 and np.isfinite(out).all()
    np.testing.assert_array_equal(out[ok], h[ok])  # the data is kept as it is
    from rasterio.fill import fillnodata

    whole = fillnodata(np.where(ok, h, 0).astype(np.float32), mask=ok.astype(np.uint8),
                       max_search_distance=300.0, smoothing_iterations=0)
    np.testing.assert_allclose(out[490:505, 440:460], whole[490:505, 440:460], atol=1e-3)
    assert np.abs(out[490:505, 440:460] - plane[490:505, 440:460]).max() < 40.0 / 3  # relief 2*15 + 1.5*20 m
    data = plane[ok]
    assert data.min() - 1 <= out.min() and out.max() <= data.max() + 1  # no overshoot far out
    near = out[390:400, 350:550] - plane[390:400, 350:550]  # 1-10 px above the data: a flat continuation
    assert np.abs(near).max() < 25.0  # at most the plane's rise over ~10 px (2 m/px) plus the rounding



#: The strip of docs/sfs.md (8 images of 120 px, each column seen by about 3, Sun azimuths 90 +- 40 degrees, small
#: fresh craters, the DEM blurred by 3 px), with every defect at once.
DEFECTS = dict(n_images=8, overlap=2 / 3, image_px=120, sun_azimuths=(50.0, 90.0, 130.0, 70.0, 110.0), fresh_craters=5.0,
               tile_size=1.0, seed=7, max_num_iter=10, dem_blur_px=3.0, haze_dn=(5.0, 15.0), outlier_fraction=0.01,
               misregister_px=2.0)


@pytest.mark.slow
def test_refine_dem_with_every_defect_haze_outliers_misregistration(tmp_path):
    """Blurred DEM, 5-15 DN of haze, 1 % outliers (hot spots, dropout rows), every image off by up to 2 px: heights,
    haze, registration and the outlier test compose (two workers; ~30 s on a busy 2-core machine)."""
    d = tmp_path / "scene"
    render_scene(d, SceneSpec(**DEFECTS))
    path = _settings(d, ["REFINE_DEM 1", "FLOAT_HAZE 1", "REGISTER_IMAGES 1"])
    res = solve(path, out=tmp_path / "sfs", workers=2, plots=False)
    err, given = _height_errors(tmp_path / "sfs", d)
    sc = score(tmp_path / "sfs", d)
    assert err <= 0.6 * given, (err, given)  # measured x0.29-0.31
    assert sc["albedo_rel_rmse"] <= 0.03 and sc["exposure_max_rel_err"] <= 0.015, sc  # measured 1.7 %, 0.7-0.9 %
    assert res.report["refine_dem"]["input_blur_fit"]["sigma_px"] == pytest.approx(3.0, abs=0.4)  # the scene's blur


def test_height_uncertainty_counts_the_floating_albedo_in_the_degrees_of_freedom():
    """With the albedo floating per pixel, each observed pixel's a* uses up one observation: one image leaves
    zero residuals whatever the heights (the real NAC crop read 3e-17 m), so no standard error is given; two
    images leave n - pixels degrees of freedom, and s^2 is the misfit over them."""
    rng = np.random.default_rng(2)
    h_, w_ = 9, 11
    lon, lat, h, pts, obs = _window(rng, h_, w_)
    terms = lambda o: Cost([Shading(1.0, unit_up(lon, lat), 1737.4, o, photometry.get(2).reflectance, (1.4, 0.5)),  # noqa: E731
                            Smoothness(0.3, 300.0), Fidelity(0.2, 300.0, h, 1.5)])
    sigma, s2 = height_uncertainty(terms(obs[:1]), h)
    assert np.isnan(s2) and np.isnan(sigma).all()
    sigma, s2 = height_uncertainty(terms(obs), h)
    _, misfit, n, dof = terms(obs).terms[0].gauss_newton_diagonal(h)
    assert (n, dof) == (2 * (h_ - 2) * (w_ - 2), (h_ - 2) * (w_ - 2))
    assert s2 == pytest.approx(misfit / dof, rel=1e-12) and np.isfinite(sigma).all()


def test_input_blur_is_left_at_zero_when_the_images_cannot_tell_the_blurs_apart(monkeypatch):
    """``REFINE_DEM_INPUT_BLUR auto``: a misfit curve with a clear minimum gives its vertex; one that varies by 1 %
    over all the candidates (PhotometryTK's Apollo scene: the smallest at 3.13 px moved the heights 431 m RMS)
    holds the input as given (sigma 0) instead of taking the minimum of noise."""
    from lunaralbedo.engine import refine, sfs_tile
    from lunaralbedo.parallel.executor import SerialExecutor

    def curve(shape):
        def misfits(t, *, sigmas, level, scene=None, **kw):  # per window: the misfit at each candidate blur
            return [shape(s) / 8 for s in sigmas]
        return misfits

    clear = lambda s: 1.0 + (np.log(max(s, 0.1)) - np.log(3.0)) ** 2  # noqa: E731  minimum at 3 px
    flat = lambda s: 1.0 + 0.005 * np.cos(3 * s)  # noqa: E731  1 % of wobble, its minimum near 3.14 px
    monkeypatch.setattr(sfs_tile, "blur_misfits", curve(clear))
    fit = refine.estimate_input_blur(SerialExecutor(), n_windows=8, levels=2, max_iter=5, scene=None)
    assert fit["sigma_px"] == pytest.approx(3.0, rel=0.1) and not fit.get("flat")
    monkeypatch.setattr(sfs_tile, "blur_misfits", curve(flat))
    fit = refine.estimate_input_blur(SerialExecutor(), n_windows=8, levels=2, max_iter=5, scene=None)
    assert fit["sigma_px"] == 0.0 and fit["flat"]
