"""Bad values a new user gives on a first real run (docs/errors.md, "Bad values caught up front").

Every case: the exit code, one line ``error: ...`` naming the option or file and the problem,
no traceback, no library dump, nothing written.  Inputs: the repository's sample cubes, a small
forward-model scene, the real cubes of ``../shared/realdata`` read in place.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bad_input_common import assert_clean_failure, cli, truncate
from lunaralbedo.io.geotiff import write_geotiff
from lunaralbedo.io.rasters import MOON_CRS
from lunaralbedo.nac.synthetic import Terrain
from lunaralbedo.simulate import SceneSpec, render_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data"
CUBE = SAMPLE / "cubes" / "SIM-F-00001.cub"
GLD100 = "WAC_GLD100_V1.0_GLOBAL_with_LOLA_30M_POLE.16bit.reduced.cub"


def ingest(*args, out: Path):
    return cli("ingest", *args, "-o", out)


# --- ingest -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("option,value", [("--tile-size", "0"), ("--tile-size", "-1"), ("--tile-size", "nan"),
                                          ("--tile-size", "400"), ("--mpp", "0"), ("--mpp", "inf")])
def test_ingest_bad_grid_option_writes_nothing(tmp_path, option, value):
    work = tmp_path / "work"
    res = ingest(CUBE, "--dem", SAMPLE / "dem", option, value, out=work)
    assert_clean_failure(res, 2, option, absent=work)


def test_text_file_named_cub(tmp_path):
    fake = tmp_path / "notes.cub"
    fake.write_text("observing log\nsun was high\n")
    res = ingest(fake, "--dem", SAMPLE / "dem", out=tmp_path / "work")
    msg = assert_clean_failure(res, 2, fake, "not an ISIS cube", absent=tmp_path / "work")
    assert "ParseError" not in msg and "LexerError" not in msg and len(msg) < 300
    res = cli("positions", fake, "--sun", tmp_path / "s.txt", "--spacecraft", tmp_path / "c.txt")
    assert_clean_failure(res, 2, fake, "not an ISIS cube", absent=tmp_path / "s.txt")


def test_folder_given_as_a_cube(tmp_path):
    folder = tmp_path / "images.cub"
    folder.mkdir()
    res = ingest(folder, "--dem", SAMPLE / "dem", out=tmp_path / "work")
    assert_clean_failure(res, 2, folder, "is a folder", absent=tmp_path / "work")
    res = cli("positions", folder, "--sun", tmp_path / "s.txt", "--spacecraft", tmp_path / "c.txt")
    assert_clean_failure(res, 2, folder, "is a folder", absent=tmp_path / "s.txt")


def test_truncated_isis_dem(realdata, tmp_path):
    dem = tmp_path / "gld100.cub"
    shutil.copyfile(realdata / "isis" / GLD100, dem)
    truncate(dem, 0.4)
    res = ingest(CUBE, "--dem", dem, out=tmp_path / "work")
    msg = assert_clean_failure(res, 2, dem, "truncated", absent=tmp_path / "work")
    assert "previous exception" not in msg
    assert f"{dem.stat().st_size:,} bytes" in msg  # what the file has against what its label needs


@pytest.mark.usefixtures("clean_spice_pool")
def test_mini_rf_is_refused_before_its_clock(realdata, tmp_path):
    rf = realdata / "isis" / "LSZ_04866_1CD_XKU_89N109_V1_lev1.crop.cub"
    # with the LRO SCLK loaded its clock count "UNK" would fail to parse: the refusal comes first
    res = ingest(rf, "--dem", realdata / "isis" / GLD100, "--kernels", realdata / "lro", out=tmp_path / "work")
    msg = assert_clean_failure(res, 2, rf, "radar (Mini-RF) is not supported: ", absent=tmp_path / "work")
    assert "SCLK" not in msg and "UNK" not in msg


@pytest.mark.usefixtures("clean_spice_pool")
def test_mini_rf_backplanes_are_refused_before_its_clock(realdata, tmp_path):
    rf = realdata / "isis" / "LSZ_04866_1CD_XKU_89N109_V1_lev1.crop.cub"
    res = cli("backplanes", rf, "-o", tmp_path / "bp.tif", "--kernels", realdata / "lro")
    msg = assert_clean_failure(res, 2, rf, "radar (Mini-RF) is not supported: ", absent=tmp_path / "bp.tif")
    assert "SCLK" not in msg and "UNK" not in msg


@pytest.mark.usefixtures("clean_spice_pool")
def test_mini_rf_positions_with_the_lro_sclk_are_timed_from_start_time(realdata, tmp_path):
    """ISIS's MiniRF camera times a radar cube from its StartTime: with the LRO SCLK loaded, its clock counts
    (``UNK``) are not parsed, and the centre line (alpha line 4909 of the crop, 0.004651130362 s a line) is at
    StartTime + 4908.5 lines, the time ISIS campt gives (docs/ingest.md)."""
    import spiceypy

    from lunaralbedo.io.positions import read_positions

    rf = realdata / "isis" / "LSZ_04866_1CD_XKU_89N109_V1_lev1.crop.cub"
    sun, sc = tmp_path / "sun.txt", tmp_path / "sc.txt"
    res = cli("positions", rf, "--kernels", realdata / "kernels" / "generic", "--kernels", realdata / "lro",
              "--sun", sun, "--spacecraft", sc)
    assert res.exit_code == 0, res.stderr
    et = float(res.stdout.split(" ET ")[1].split()[0])
    spiceypy.furnsh(str(realdata / "kernels" / "generic" / "naif0012.tls"))
    assert et == pytest.approx(spiceypy.str2et("2010-07-16T05:37:58.417299") + 4908.5 * 0.004651130362, abs=1e-5)
    assert 1737.4 + 30 < np.linalg.norm(read_positions(sc)["LSZ_04866_1"]) < 1737.4 + 150


# --- solve --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("options_scene")
    render_scene(d, SceneSpec(n_images=3, image_px=40, tile_size=0.25, max_num_iter=2, seed=5))
    return d


@pytest.mark.parametrize("option,value", [("--max-iter", "-3"), ("--tolerance", "-1"), ("--tolerance", "nan"),
                                          ("--jobs", "0")])
def test_solve_bad_option_writes_nothing(scene, tmp_path, option, value):
    out = tmp_path / "out"
    res = cli("solve", scene / "settings.txt", "-o", out, "--quiet", option, value)
    assert_clean_failure(res, 2, option, absent=out)


def test_solve_into_a_closed_pipe_ends_quietly(scene, tmp_path):
    """``solve ... | head -1``: the reader is gone before the summary is printed; no error, status 141."""
    out = tmp_path / "out"
    read, write = os.pipe()
    os.close(read)  # the reader went away
    proc = subprocess.run([sys.executable, "-m", "lunaralbedo.cli", "solve", str(scene / "settings.txt"), "-o",
                           str(out), "--quiet"], stdout=write, stderr=subprocess.PIPE, text=True)
    os.close(write)
    assert proc.returncode == 141, proc.stderr
    assert proc.stderr.strip() == "", proc.stderr
    assert (out / "report.json").is_file()  # the work was done; only its summary had nowhere to go


# --- align --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def terrain(tmp_path_factory):
    d = tmp_path_factory.mktemp("align_bad")
    rng = np.random.default_rng(3)
    ter = Terrain.random(rng, size_m=3000.0, n_craters=15)
    h, tr = ter.dem(3000.0, 20.0)
    write_geotiff(d / "dem.tif", h.astype(np.float32), tr, MOON_CRS, nodata=np.nan, dtype="float32")
    pts = ter.tracks(rng, 2600.0, noise_m=0.5)
    return d, pts


def _align(d: Path, reference: Path, prefix: Path, *extra):
    return cli("align", d / "dem.tif", "--reference", reference, "-o", prefix, *extra)


def test_align_errors_list_only_points_on_the_dem(terrain, tmp_path):
    d, pts = terrain
    off = pts[:40].copy()
    off[:, 0] += 1.0  # 30 km east: off the 3 km DEM
    ref = tmp_path / "ref.csv"
    np.savetxt(ref, np.vstack([pts, off]), delimiter=",", header="lon,lat,radius", comments="", fmt="%.9f")
    res = _align(d, ref, tmp_path / "a")
    assert res.exit_code == 0, res.output
    for name in ("a-beg_errors.csv", "a-end_errors.csv"):
        rows = (tmp_path / name).read_text().splitlines()[1:]
        assert len(rows) <= len(pts) and len(rows) > 0.9 * len(pts)
        assert not any("nan" in r.lower() for r in rows)
    assert f"{len(pts)} points over the DEM of {len(pts) + 40}" in res.output


def test_align_without_overlap_leaves_nothing(terrain, tmp_path):
    d, pts = terrain
    far = pts.copy()
    far[:, 0] += 5.0
    ref = tmp_path / "far.csv"
    np.savetxt(ref, far, delimiter=",", header="lon,lat,radius", comments="", fmt="%.9f")
    res = _align(d, ref, tmp_path / "a")
    assert_clean_failure(res, 2, ref, "do not overlap")
    assert not list(tmp_path.glob("a-*"))


@pytest.mark.parametrize("option,value", [("--max-displacement", "0"), ("--outlier-ratio", "1.5")])
def test_align_bad_option(terrain, tmp_path, option, value):
    d, pts = terrain
    ref = tmp_path / "ref.csv"
    np.savetxt(ref, pts, delimiter=",", header="lon,lat,radius", comments="", fmt="%.9f")
    assert_clean_failure(_align(d, ref, tmp_path / "a", option, value), 2, option)
    assert not list(tmp_path.glob("a-*"))


@pytest.mark.usefixtures("clean_spice_pool")
def test_align_too_few_points_on_a_real_dem(realdata, tmp_path):
    """The 10 x 5 px GLD100 crop against the 7.6 km LOLA LDEM: 8 points over it, not enough to fix a rigid
    transform (they drift off); exit 2 with the reason, nothing written."""
    isis = realdata / "isis"
    res = cli("align", isis / "WAC_GLD100_V1.0_GLOBAL_with_LOLA_30M_POLE.10km_cropped.cub", "--reference",
              isis / "ldem_4_reduced.cub", "-o", tmp_path / "a", "--max-displacement", "5000")
    assert_clean_failure(res, 2, "ldem_4_reduced.cub", "too few points")
    assert not list(tmp_path.glob("a-*"))


def test_align_ctrl_c_does_not_offer_resume(terrain, tmp_path, monkeypatch):
    """align has no checkpoint: Ctrl-C says interrupted (130) without pointing to a --resume it lacks."""
    import lunaralbedo.nac.align_files as af

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(af, "icp", interrupted)
    d, pts = terrain
    ref = tmp_path / "ref.csv"
    np.savetxt(ref, pts, delimiter=",", header="lon,lat,radius", comments="", fmt="%.9f")
    msg = assert_clean_failure(_align(d, ref, tmp_path / "a"), 130, "interrupted")
    assert "resume" not in msg
    assert not list(tmp_path.glob("a-*"))


def test_native_union_too_big_asks_for_mpp():
    """Two 0.5 m images 10 degrees apart would make a 600 000 px wide grid at their native resolution:
    refused before anything is written, with the --mpp that fits."""
    from lunaralbedo.errors import InputError
    from lunaralbedo.ingest.dem import DemMosaic, load_dems
    from lunaralbedo.ingest.run import MAX_GRID_PIXELS, _check_union_size

    dem = DemMosaic(load_dems([SAMPLE / "dem"]))
    near = [(0.5, (10.0, 0.0, 10.01, 0.1)), (0.5, (10.02, 0.0, 10.03, 0.1))]
    _check_union_size(near, dem)  # 0.03 x 0.1 degrees at 0.5 m: ~1800 x 6100 px, fine
    with pytest.raises(InputError, match=r"give --mpp ([0-9.]+) or coarser") as exc:
        _check_union_size(near + [(0.5, (20.0, 0.0, 20.01, 0.1))], dem)
    coarser = float(exc.value.args[0].split("give --mpp ")[1].split()[0])
    width, height = 10.01 / np.degrees(coarser / 1737400.0), 0.1 / np.degrees(coarser / 1737400.0)
    assert width * height == pytest.approx(MAX_GRID_PIXELS, rel=0.05)


def test_align_reports_each_iteration(terrain, tmp_path):
    """align's progress: one call per ICP iteration with the mean distance, as many as the report counts."""
    from lunaralbedo.nac.align_files import align_files

    d, pts = terrain
    ref = tmp_path / "ref.csv"
    np.savetxt(ref, pts, delimiter=",", header="lon,lat,radius", comments="", fmt="%.9f")
    seen = []
    report = align_files(d / "dem.tif", ref, tmp_path / "a", on_iteration=lambda i, dist: seen.append((i, dist)))
    assert [i for i, _ in seen] == list(range(1, report["iterations"] + 1))
    assert all(np.isfinite(dist) and dist >= 0 for _, dist in seen)


def test_solve_warns_naming_tile_size_over_the_budget(scene, tmp_path, monkeypatch):
    """A tile over the memory budget: one warning naming TILE_SIZE and the value that fits; the run goes on
    in blocks of rows and finishes."""
    monkeypatch.setenv("LUNARALBEDO_BLOCK_MB", "0.05")  # 52 kB: 546 px at 96 B/px, less than one tile of the scene
    from lunaralbedo.settings import load_settings

    s = load_settings(scene / "settings.txt")
    out = tmp_path / "out"
    res = cli("solve", scene / "settings.txt", "-o", out, "--quiet")
    assert res.exit_code == 0, res.stderr
    warnings = [line for line in res.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 1 and f"TILE_SIZE {s.tile_size:g} gives tiles of" in warnings[0], res.stderr
    fits = float(warnings[0].split("; TILE_SIZE ")[1].split()[0])
    assert fits < s.tile_size
    monkeypatch.delenv("LUNARALBEDO_BLOCK_MB")
    res = cli("solve", scene / "settings.txt", "-o", tmp_path / "out2", "--quiet")
    assert res.exit_code == 0 and "warning" not in res.stderr
