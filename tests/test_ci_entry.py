"""``.ci/run``: CI refuses to start, with one line, when the reference data is missing."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash to run .ci/run")
def test_ci_run_fails_with_one_line_without_the_reference_data(tmp_path):
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "make").write_text("#!/bin/sh\necho make-was-run\nexit 99\n")  # never the real suite from a test
    (fake / "make").chmod(0o755)
    env = dict(os.environ, LUNARALBEDO_SHARED=str(tmp_path / "no-shared"), PATH=f"{fake}:{os.environ['PATH']}")
    proc = subprocess.run(["bash", str(REPO / ".ci" / "run")], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: CI needs the reference data")
    assert str(tmp_path / "no-shared" / "photk_tests") in lines[0]
    (tmp_path / "no-shared" / "photk_tests").mkdir(parents=True)
    (tmp_path / "no-shared" / "realdata").mkdir()
    proc = subprocess.run(["bash", str(REPO / ".ci" / "run")], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 99 and "make-was-run" in proc.stdout  # with the data there, CI runs `make test`
