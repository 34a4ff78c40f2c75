"""Positions at the campt time: attached tables vs kernels (real LRO cubes), Apollo 15 Metric from kernels."""
from __future__ import annotations

import numpy as np
import pytest
import spiceypy
from click.testing import CliRunner

from lunaralbedo.cli import main
from lunaralbedo.errors import SpiceError
from lunaralbedo.ingest.observation import open_observation
from lunaralbedo.ingest.positions import compute_positions
from lunaralbedo.io.positions import read_positions
from lunaralbedo.isis import read_label
from lunaralbedo.spice.ephemeris import KernelEphemeris, TableEphemeris
from lunaralbedo.spice.kernels import KernelPool, expand_kernel_args, label_kernels, resolve_isis_path

LRO_CUBES = ["M143947267L.cal.echo.crop.cub", "M1181493219CE.vis.odd.reduced.cub", "LSZ_04866_1CD_XKU_89N109_V1_lev1.crop.cub"]


@pytest.fixture(autouse=True)
def clean_pool():
    """The kernel pool is global: every test starts and ends with it empty."""
    spiceypy.kclear()
    yield
    assert spiceypy.ktotal("ALL") == 0, "a test left kernels loaded"
    spiceypy.kclear()


@pytest.mark.parametrize("name", LRO_CUBES)
def test_lro_table_sun_equals_kernel_sun(realdata, name):
    """Attached SunPosition/BodyRotation vs de421 + moon_pa_de421 + moon frame kernels: < 1 km.

    Measured: NAC 1.3e-5 km, Mini-RF 1.4e-3 km, WAC 0.30 km (its 2-record Linear Sun cache spans
    15 minutes and is read at its midpoint, where linear interpolation of the curved path errs most).
    """
    generic = expand_kernel_args([realdata / "kernels/generic"])
    with open_observation(realdata / "isis" / name, name[:11], generic, source="table") as obs:
        table_sun = obs.sun
        kernels = KernelEphemeris(-85, None, name)
        assert kernels.body_frame == "MOON_ME"
        kernel_sun = kernels.sun(obs.et)
        diff = np.linalg.norm(table_sun - kernel_sun)
        print(f"{name}: |table - kernel| Sun = {diff:.3e} km at ET {obs.et:.6f}")
        assert diff < 1.0
        rot = np.abs(obs.ephemeris.body_rotation(obs.et) - kernels.body_rotation(obs.et)).max()
        assert rot < 1e-9  # BodyRotation table = J2000 -> MOON_PA_DE421 then ConstantRotation -> MOON_ME
        assert 1.4e8 < np.linalg.norm(table_sun) < 1.6e8
        assert 1737.4 + 30 < np.linalg.norm(obs.spacecraft) < 1737.4 + 150


def test_nac_campt_time_from_preroll_clock(realdata):
    """LRO NAC line times: the crop's top edge (AlphaStartingLine 15999.5) is the tables' start time."""
    with open_observation(realdata / "isis" / LRO_CUBES[0], "M143947267L") as obs:
        from lunaralbedo.camera.timing import line_timing

        t = line_timing(obs.label, -85600)
        table_start = obs.ephemeris.time_range[0]
        assert t.et(15999.5) == pytest.approx(table_start, abs=1e-6)
        # centre pixel (200.5, 200.5) of the crop is alpha line 15999.5 + 200 = 16199.5
        assert obs.et == pytest.approx(t.et(16199.5), abs=1e-6)


def test_apollo_metric_positions_from_kernels_alone(realdata):
    """AS15-M-1450: detached label, no tables, positions from the ale kernel slices."""
    a15 = realdata / "apollo15_metric"
    res = compute_positions([a15 / "AS15-M-1450_isis3.lbl"], [realdata / "kernels/generic", a15])
    (r,) = res
    assert r.key == "AS15-M-1450" and r.source == "kernels"
    assert r.et == pytest.approx(-896821275.036744, abs=1e-6)  # StartTime, no exposure keyword
    assert np.linalg.norm(r.spacecraft) - 1737.4 == pytest.approx(118.409, abs=0.01)
    lon = np.degrees(np.arctan2(r.spacecraft[1], r.spacecraft[0]))
    lat = np.degrees(np.arcsin(r.spacecraft[2] / np.linalg.norm(r.spacecraft)))
    assert (lon, lat) == (pytest.approx(118.4218, abs=1e-3), pytest.approx(-18.5464, abs=1e-3))
    assert np.linalg.norm(r.sun) == pytest.approx(1.51999e8, rel=1e-5)


