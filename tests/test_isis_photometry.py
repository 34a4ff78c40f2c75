"""LROC photometric corrections against ISIS's own functional-test figures (lronacpho, lrowacphomap).

Reference numbers are ISIS3's (isis/tests/FunctionalTestsLronacpho.cpp, FunctionalTestsLrowacphomap.cpp);
the cubes, parameter files and ISIS's phocube backplane are read in place from ``../shared/realdata/isis``.
"""
from __future__ import annotations

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from lunaralbedo.cli.photometry import command as photometry_cmd
from lunaralbedo.errors import IsisError
from lunaralbedo.isis.pvlfile import read_pvl
from lunaralbedo.model.photometry.hapke import hapke_lroc
from lunaralbedo.model.photometry.lroc_empirical import LrocEmpirical
from lunaralbedo.phocorr.params import load_lroc_empirical
from lunaralbedo.phocorr.run import correct

NAC = "M143947267L.cal.echo.crop.cub"
WAC = "M1181493219CE.vis.odd.reduced.cub"
PARAM_MAP = "1x1_70NS_7b_wbhs_albflt_grid_geirist_tcorrect.reduced.cub"
# ISIS's NAC_PHO_LROC_Empirical.0002.pvl (2014 form, A0-A3), the parameters of its "Algo2" functional test
PVL_2014 = """Object = NormalizationModel
  Group = Algorithm
    Name = LROC_Empirical
    Incref=30.0
    Emaref=0.0
    Pharef=30.0
  EndGroup
EndObject
Object = PhotometricModel
  Units = Degrees
  Group = Algorithm
    Name = LROC_Empirical
    BandBinCenter = 600.0
    A0 = -2.9811422
    A1 = -0.0112862
    A2 = -0.8084603
    A3 = 1.3248888
  EndGroup
EndObject
"""

pytestmark = pytest.mark.usefixtures("clean_spice_pool")


@pytest.fixture(scope="module")
def isis(realdata):
    return realdata / "isis"


def _read(path, band=1):
    with rasterio.open(path) as ds:
        return ds.read(band)


def test_parameter_files_with_endgroup_parse_without_editing(isis):
    m = read_pvl(isis / "hapke_full_reformatted.pvl")
    groups = [v for k, v in m["PhotometricModel"].items() if k == "Parameters"]
    assert [g["BandBinCenter"] for g in groups] == [321, 360, 415, 566, 604, 643, 689]
    models, ref = load_lroc_empirical(isis / "NAC_PHO_LROC_Empirical.0003.pvl", [600.0])
    assert ref == (30.0, 0.0, 30.0) and models[0].version == 2019 and models[0].degrees
    with pytest.raises(IsisError, match="no PhotometricModel Algorithm group for band 1"):
        load_lroc_empirical(isis / "NAC_PHO_LROC_Empirical.0003.pvl", [415.0])


def test_lroc_empirical_2019_form_is_the_published_formula():
    """F = mu0/(mu+mu0) exp(B0 + B1 g^2 + B2 g + B3 sqrt g + B4 mu + B5 mu0 + B6 mu0^2), g in degrees."""
    b = (-1.479654495, -0.000083528, 0.012964707, -0.237774774, 0.556075496, 0.663671460, -0.439918609)
    m = LrocEmpirical(b=b, version=2019, degrees=True)
    i, e, g = 50.0, 10.0, 55.0
    mu0, mu = np.cos(np.radians(i)), np.cos(np.radians(e))
    want = mu0 / (mu + mu0) * np.exp(b[0] + b[1] * g * g + b[2] * g + b[3] * np.sqrt(g) + b[4] * mu + b[5] * mu0
                                     + b[6] * mu0 * mu0)
    assert float(m(i, e, g)) == pytest.approx(want, rel=1e-14)
    assert float(m.correction(30.0, 0.0, 30.0)) == pytest.approx(1.0, rel=1e-14)


@pytest.mark.parametrize("pvl, expected", [("0003", 0.26584613), ("0002", 0.28940132)])
def test_lronacpho_functional_figure(isis, tmp_path, pvl, expected):
    """ISIS lronacpho usedem=no: line 300, sample 301 of the NAC crop (both algorithm versions), +-0.002."""
    params = isis / "NAC_PHO_LROC_Empirical.0003.pvl"
    if pvl == "0002":
        params = tmp_path / "NAC_PHO_LROC_Empirical.0002.pvl"
        params.write_text(PVL_2014)
    out = tmp_path / "nac.tif"
    res = correct(isis / NAC, out, "lroc-empirical", params, ellipsoid=True)
    value = float(_read(out)[299, 300])
    assert value == pytest.approx(expected, abs=0.002)
    assert res[0].count == 400 * 400  # every pixel lit and seen within ISIS's 85-degree limits


WITH_BACK = dict(mean=58.565850201775, std=19.336237864721, minimum=21.181716918945, maximum=160.17492675781,
                 total=197132.65177917)


def _hapke_args(isis):
    return ["--model", "hapke-map", "--params", str(isis / "hapke_full_reformatted.pvl"),
            "--param-map", str(isis / PARAM_MAP)]


