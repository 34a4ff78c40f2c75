"""ISIS3 labels, tables and pixels of the real cubes in ../shared/realdata (read in place)."""
from __future__ import annotations

import datetime

import numpy as np
import pytest
import rasterio

from lunaralbedo.errors import IsisError
from lunaralbedo.isis import read_label, read_table
from lunaralbedo.isis.pvlfile import read_pvl
from lunaralbedo.isis.pixels import read_band, read_dem_cube
from lunaralbedo.model.geometry import radius_to_height
from lunaralbedo.isis.tables import has_table
from lunaralbedo.isis.write import write_cube

NAC = "isis/M143947267L.cal.echo.crop.cub"

CUBES = {  # name: (bands, lines, samples, pixel type)
    "isis/M143947267L.cal.echo.crop.cub": (1, 400, 400, "Real"),
    "isis/M1181493219CE.vis.odd.reduced.cub": (5, 357, 22, "Real"),
    "isis/LSZ_04866_1CD_XKU_89N109_V1_lev1.crop.cub": (1, 5, 5, "Real"),
    "isis/wac00002cf4.vis.even.cal.reduced.cub": (5, 10, 1, "Real"),
    "isis/ldem_4_reduced.cub": (1, 240, 480, "SignedWord"),
    "isis/WAC_GLD100_V1.0_GLOBAL_with_LOLA_30M_POLE.10km_cropped.cub": (1, 10, 5, "Real"),
    "isis/ulcn2005_lpo_downsampled.cub": (1, 219, 437, "SignedWord"),
    "isis/1x1_70NS_7b_wbhs_albflt_grid_geirist_tcorrect.reduced.cub": (63, 4, 11, "Real"),
    "isis/pattern.cub": (1, 90, 90, "Real"),
    "apollo15_metric/AS15-M-1450_isis3.lbl": (1, 25356, 25798, "Real"),
    "kaguya_tc/TC1S2B0_01_06691S820E0465_isis3.lbl": (1, 400, 3208, "SignedWord"),
}


@pytest.mark.parametrize("name", sorted(CUBES))
def test_every_real_label_parses(realdata, name):
    label = read_label(realdata / name)
    b, l, s, t = CUBES[name]
    assert label.shape == (b, l, s)
    assert label.pixel_type == t
    # detached labels have no pixels; attached cubes are their own pixel file
    assert (label.data_path is None) == name.endswith(".lbl")


def _gdal_label(path):
    """The label as GDAL's ISIS3 driver reads it (its own PVL parser), from its ``json:ISIS3`` metadata."""
    import json

    with rasterio.open(path) as ds:
        (head, rest), = ds.tags(ns="json:ISIS3").items()  # one JSON text, split by rasterio at its first ':'
        return json.loads(f"{head}:{rest}"), (ds.count, ds.height, ds.width)


def _same(ours, gdal) -> bool:
    if isinstance(gdal, dict) and "value" in gdal:  # a value with units
        gdal = gdal["value"]
    if isinstance(gdal, list):
        return isinstance(ours, (list, tuple)) and len(ours) == len(gdal) and all(map(_same, ours, gdal))
    ours = getattr(ours, "value", ours)
    if isinstance(ours, (datetime.date, datetime.time)):  # pvl reads ISIS times as datetimes, GDAL keeps the text
        kind = type(ours)
        return ours.replace(tzinfo=None) == kind.fromisoformat(str(gdal).removesuffix("Z")).replace(tzinfo=None)
    if isinstance(gdal, (int, float)) and isinstance(ours, (int, float)):
        return ours == pytest.approx(gdal, rel=1e-12)
    return str(ours) == str(gdal)


@pytest.mark.parametrize("name", sorted(n for n in CUBES if n.endswith(".cub")))
def test_labels_read_as_gdal_reads_them(realdata, name):
    """The package's one PVL reader against GDAL's ISIS3 driver on each real cube: the size of the pixels GDAL
    opens, and every text or number keyword of the Dimensions, Pixels, Instrument, Kernels and Mapping groups
    (GDAL writes ISIS's Null as the text 'Null', yes/no words as text, keeps the line breaks of a quoted
    text and flattens nested sets: those keywords are left out)."""
    label = read_label(realdata / name)
    gdal, shape = _gdal_label(realdata / name)
    assert label.shape == shape
    compared = 0
    for group in ("Dimensions", "Pixels", "Instrument", "Kernels", "Mapping"):
        theirs = gdal["IsisCube"].get("Core", {}).get(group) or gdal["IsisCube"].get(group)
        if theirs is None:
            assert not label.has(group)
            continue
        ours = label.group(group)
        for key, value in theirs.items():
            nested = isinstance(ours.get(key), list) and any(isinstance(v, list) for v in ours[key])
            if (key.startswith("_") or value == "Null" or "\n" in str(value) or "\\n" in str(value)
                    or str(value).upper() in ("TRUE", "FALSE") or nested):
                continue
            assert _same(ours[key], value), (group, key, ours[key], value)
            compared += 1
    assert compared >= 7  # the test pattern's Dimensions and Pixels; 21-44 for the others


def test_split_words_and_endgroup_spellings_are_read_by_the_grammar(realdata):
    nac = read_label(realdata / NAC)
    spk = nac.group("Kernels")["InstrumentPosition"]
    assert spk == ["Table", "$lro/kernels/spk/fdf29r_2010305_2010335_v01.bsp"]
    a15 = read_label(realdata / "apollo15_metric/AS15-M-1450_isis3.lbl")
    assert "$apollo15/kernels/tspk/moon_pa_de421_1900-2050.bpc" in a15.group("Kernels")["TargetPosition"]
    hapke = read_pvl(realdata / "isis/hapke_full_reformatted.pvl")  # EndGroup / EndObject
    assert hapke["PhotometricModel"]["Algorithm"]["Name"] == "HapkeLROC"
    assert read_pvl(realdata / "isis/NAC_PHO_LROC_Empirical.0003.pvl")