def test_apollo_j2000_state_matches_ale_isd(realdata):
    """The same J2000 vectors as ALE's ISD for this image (DOI-USGS/ale apollometric_isd.json)."""
    a15 = realdata / "apollo15_metric"
    kernels = expand_kernel_args([realdata / "kernels/generic", a15])
    with KernelPool(kernels):
        et = -896821275.036744
        sc, _ = spiceypy.spkpos("-915", et, "J2000", "LT+S", "MOON")
        sun, _ = spiceypy.spkpos("SUN", et, "J2000", "LT+S", "MOON")
    np.testing.assert_allclose(sc, [-1754.1260075053833, -8.536489940357743, -605.8016452642961], atol=1e-6)
    np.testing.assert_allclose(sun, [-95593128.35578895, 108408313.93764308, 47045061.66457185], atol=1e-3)


def test_isis_variables_resolve(tmp_path):
    lbl = tmp_path / "x.lbl"
    assert resolve_isis_path("$lro/kernels/a.bsp", tmp_path, tmp_path) == tmp_path / "lro/kernels/a.bsp"
    assert resolve_isis_path("$ISISDATA/base/x.tls", tmp_path, tmp_path) == tmp_path / "base/x.tls"
    assert resolve_isis_path("$base/x.tls", None, tmp_path) is None
    assert resolve_isis_path("k/a.tf", None, tmp_path) == tmp_path / "k/a.tf"
    (tmp_path / "lro").mkdir()
    (tmp_path / "lro/a.bsp").write_bytes(b"")
    found, missing = label_kernels({"TargetPosition": ["Table", "$lro/a.bsp"], "LeapSecond": "$base/n.tls"}, lbl, tmp_path)
    assert found == [tmp_path / "lro/a.bsp"] and missing == ["$base/n.tls"]


def test_missing_kernel_uncovered_time_unknown_frame_are_named(realdata, tmp_path):
    with pytest.raises(SpiceError, match="nope.bsp: kernel file or folder not found"):
        expand_kernel_args([tmp_path / "nope.bsp"])
    # Apollo label without its SPK: the error names the spacecraft, the time and the label kernels not found
    a15 = realdata / "apollo15_metric"
    only_generic = expand_kernel_args([realdata / "kernels/generic"])
    with pytest.raises(SpiceError) as err:
        with open_observation(a15 / "AS15-M-1450_isis3.lbl", "AS15-M-1450", only_generic):
            pass
    msg = str(err.value)
    assert "AS15-M-1450_isis3.lbl" in msg and "SPKINSUFFDATA" in msg and "AS15_M_REV35_v2.bsp" in msg
    # unknown instrument frame: the LRO frames kernel is not loaded
    with KernelPool(only_generic):
        eph = KernelEphemeris(-85, -85600, "cube.cub")
        with pytest.raises(SpiceError, match="unknown instrument frame -85600"):
            eph.instrument_rotation(0.0)
        # a time outside de421/moon_pa coverage
        with pytest.raises(SpiceError, match="MOON_PA_DE421 for epoch 5168"):
            eph.sun(1.0e11)


