"""Faults during a run: a Dask worker killed mid-solve, the disk filling up, Ctrl-C.

Each leaves a clean failure (one line, exit 3 or 130, no traceback, no result tiles,
the checkpoint kept) and ``--resume`` then finishes with the same bytes as an
uninterrupted run.
"""
from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from distributed import WorkerPlugin

from bad_input_common import assert_clean_failure, cli
from lunaralbedo.engine.solve import solve
from lunaralbedo.simulate import SceneSpec, render_scene
from test_engine import same_results

STATE = Path("checkpoint") / "state.json"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("faults")
    render_scene(d, SceneSpec(n_images=4, image_px=80, tile_size=0.25, max_num_iter=4, seed=21))
    return d


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "out"
    solve(scene / "settings.txt", out=out, workers=1)
    return out


def assert_only_checkpoint(out: Path) -> None:
    """A failed run leaves its marker and the checkpoint, and no result (partial or not)."""
    assert (out / "checkpoint").is_dir(), "the checkpoint must be kept for --resume"
    assert sorted(p.name for p in out.iterdir()) == [".lunaralbedo", "checkpoint"]


def resume(scene: Path, out: Path):
    return cli("solve", scene / "settings.txt", "-o", out, "--quiet", "--workers", "1", "--resume")


class KillOnce(WorkerPlugin):
    """Worker plugin: SIGKILL the worker's own process when a task starts after the
    solve's first checkpoint exists (so mid-solve), once per test (a marker file)."""

    name = "lunaralbedo-kill-once"

    def __init__(self, out: Path, marker: Path):
        self.out, self.marker = str(out), str(marker)

    def transition(self, key, start, finish, **kwargs):
        if finish == "executing" and os.path.exists(os.path.join(self.out, str(STATE))) and not os.path.exists(self.marker):
            Path(self.marker).touch()
            os.kill(os.getpid(), signal.SIGKILL)


@pytest.mark.parametrize("allowed_failures", [3, 0], ids=["dask-retries", "run-fails"])
def test_worker_killed_mid_solve(scene, reference, tmp_path, dask_cluster, allowed_failures):
    import cloudpickle
    from distributed import Client

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import this test module
    out = tmp_path / "out"
    client = Client(dask_cluster)
    old = dask_cluster.scheduler.allowed_failures
    dask_cluster.scheduler.allowed_failures = allowed_failures
    client.register_plugin(KillOnce(out, tmp_path / "killed"), name=KillOnce.name)
    try:
        res = cli("solve", scene / "settings.txt", "-o", out, "--quiet", "--scheduler", dask_cluster.scheduler_address)
    finally:
        dask_cluster.scheduler.allowed_failures = old
        client.unregister_worker_plugin(KillOnce.name)
        client.wait_for_workers(2, timeout=60)
        client.close()
    assert (tmp_path / "killed").exists(), "no worker was killed"
    if allowed_failures:  # Dask restarts the worker and reruns its task: same result
        assert res.exit_code == 0, res.stderr
    else:
        msg = assert_clean_failure(res, 3, "worker", "--resume")
        assert "cancel" not in msg.lower()
        assert_only_checkpoint(out)
        r = resume(scene, out)
        assert r.exit_code == 0, r.stderr
    same_results(reference, out)


@pytest.mark.parametrize("stage", ["finalise", "prepare"])
def test_disk_full_while_writing_tiles(scene, reference, tmp_path, monkeypatch, stage):
    """A tile writer that fails with ENOSPC on the second tile: exit 3, naming the file (finalise's albedo and
    error tiles) or the tile's cache entry (the DEM and weight-sum tiles, written with it), no result tiles,
    resumable."""
    from lunaralbedo.io.geotiff import GeoTiffRows

    real, calls = GeoTiffRows.write, []
    kind = {"finalise": "error", "prepare": "DEM"}[stage]

    def failing(self, rows, row0, col0=0):  # the tile outputs are written a block of rows at a time
        path = Path(self.path)
        if kind in (path.parent.name, path.stem):  # error/tile_*.tif, or DEM.tif in a cache entry
            if path not in calls:
                calls.append(path)
            if len(calls) == 2:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(self, rows, row0, col0)

    monkeypatch.setattr(GeoTiffRows, "write", failing)
    out = tmp_path / "out"
    res = cli("solve", scene / "settings.txt", "-o", out, "--quiet", "--workers", "1")
    line = assert_clean_failure(res, 3, "no space left")
    assert str(calls[1]) in line if stage == "finalise" else re.search(rf"{out}/checkpoint/cache/tile_\w+: ", line), line
    assert_only_checkpoint(out)
    monkeypatch.undo()
    r = resume(scene, out)
    assert r.exit_code == 0, r.stderr
    resumed = json.loads((out / "report.json").read_text())["resumed"]
    assert resumed["tiles_written_before" if stage == "finalise" else "tiles_prepared_before"] >= 1
    same_results(reference, out)


