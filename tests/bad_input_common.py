"""Shared checks of the bad-input matrix (tests/test_bad_input_*.py): exit code, one line, no traceback."""
from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from lunaralbedo.cli import main


def cli(*args: str):
    """Run ``lunaralbedo ARGS`` in-process; stderr separate from stdout."""
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_clean_failure(res, code: int, *culprits, absent: Path | None = None) -> str:
    """Exit ``code``, one ``error: ...`` line naming every culprit, no traceback, ``absent`` not created."""
    assert res.exit_code == code, (res.exit_code, res.stdout, res.stderr, res.exception)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert "Traceback" not in res.stderr + res.stdout
    for c in culprits:
        assert str(c) in lines[0], (c, lines[0])
    if absent is not None:
        assert not absent.exists(), f"{absent} was left behind by a failed run"
    return lines[0]


def truncate(path: Path, keep: float | int) -> None:
    """Cut ``path`` short, keeping a fraction (float) or a number of bytes (int)."""
    data = path.read_bytes()
    n = int(len(data) * keep) if isinstance(keep, float) else keep
    path.write_bytes(data[:n])