def test_positions_command_writes_legacy_files(realdata, tmp_path):
    sun, sc = tmp_path / "sunpos.txt", tmp_path / "spacecraftpos.txt"
    args = ["positions", str(realdata / "isis" / LRO_CUBES[0]), str(realdata / "apollo15_metric/AS15-M-1450_isis3.lbl"),
            "--kernels", str(realdata / "kernels/generic"), "--kernels", str(realdata / "apollo15_metric"),
            "--sun", str(sun), "--spacecraft", str(sc)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    s, c = read_positions(sun), read_positions(sc)
    assert list(s) == ["M143947267L", "AS15-M-1450"] and list(c) == list(s)
    assert np.linalg.norm(c["M143947267L"]) - 1737.4 == pytest.approx(54.473, abs=0.01)
    # a cube whose time cannot be modelled (push-frame WAC without tables): exit 2, "error: ...", nothing written
    out2 = tmp_path / "s2.txt"
    bad = CliRunner().invoke(main, ["positions", str(realdata / "isis/wac00002cf4.vis.even.cal.reduced.cub"),
                                    "--sun", str(out2), "--spacecraft", str(tmp_path / "c2.txt")])
    assert bad.exit_code == 2 and "error:" in bad.output and "push-frame camera without SPICE tables" in bad.output
    assert not out2.exists()


def test_pushframe_and_radar_times(realdata):
    """WAC push-frame: one position per band (the keys of ingest's DRGs), at a time inside its SPICE cache;
    Mini-RF: centre line of the crop, LineExposureDuration in s."""
    wac = realdata / "isis/M1181493219CE.vis.odd.reduced.cub"
    rf = realdata / "isis/LSZ_04866_1CD_XKU_89N109_V1_lev1.crop.cub"
    *bands, r = compute_positions([wac, rf])
    assert [b.key for b in bands] == [f"M1181493B0{b}" for b in range(1, 6)]
    assert all(480126019.21679896 < b.et < 480126924.46679896 for b in bands)
    # Mini-RF crop: alpha line 4906.5 + 2.5 = 4909 at StartTime + (4909 - 0.5) * 0.004651130362 s
    start = r.et - (4909 - 0.5) * 0.004651130362
    with KernelPool(expand_kernel_args([realdata / "kernels/generic"])):
        assert start == pytest.approx(spiceypy.str2et("2010-07-16T05:37:58.417299"), abs=1e-6)


def test_table_ephemeris_requires_tables(realdata):
    with pytest.raises(Exception, match="no SunPosition table"):
        TableEphemeris(read_label(realdata / "isis/wac00002cf4.vis.even.cal.reduced.cub"))


def test_kaguya_tc_line_scanner_time_from_sclk(realdata):
    """Kaguya TC (LineSamplingInterval, SCLK start count): centre time = ALE's ISD center_ephemeris_time."""
    tc = realdata / "kaguya_tc"
    (r,) = compute_positions([tc / "TC1S2B0_01_06691S820E0465_isis3.lbl"], [realdata / "kernels/generic", tc])
    assert r.et == pytest.approx(292234261.12293595, abs=1e-5)
    assert np.linalg.norm(r.spacecraft) - 1737.4 == pytest.approx(52.93, abs=0.05)


def test_label_kernels_resolve_through_isisdata(realdata, tmp_path, monkeypatch):
    """$base/$apollo15 paths of the AS15-M-1450 label resolve under ISISDATA (a tree of symlinks here)."""
    a15, gen = realdata / "apollo15_metric", realdata / "kernels/generic"
    links = {
        "base/kernels/lsk/naif0012.tls": gen / "naif0012.tls", "base/kernels/pck/pck00009.tpc": gen / "pck00009.tpc",
        "apollo15/kernels/pck/moon_080317.tf": gen / "moon_080317.tf",
        "apollo15/kernels/pck/moon_assoc_me.tf": gen / "moon_assoc_me.tf",
        "apollo15/kernels/tspk/moon_pa_de421_1900-2050.bpc": gen / "moon_pa_de421_1900-2050.bpc",
        "apollo15/kernels/tspk/de421.bsp": gen / "de421.bsp",
        "apollo15/kernels/fk/apollo15_v2.0002.tf": a15 / "apollo15_v2.0002.tf",
        "apollo15/kernels/ik/apollo15_metric_v2.0001.ti": a15 / "apollo15_metric_v2.0001.ti",
        "apollo15/kernels/sclk/apollo15.0001.tsc": a15 / "apollo15.0001.tsc",
        "apollo15/kernels/iak/apollo15MetricAddendum002.ti": a15 / "apollo15MetricAddendum002.ti",
    }
    for rel, target in links.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).symlink_to(target)
    label = a15 / "AS15-M-1450_isis3.lbl"
    found, missing = label_kernels(read_label(label).group("Kernels"), label, tmp_path)
    assert len(found) == len(links)
    # (ShapeModel names a DEM, not a kernel: not listed)
    assert missing == ["$apollo15/kernels/ck/AS15_M_REV35_v2.bc", "$apollo15/kernels/spk/AS15_M_REV35_v2.bsp"]
    # the ale slices of the SPK/CK have other names: give them with --kernels; the data area passed in
    # (the command line's --isisdata defaults to $ISISDATA; the library reads no environment)
    monkeypatch.setenv("ISISDATA", str(tmp_path / "elsewhere"))
    slices = [a15 / n for n in ("AS15-M-1450.isis_0.bsp", "AS15-M-1450.isis_1.bsp",
                                "AS15_M_REV35_v2_0_sliced_-915240.bc", "AS15_M_REV35_v2_1_sliced_-915240.bc")]
    (r,) = compute_positions([label], slices, isisdata=tmp_path)
    (ref,) = compute_positions([label], [gen, a15])
    np.testing.assert_allclose(r.spacecraft, ref.spacecraft, atol=1e-9)
    np.testing.assert_allclose(r.sun, ref.sun, atol=1e-6)