def test_nac_spice_tables(realdata):
    label = read_label(realdata / NAC)
    sizes = {name: read_table(label, name).records.size for name in label.table_labels()}
    assert sizes == {"InstrumentPointing": 4, "InstrumentPosition": 3, "BodyRotation": 2, "SunPosition": 2}
    pos = read_table(label, "InstrumentPosition")
    assert pos.meta["CacheType"] == "HermiteSpline"
    assert pos.column("ET")[0] == pytest.approx(342580072.37562, abs=1e-4)
    assert np.linalg.norm(pos.columns("J2000X", "J2000Y", "J2000Z")[0]) == pytest.approx(1791.87, abs=0.05)
    rot = read_table(label, "BodyRotation")
    q = rot.columns("J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3")
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    assert len(rot.meta["ConstantRotation"]) == 9


def test_detached_label_tables_are_not_readable(realdata):
    label = read_label(realdata / "apollo15_metric/AS15-M-1450_isis3.lbl")
    assert "SunPosition" in label.table_labels()
    assert not has_table(label, "SunPosition")
    with pytest.raises(IsisError, match="no pixel/table file"):
        read_table(label, "SunPosition")
    with pytest.raises(IsisError, match="label only"):
        read_band(label)


def test_pixels_with_special_pixels_masked(realdata):
    nac = read_band(realdata / NAC)
    assert nac.shape == (400, 400)
    assert np.isfinite(nac).all()
    assert np.mean(nac) == pytest.approx(0.10371, abs=1e-4)  # I/F
    wac = read_band(realdata / "isis/M1181493219CE.vis.odd.reduced.cub")
    assert np.isnan(wac).sum() == 4488  # NULL pixels of the WAC push-frame gaps
    assert 100 < np.nanmin(wac) and np.nanmax(wac) < 800
    # the raw file holds the ISIS NULL value where we have NaN
    with rasterio.open(realdata / "isis/M1181493219CE.vis.odd.reduced.cub") as ds:
        raw = ds.read(1)
    assert raw[np.isnan(wac)].max() < -3.4e38


def test_dem_cubes_radius_detected_and_converted(realdata):
    h, transform, crs, was_radius = read_dem_cube(realdata / "isis/ldem_4_reduced.cub")
    assert was_radius  # Base 1737400 + 0.5 * stored: radius in metres
    assert np.nanmin(h) == pytest.approx(-7811.0) and np.nanmax(h) == pytest.approx(9141.0)
    assert crs is not None and transform.a == pytest.approx(22742.52, abs=0.01)
    g, *_rest, g_radius = read_dem_cube(realdata / "isis/WAC_GLD100_V1.0_GLOBAL_with_LOLA_30M_POLE.10km_cropped.cub")
    assert g_radius and -2000 < np.nanmin(g) < np.nanmax(g) < 1000
    u, *_rest, _ = read_dem_cube(realdata / "isis/ulcn2005_lpo_downsampled.cub")
    assert np.isnan(u).sum() == 437  # one row of NULL pixels
    forced, was = radius_to_height(np.array([5.0, 7.0]), "radius")
    assert was and forced[0] == pytest.approx(5.0 - 1737400.0)
    kept, was = radius_to_height(np.array([1737500.0]), "height")
    assert not was and kept[0] == 1737500.0


def test_not_a_cube_is_a_clear_error(tmp_path, realdata):
    bad = tmp_path / "bad.cub"
    bad.write_text("this is not PVL = = (\n")
    with pytest.raises(IsisError, match="bad.cub"):
        read_label(bad)
    with pytest.raises(IsisError, match="not found"):
        read_label(tmp_path / "missing.cub")
    with pytest.raises(IsisError, match="no IsisCube"):
        read_label(realdata / "isis/NAC_PHO_LROC_Empirical.0003.pvl")


def test_written_cube_reads_back_through_gdal(tmp_path):
    data = np.arange(12, dtype=np.float32).reshape(3, 4) / 7.0
    data[1, 2] = np.nan
    path = tmp_path / "x.cub"
    write_cube(path, data, {"Instrument": {"TargetName": "MOON", "StartTime": "2021-05-23T00:00:00.000"}})
    label = read_label(path)
    assert label.shape == (1, 3, 4) and label.keyword("Instrument", "TargetName") == "MOON"
    back = read_band(label)
    np.testing.assert_array_equal(np.isnan(back), np.isnan(data))
    np.testing.assert_allclose(back[~np.isnan(data)], data[~np.isnan(data)], rtol=1e-7)
    with rasterio.open(path) as ds:
        assert ds.driver == "ISIS3" and ds.shape == (3, 4)


def test_a_label_that_is_not_pvl_is_one_error_naming_the_file(tmp_path, realdata):
    """A label cut inside a quoted text: IsisError naming the file; a missing file likewise."""
    text = (realdata / NAC).read_bytes()[:2000]  # the label, cut off in its first groups
    bad = tmp_path / "cut.cub"
    bad.write_bytes(text + b'\n  Name = "a quote that never closes\nEnd\n')
    with pytest.raises(IsisError, match=r"cut\.cub: not an ISIS cube or ISIS label \(cannot parse"):
        read_label(bad)
    with pytest.raises(IsisError, match=r"nothing\.cub: ISIS label not found"):
        read_label(tmp_path / "nothing.cub")