def test_an_atomic_write_that_fails_without_a_file_name_names_its_target(tmp_path, monkeypatch):
    """Python's error for a short write (a full disk) names no file: the atomic writer names the target, so
    the user is told which file could not be written, and leaves no temporary behind."""
    from lunaralbedo.errors import DiskFullError, typed_error
    from lunaralbedo.io import atomic

    def full(self, text, *args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic.Path, "write_text", full)
    target = tmp_path / "checkpoint" / "state.json"
    with pytest.raises(OSError) as err:
        atomic.atomic_write_text(target, "{}")
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(target)
    assert list(target.parent.iterdir()) == []
    typed = typed_error(err.value)
    assert isinstance(typed, DiskFullError) and str(typed).startswith(f"{target}: no space left")


def _unshare_works() -> bool:
    if not shutil.which("unshare"):
        return False
    r = subprocess.run(["unshare", "-rm", "true"], capture_output=True)
    return r.returncode == 0


FULL_DISK = """
set -u
mount -t tmpfs -o size={size}k tmpfs {mnt} || exit 99
{python} -m lunaralbedo.cli solve {settings} -o {mnt}/out --quiet --workers 1 2> {log}
echo $? > {rc}
cp -a {mnt}/out {copy} 2>/dev/null || true
"""


@pytest.mark.skipif(not _unshare_works(), reason="needs `unshare -rm` (user + mount namespaces) for a small tmpfs")
@pytest.mark.parametrize("size_kb", [150, 600, 1400])
def test_disk_full_on_a_small_filesystem(scene, reference, tmp_path, size_kb):
    """A real full file system: a small tmpfs (in a private mount namespace) as OUTDIR's disk.  The sizes
    fill it in different writes of the cache (blocks, GeoTIFFs, ``meta.json``: at 600 KiB a ``meta.json``
    whose write error named no file was once reported without one); the scene needs ~2.2 MB."""
    mnt, copy = tmp_path / "mnt", tmp_path / "copy"
    mnt.mkdir()
    script = FULL_DISK.format(size=size_kb, mnt=mnt, python=sys.executable, settings=scene / "settings.txt",
                              log=tmp_path / "log", rc=tmp_path / "rc", copy=copy)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parents[1]), os.environ.get("PYTHONPATH", "")])}
    subprocess.run(["unshare", "-rm", "sh", "-c", script], check=True, env=env)
    log = (tmp_path / "log").read_text()
    assert (tmp_path / "rc").read_text().strip() == "3", log
    lines = log.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {mnt}/out/checkpoint/") and "no space left" in lines[0], log
    assert_only_checkpoint(copy)
    # the copy on a roomy disk resumes to the same bytes
    r = resume(scene, copy)
    assert r.exit_code == 0, r.stderr
    same_results(reference, copy)


def test_ctrl_c_leaves_a_resumable_state(scene, reference, tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "lunaralbedo.cli", "solve", str(scene / "settings.txt"), "-o", str(out), "--workers", "1", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    while not (out / STATE).exists() or json.loads((out / STATE).read_text() or "{}").get("iteration", 0) < 1:
        assert proc.poll() is None, "finished before it could be interrupted: " + proc.stderr.read()
        assert time.monotonic() - t0 < 60
        time.sleep(0.002)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: interrupted") and "--resume" in lines[0], err
    assert_only_checkpoint(out)
    r = resume(scene, out)
    assert r.exit_code == 0, r.stderr
    assert json.loads((out / "report.json").read_text())["resumed"]["iterations_done_before"] >= 1
    same_results(reference, out)
