"""The command line imports what a command uses: ``--help`` loads none of the heavy packages.

Each case runs a fresh interpreter (``python -m lunaralbedo ...``) and reads its ``sys.modules``
at exit, so nothing this test process imported can hide an import.
"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

HEAVY = ("numba", "llvmlite", "dask", "distributed", "cv2", "matplotlib", "scipy", "rasterio", "spiceypy", "pyproj")
COMMANDS = ("align", "backplanes", "export-kml", "export-web", "ingest", "jitreg", "nacmosaic", "photometry",
            "positions", "response", "simulate", "solve", "view")

_PROBE = """
import atexit, runpy, sys
atexit.register(lambda: sys.__stderr__.write("LOADED " + " ".join(m for m in {heavy!r} if m in sys.modules) + "\\n"))
sys.argv = ["lunaralbedo", *{args!r}]
runpy.run_module("lunaralbedo", run_name="__main__")
"""


def _loaded(*args: str) -> tuple[list[str], str]:
    env = dict(os.environ)
    # The package's SIMD set-up at import (lunaralbedo/simd.py) asks numba for the CPU's features; it is
    # not the command line's doing and is switched off here so that only the CLI's imports are measured.
    env["LUNARALBEDO_VECTOR_BITS"] = "256"
    proc = subprocess.run([sys.executable, "-c", _PROBE.format(heavy=HEAVY, args=args)],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    line = [ln for ln in proc.stderr.splitlines() if ln.startswith("LOADED")][-1]
    return line.split()[1:], proc.stdout


def test_help_lists_every_command_and_loads_no_heavy_package():
    loaded, out = _loaded("--help")
    assert loaded == []
    listed = out.split("Commands:")[1].split()
    assert all(name in listed for name in COMMANDS), out


@pytest.mark.parametrize("command", COMMANDS)
def test_a_commands_help_loads_no_heavy_package(command):
    loaded, out = _loaded(command, "--help")
    assert loaded == []
    assert out.startswith(f"Usage: lunaralbedo {command} ") or f"lunaralbedo {command}" in out.splitlines()[0], out


def test_a_command_still_loads_what_it_uses(tmp_path):
    """The probe sees imports: running a command (bad input, exit 2) loads what the command needs."""
    env = dict(os.environ, LUNARALBEDO_VECTOR_BITS="256")
    code = _PROBE.format(heavy=HEAVY, args=("solve", str(tmp_path / "missing.txt")))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "missing.txt" in proc.stderr
    loaded = [ln for ln in proc.stderr.splitlines() if ln.startswith("LOADED")][-1].split()[1:]
    assert "numba" in loaded
