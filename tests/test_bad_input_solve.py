"""Bad-input matrix of ``solve``, with 1 worker (in-process) and 2 (Dask workers of a local cluster).

Every case: exit 2, one line ``error: ...`` naming the culprit (not a cancellation or a
worker log), no traceback, no OUTDIR left behind; inputs unchanged.
"""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio

from bad_input_common import assert_clean_failure, cli, truncate
from lunaralbedo.simulate import SceneSpec, render_scene


@pytest.fixture(scope="module")
def base_scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad_solve")
    render_scene(d, SceneSpec(n_images=3, image_px=60, tile_size=0.25, max_num_iter=2, seed=5))
    return d


@pytest.fixture
def scene(base_scene, tmp_path):
    return Path(shutil.copytree(base_scene, tmp_path / "scene"))  # each case edits its own copy


@pytest.fixture(params=["1 worker", "2 workers"])
def engine(request) -> list[str]:
    if request.param == "1 worker":
        return ["--workers", "1"]
    return ["--scheduler", request.getfixturevalue("dask_cluster").scheduler_address]


def solve(scene: Path, engine, out: Path | None = None, settings: Path | None = None):
    out = out or scene.parent / "out"
    return cli("solve", settings or scene / "settings.txt", "-o", out, "--quiet", *engine), out


def digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()


def test_drg_pixels_cut_short(scene, engine):
    bad = scene / "DRG" / "SIM-IMG-001_drg.tif"
    truncate(bad, 0.6)
    before = digest(scene)
    res, out = solve(scene, engine)
    msg = assert_clean_failure(res, 2, bad, absent=out)
    assert "cancel" not in msg.lower()
    assert digest(scene) == before, "inputs must never be modified"


def test_dem_cut_short(scene, engine):
    bad = next((scene / "DEM").glob("*.tif"))
    truncate(bad, 0.5)
    res, out = solve(scene, engine)
    assert_clean_failure(res, 2, bad, absent=out)


def test_output_below_a_regular_file(scene, engine):
    blocker = scene.parent / "afile"
    blocker.write_text("x")
    res, _ = solve(scene, engine, out=blocker / "out")
    assert_clean_failure(res, 2, blocker)
    assert blocker.read_text() == "x"


def test_zero_byte_position_file(scene, engine):
    sun = scene / "meta" / "sunpos.txt"
    sun.write_bytes(b"")
    res, out = solve(scene, engine)
    assert_clean_failure(res, 2, sun, absent=out)


@pytest.mark.parametrize("line, words", [
    ("TILE_SIZE four", ("TILE_SIZE", "four")),
    ("MAX_NUM_ITER 2.5", ("MAX_NUM_ITER", "2.5")),
    ("SIMULATION_BOX 10:11:-5", ("SIMULATION_BOX",)),
    ("NO_SUCH_KEY 1", ("NO_SUCH_KEY",)),
])
def test_settings_with_wrong_types(scene, line, words):
    s = scene / "settings.txt"
    key = line.split()[0]
    s.write_text("".join(l for l in s.read_text().splitlines(keepends=True) if not l.startswith(key + " ")) + line + "\n")
    res, out = solve(scene, ["--workers", "1"])
    assert_clean_failure(res, 2, s, *words, absent=out)


def test_header_only_drg(scene):
    bad = scene / "DRG" / "SIM-IMG-002_drg.tif"
    truncate(bad, 200)
    res, out = solve(scene, ["--workers", "1"])
    assert_clean_failure(res, 2, bad, absent=out)


def test_malformed_position_file(scene):
    sc = scene / "meta" / "spacecraftpos.txt"
    sc.write_text("this is not a position file\n")
    res, out = solve(scene, ["--workers", "1"])
    assert_clean_failure(res, 2, sc, absent=out)


