"""Outputs of ``jitreg``: ``PREFIX.json``, ``PREFIX-lines.csv``, ``PREFIX-jitter.png`` and ASP's per-row log.

All writes are atomic.  The ASP log follows ``lronacjitreg``'s layout (ASP
``src/asp/Tools/lronacjitreg.cc``): a commented header, one row per correlated line
``row, line offset, sample offset Count = n Std = s`` and the ``Average Sample
Offset`` / ``Average Line Offset`` lines that ``lronac2mosaic.py`` parses.  ASP's
offsets map LE (its left/FROM image) pixels onto RE (MATCH) pixels, so they are
the negatives of this package's ``sample_offset``/``line_offset``.  ASP averages
per-pixel disparities of a row; here a row is a correlation window (``Count`` =
its overlap columns, ``Std`` = 0 because one translation is fitted per window).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write_text
from ..io.outputs import save_figure
from .jitreg import JitterResult


def _g(v: float, width: int = 0) -> str:
    """C++ ``setprecision(4)`` default-float formatting (4 significant digits)."""
    return f"{float(v):{width}.4g}"


def lines_csv(result: JitterResult) -> str:
    """``line,sample_offset,line_offset,correlation`` per good window (0-based centre line)."""
    rows = ["line,sample_offset,line_offset,correlation"]
    for k in np.flatnonzero(result.good):
        rows.append(f"{int(result.lines[k])},{result.sample_offset[k]:.5f},{result.line_offset[k]:.5f},"
                    f"{result.correlation[k]:.4f}")
    return "\n".join(rows) + "\n"


def asp_log(result: JitterResult, le_name: str, re_name: str) -> str:
    """The per-row log of ASP ``lronacjitreg --output-log`` (ASP sign convention)."""
    lines, samples = result.shape
    c0, c1 = result.columns
    out = ["#       Lronacjitreg ISIS Application Results", "#    Coordinates are (Sample, Line) unless indicated", "#",
           "#    ****  Image Input Information ****"]
    for tag, name in (("FROM: ", le_name), ("MATCH:", re_name)):
        out += [f"#  {tag} {name}", f"#    Lines:       {lines}", f"#    Samples:     {samples}",
                f"#    SampOffset:  {c0}", f"#    TopLeft:     {c0:7d} {0:7d}",
                f"#    LowerRight:  {c1:7d} {lines:7d}", ""]
    for k, row in enumerate(result.lines):
        ok = bool(result.good[k])
        dy = -result.line_offset[k] if ok else 0.0
        dx = -result.sample_offset[k] if ok else 0.0
        out.append(f"{int(row):5d}, {_g(dy, 6)}, {_g(dx, 6)} Count = {(c1 - c0) if ok else 0:3d} Std = {_g(0.0, 4)}")
    s = result.summary()
    out += ["", "#  **** Registration Data ****", "#   RegFile: ", f"#   OverlapSize:      {c1 - c0:7d} {lines:7d}",
            "#   Sample Spacing:   1", f"#   Line Spacing:     {result.step}",
            f"#   Columns, Rows:    {c1 - c0} {result.window}", "#   Corr. Algorithm:  CROSS_CORRELATION"]
    if result.n_good:
        out += ["#   Using IpFind result only:   0",
                f"#   Average Sample Offset: {_g(-s['sample_offset'])}  StdDev: {_g(s['sample_offset_std'])}",
                f"#   Average Line Offset:   {_g(-s['line_offset'])} StdDev: {_g(s['line_offset_std'])}"]
    else:
        out += ["#   Using IpFind result only:   0", "#   Average Sample Offset: NULL StdDev: NULL",
                "#   Average Line Offset:   NULL StdDev: NULL"]
    return "\n".join(out) + "\n"


def plot_jitter(path: Path, result: JitterResult, title: str = "LE/RE offset along the track") -> None:
    """Sample and line offset of every good window against its line (the jitter series)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = result.good
    fig, axes = plt.subplots(2, 1, figsize=(7, 4.2), sharex=True)
    for ax, v, name in ((axes[0], result.sample_offset, "sample offset (px)"), (axes[1], result.line_offset, "line offset (px)")):
        ax.plot(result.lines[g], v[g], ".", ms=2)
        ax.axhline(float(np.mean(v[g])) if g.any() else 0.0, color="k", lw=0.8)
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[1].set_xlabel("line (0-based row of the ideal-camera grid)")
    axes[0].set_title(title)
    fig.tight_layout()
    save_figure(fig, path)


def write_jitreg(prefix: str | Path, result: JitterResult, le: Path, re: Path, output_log: Path | None = None) -> dict:
    """Write ``PREFIX.json``, ``PREFIX-lines.csv``, ``PREFIX-jitter.png`` (and the ASP log); return the summary."""
    prefix = Path(prefix)
    summary = {"left": str(le), "right": str(re), **result.summary()}
    atomic_write_text(Path(f"{prefix}.json"), json.dumps(summary, indent=1) + "\n")
    atomic_write_text(Path(f"{prefix}-lines.csv"), lines_csv(result))
    plot_jitter(Path(f"{prefix}-jitter.png"), result)
    if output_log is not None:
        atomic_write_text(output_log, asp_log(result, str(le), str(re)))
    return summary


def read_offset(path: str | Path) -> tuple[float, float]:
    """``(sample_offset, line_offset)`` from a ``PREFIX.json`` written by :func:`write_jitreg`."""
    from ..errors import InputError

    path = Path(path)
    try:
        d = json.loads(path.read_text())
        return float(d["sample_offset"]), float(d["line_offset"])
    except FileNotFoundError:
        raise InputError(f"{path}: offset file not found") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a jitreg result (need sample_offset and line_offset: {exc})") from None
