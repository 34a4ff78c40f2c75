"""Shared by the resume tests: a solve stopped at the start of a given iteration, as Ctrl-C would stop it."""
from __future__ import annotations

import pytest

from lunaralbedo.engine import solve as solve_module
from lunaralbedo.engine.solve import solve


def solve_stopped_at_pass(monkeypatch, settings, out, n_tiles: int, stop_pass: int, **kwargs) -> None:
    """Run ``solve(settings, out=out, **kwargs)`` and stop it (KeyboardInterrupt) as its iteration ``stop_pass``
    (1-based) begins its first tile; the real tile task is back in place afterwards."""
    real, calls = solve_module.iterate_tile, []

    def stopped(*args, **kw):
        calls.append(1)
        if len(calls) == (stop_pass - 1) * n_tiles + 1:
            raise KeyboardInterrupt
        return real(*args, **kw)

    monkeypatch.setattr(solve_module, "iterate_tile", stopped)
    with pytest.raises(KeyboardInterrupt):
        solve(settings, out=out, **kwargs)
    monkeypatch.setattr(solve_module, "iterate_tile", real)