def test_lrowacphomap_with_backplane_isis_compat_is_exact(isis, tmp_path):
    out = tmp_path / "wac.tif"
    r = CliRunner().invoke(photometry_cmd, [str(isis / WAC), "--band", "1", *_hapke_args(isis), "--backplane",
                                           str(isis / "back.reduced.cub"), "--isis-compat", "-o", str(out)])
    assert r.exit_code == 0, r.output
    v = _read(out).astype(np.float64)
    v = v[np.isfinite(v)]
    got = dict(mean=v.mean(), std=v.std(ddof=1), minimum=v.min(), maximum=v.max(), total=v.sum())
    for k, want in WITH_BACK.items():
        assert got[k] == pytest.approx(want, rel=1e-9, abs=1e-9), k


def test_lrowacphomap_correct_mode_uses_the_band_own_parameters(isis, tmp_path):
    """Correct mode: r415(60,0,60)/r415(i,e,g); ISIS's defects give r321(60,0,60)/r689(i,e,g) (issue: mean 165.39)."""
    out = tmp_path / "wac.tif"
    res = correct(isis / WAC, out, "hapke-map", isis / "hapke_full_reformatted.pvl", band=1,
                  param_map=isis / PARAM_MAP, backplane=isis / "back.reduced.cub")
    assert res[0].count == 3366 and res[0].mean == pytest.approx(165.39, abs=0.01)
    # the definition, checked pixel by pixel with the 415 nm parameters of the map pixel
    from lunaralbedo.isis.pixels import read_band
    from lunaralbedo.isis.parameter_map import read_parameter_map

    pmap = read_parameter_map(isis / PARAM_MAP)
    ph, em, inc, lat, lon = (read_band(isis / "back.reduced.cub", b) for b in range(1, 6))
    img = read_band(isis / WAC, 1)
    rows, cols, inside = pmap.pixel(lat, lon)
    p415 = [pmap.data[18 + k][rows, cols] for k in range(9)]  # bands 19-27 of the map are the 415 nm group
    want = img * hapke_lroc(60.0, 0.0, 60.0, *p415) / hapke_lroc(inc, em, ph, *p415)
    got = _read(out).astype(np.float64)
    ok = np.isfinite(got)
    np.testing.assert_allclose(got[ok], want[ok], rtol=1e-6)


USEDEM = dict(mean=58.159470616532, std=18.558190342074, total=195764.77809525)


def test_lrowacphomap_usedem_with_our_pushframe_camera(isis, tmp_path):
    """ISIS usedem=true: our WAC camera + the cube's ShapeModel (reduced GLD100) within 0.2 % / 1 % / count."""
    out = tmp_path / "wac.tif"
    res = correct(isis / WAC, out, "hapke-map", isis / "hapke_full_reformatted.pvl", band=1,
                  param_map=isis / PARAM_MAP, isis_compat=True)[0]
    assert "WAC_GLD100" in res.geometry  # the label's ShapeModel resolved beside the cube
    assert res.count == round(USEDEM["total"] / USEDEM["mean"]) == 3366
    assert res.mean == pytest.approx(USEDEM["mean"], rel=0.002)
    assert res.std == pytest.approx(USEDEM["std"], rel=0.01)
    # measured: 58.1594810 / 18.5581879 / 195764.8131 (1.8e-7 relative on the mean)
    assert res.mean == pytest.approx(USEDEM["mean"], rel=1e-5)


def test_our_backplane_feeds_photometry_and_bad_input_is_refused(isis, tmp_path):
    """`backplanes` output used as --backplane gives the camera path's result; bad input: exit 2, nothing written."""
    from lunaralbedo.cli.backplanes import command as backplanes_cmd

    bp = tmp_path / "bp.tif"
    assert CliRunner().invoke(backplanes_cmd, [str(isis / NAC), "--ellipsoid", "-o", str(bp)]).exit_code == 0
    params = isis / "NAC_PHO_LROC_Empirical.0003.pvl"
    correct(isis / NAC, tmp_path / "a.tif", "lroc-empirical", params, ellipsoid=True)
    correct(isis / NAC, tmp_path / "b.tif", "lroc-empirical", params, backplane=bp)
    np.testing.assert_allclose(_read(tmp_path / "b.tif"), _read(tmp_path / "a.tif"), rtol=1e-5)
    out = tmp_path / "x.tif"
    r = CliRunner().invoke(photometry_cmd, [str(isis / WAC), "--band", "1", "--model", "hapke-map", "--params",
                                           str(isis / "hapke_full_reformatted.pvl"), "-o", str(out)])
    assert r.exit_code == 2 and "needs --param-map" in r.output and not out.exists()
    r = CliRunner().invoke(photometry_cmd, [str(isis / WAC), "--band", "1", "--model", "lroc-empirical", "--params",
                                           str(params), "--ellipsoid", "-o", str(out)])
    assert r.exit_code == 2 and "no PhotometricModel Algorithm group for band 1 (centre 415.0 nm)" in r.output
    assert not out.exists()
