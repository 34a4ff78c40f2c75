"""Run-level outputs: exposure table, fitted model parameters, report, plots, weight profiles.

All writes are atomic.  Plots use matplotlib's non-interactive Agg backend.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import numpy as np

from .atomic import atomic_path, atomic_write_text


def write_exposure_csv(path: Path, keys: Sequence[str], exposure: np.ndarray, initial: np.ndarray) -> None:
    """``key,exposure,initial_exposure`` per image (exposure: the solved T^k)."""
    lines = ["key,exposure,initial_exposure"]
    lines += [f"{k},{t:.9g},{t0:.9g}" for k, t, t0 in zip(keys, exposure, initial)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_exposure_csv(path: Path) -> dict[str, float]:
    """``{key: exposure}`` from an ``exposure.csv``."""
    rows = Path(path).read_text().splitlines()[1:]
    return {r.split(",")[0]: float(r.split(",")[1]) for r in rows if r.strip()}


def write_phase_csv(path: Path, names: Sequence[str], history: Sequence[Sequence[float]]) -> None:
    """``iteration,<name>,...``: the fitted parameters per iteration (iteration 0 is the initial value)."""
    lines = [",".join(["iteration", *names])] + [",".join([str(i), *(f"{v:.9g}" for v in c)]) for i, c in enumerate(history)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def write_json(path: Path, data: dict) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=False, default=_jsonable) + "\n")


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj)}")


def write_weight_profile(path: Path, profile) -> None:
    """Per-image weight profile: 4 lines (row first/last valid column, column first/last valid row)."""
    lines = [" ".join(str(int(v)) for v in arr) for arr in (profile.row_first, profile.row_last, profile.col_first, profile.col_last)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def plot_exposures(path: Path, keys: Sequence[str], exposure: np.ndarray, initial: np.ndarray, haze=None) -> None:
    """Exposure per image (as Nefian et al. (LPSC), fig. 4): solved and initial, normalised to their mean; with ``haze``
    (FLOAT_HAZE 1, DRG units) a second panel beside it with each image's haze."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    width = max(6, 0.18 * len(keys))
    fig, axes = plt.subplots(1, 1 if haze is None else 2, figsize=(width * (1 if haze is None else 2), 3.5), squeeze=False)
    ax = axes[0, 0]
    x = np.arange(len(keys))
    ax.plot(x, exposure / np.mean(exposure), "o-", label="solved")
    ax.plot(x, initial / np.mean(initial), ".", color="grey", label="initial")
    ax.set_xticks(x)
    ax.set_xticklabels(keys, rotation=90, fontsize=6)
    ax.set_ylabel("relative exposure T / mean(T)")
    ax.set_title("Estimated relative exposure times")
    ax.legend()
    if haze is not None:
        hx = axes[0, 1]
        hx.bar(x, haze, color="tab:orange")
        hx.axhline(0, color="grey", lw=0.5)
        hx.set_xticks(x)
        hx.set_xticklabels(keys, rotation=90, fontsize=6)
        hx.set_ylabel("haze H (DRG units)")
        hx.set_title("Estimated haze per image (I = T A R + H)")
    fig.tight_layout()
    save_figure(fig, path)


def write_haze_csv(path: Path, keys: Sequence[str], haze: np.ndarray) -> None:
    """``key,haze`` per image (FLOAT_HAZE 1; the DRGs' units: DN, or I/F for calibrated inputs)."""
    lines = ["key,haze"] + [f"{k},{h:.9g}" for k, h in zip(keys, haze)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def plot_cost(path: Path, q: Sequence[float]) -> None:
    """Cost Q (eq. 1) per iteration, log scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from matplotlib.ticker import MaxNLocator

    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.semilogy(np.arange(1, len(q) + 1), q, "o-")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration (Q before its update)")
    ax.set_ylabel("cost Q (eq. 1)")
    ax.set_title("Convergence")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig, path: Path) -> None:
    """Write a matplotlib figure as PNG (110 dpi) atomically and close it."""
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