def test_nan_and_inf_pixels_are_left_out(scene):
    """NaN/Inf DRG pixels are no data: the run succeeds and no output holds an Inf."""
    p = scene / "DRG" / "SIM-IMG-001_drg.tif"
    with rasterio.open(p) as ds:  # rewritten as float32 (the sample DRGs are integers)
        v, profile = ds.read().astype(np.float32), ds.profile
    v[0, 10:20, :] = np.nan
    v[0, 30:40, :] = np.inf
    profile.update(dtype="float32", nodata=None)
    with rasterio.open(p, "w", **profile) as ds:
        ds.write(v)
    res, out = solve(scene, ["--workers", "1"])
    assert res.exit_code == 0, res.stderr
    alb = [rasterio.open(t).read(1) for t in sorted((out / "albedo").glob("*.tif"))]
    assert all(not np.isinf(a).any() for a in alb)
    assert sum(np.isfinite(a).sum() for a in alb) > 1000


def test_debug_prints_the_traceback(scene):
    truncate(scene / "DRG" / "SIM-IMG-001_drg.tif", 0.6)
    res = cli("--debug", "solve", scene / "settings.txt", "-o", scene.parent / "out", "--quiet", "--workers", "1")
    assert res.exit_code == 2
    assert "Traceback" in res.stderr and res.stderr.strip().splitlines()[-1].startswith("error: ")


def test_a_failed_run_folder_is_renamed_away_before_it_is_deleted(tmp_path, monkeypatch):
    """remove_tree: the folder is gone at once (renamed, then deleted: a task still writing by its old path
    finds nothing), nothing is left beside it, and where the rename fails it is deleted in place."""
    import os

    from lunaralbedo.io import atomic
    from lunaralbedo.io.cache import save_stack

    out = tmp_path / "out"
    (out / "checkpoint" / "cache").mkdir(parents=True)
    seen = []
    real = atomic.shutil.rmtree

    def rmtree(path, ignore_errors=False):
        seen.append(Path(path))
        with pytest.raises(FileNotFoundError):  # a late task of the failed run: its cache root is gone
            save_stack(out / "checkpoint" / "cache" / "tile_0E0N", {"x": np.zeros(3, np.float32)}, {})
        real(path, ignore_errors=ignore_errors)

    monkeypatch.setattr(atomic.shutil, "rmtree", rmtree)
    atomic.remove_tree(out)
    assert seen[0].name.startswith(atomic.TMP_PREFIX) and not out.exists() and list(tmp_path.iterdir()) == []
    (out / "x").mkdir(parents=True)
    monkeypatch.setattr(atomic.shutil, "rmtree", real)
    monkeypatch.setattr(os, "rename", lambda *a: (_ for _ in ()).throw(OSError("cross-device")))
    atomic.remove_tree(out)
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_worker_start_method(scene, monkeypatch):
    """LUNARALBEDO_WORKER_START names how local workers start (lunaralbedo.runtime): another value is bad input
    (exit 2) naming the variable and the value, before any worker starts or OUTDIR is made."""
    monkeypatch.setenv("LUNARALBEDO_WORKER_START", "fork")
    res, out = solve(scene, ["--workers", "2"])
    msg = assert_clean_failure(res, 2, "LUNARALBEDO_WORKER_START", "'fork'", absent=out)
    assert "forkserver, spawn" in msg


def test_dem_cut_short_under_two_local_workers_prints_one_line_and_no_worker_log(scene, tmp_path):
    """``lunaralbedo solve --workers 2`` in its own process, as a user runs it: the workers' stderr is the
    terminal's, so a worker's "Compute Failed ... Traceback" log of the typed error (or Dask's warning about
    a dashboard port held by another cluster, held here on purpose) would show before our line."""
    import socket
    import subprocess
    import sys

    bad = next((scene / "DEM").glob("*.tif"))
    truncate(bad, 0.5)
    holder = socket.socket()
    try:
        holder.bind(("", 8787))  # Dask's default HTTP port, as another cluster on the machine would hold it
        holder.listen()
    except OSError:
        pass  # already held by something else: the same situation
    try:
        proc = subprocess.run([sys.executable, "-m", "lunaralbedo", "solve", str(scene / "settings.txt"), "-o",
                               str(tmp_path / "out"), "--quiet", "--workers", "2"],
                              capture_output=True, text=True, timeout=300)
    finally:
        holder.close()
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == [proc.stderr.strip()] and proc.stderr.startswith(f"error: {bad}: "), proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout and not (tmp_path / "out").exists()
