"""Files of the camera-response recovery: ``response.csv``, exposure-time tables, plots.

``response.csv`` has the columns ``dn,g`` (the inverse response at every DN of the
fitted range, increasing, normalised to g(128) = 1) followed by ``se_log_g`` (standard
error of ln g), ``count`` (observations at that DN) and ``free`` (1: a free level of the
fit; 0: interpolated because it had too few observations).  Readers need only ``dn,g``.
"""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..io.outputs import save_figure


def write_response_csv(path: Path, dn: np.ndarray, g: np.ndarray, se_log_g: np.ndarray, count: np.ndarray,
                       free: np.ndarray) -> None:
    lines = ["dn,g,se_log_g,count,free"]
    lines += [f"{int(z)},{v:.9g},{s:.6g},{int(c)},{int(f)}" for z, v, s, c, f in zip(dn, g, se_log_g, count, free)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def _rows(path: Path, what: str, reader) -> list:
    try:
        with open(path, newline="") as fh:
            return list(reader(fh))
    except OSError as exc:
        raise InputError(f"{path}: cannot read the {what} ({exc.strerror})") from None


def read_response_csv(path: str | Path, n_levels: int = 256) -> np.ndarray:
    """A response.csv as a float32 look-up table over 0..n_levels-1 (NaN at DN it does not list)."""
    path = Path(path)
    rows = _rows(path, "response table", csv.DictReader)
    if not rows or not {"dn", "g"} <= set(rows[0]):
        raise InputError(f"{path}: a response table needs the columns dn,g (as written by `lunaralbedo response`)")
    lut = np.full(n_levels, np.nan, np.float32)
    try:
        dn = np.array([int(r["dn"]) for r in rows])
        g = np.array([float(r["g"]) for r in rows])
    except (TypeError, ValueError):
        raise InputError(f"{path}: dn must be integers and g numbers") from None
    if dn.min() < 0 or dn.max() >= n_levels or len(np.unique(dn)) != len(dn):
        raise InputError(f"{path}: dn values must be distinct and within 0..{n_levels - 1}")
    order = np.argsort(dn)
    if not np.all(np.isfinite(g)) or g.min() <= 0 or np.any(np.diff(g[order]) < 0):
        raise InputError(f"{path}: g must be positive and non-decreasing in dn (eq. 7 of Kim et al.)")
    lut[dn] = g
    return lut


def read_exposure_table(path: str | Path) -> dict[str, float]:
    """``{name: exposure}`` from a CSV whose first column names the image and which has an ``exposure`` column.

    Accepts ``image,exposure`` (``lunaralbedo response``) and the solver's ``key,exposure,...``;
    other columns are ignored.
    """
    path = Path(path)
    rows = _rows(path, "exposure table", csv.reader)
    if not rows or "exposure" not in [c.strip() for c in rows[0]]:
        raise InputError(f"{path}: an exposure table needs a header with an 'exposure' column (e.g. image,exposure)")
    col = [c.strip() for c in rows[0]].index("exposure")
    out = {}
    for n, row in enumerate(rows[1:], start=2):
        if not row or not "".join(row).strip():
            continue
        try:
            t = float(row[col])
        except (IndexError, ValueError):
            raise InputError(f"{path}: line {n}: no numeric exposure") from None
        if not np.isfinite(t) or t <= 0:
            raise InputError(f"{path}: line {n}: exposure must be positive, got {row[col]}")
        out[row[0].strip()] = t
    return out


def write_exposure_table(path: Path, names: Sequence[str], exposure: np.ndarray) -> None:
    atomic_write_text(path, "image,exposure\n" + "".join(f"{n},{t:.9g}\n" for n, t in zip(names, exposure)))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_response(path: Path, dn: np.ndarray, g: np.ndarray, g_initial: np.ndarray, se_log_g: np.ndarray,
                  extra: dict | None = None) -> None:
    """Inverse response g(z) (log scale) with the initial guess of eq. 13 and a 2-sigma band (as fig. 8 of Kim et al.)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    se = np.nan_to_num(se_log_g)
    ax.fill_between(dn, g * np.exp(-2 * se), g * np.exp(2 * se), color="C0", alpha=0.25, lw=0, label="±2 s.e.")
    ax.semilogy(dn, g_initial, "--", color="grey", label="initial guess (eq. 13)")
    ax.semilogy(dn, g, "-", color="C0", label="maximum likelihood (eq. 8)")
    for label, (x, y, style) in (extra or {}).items():
        ax.semilogy(x, y, style, label=label, lw=1)
    ax.set_xlabel("pixel value z (DN)")
    ax.set_ylabel("sensor exposure g(z), g(128) = 1")
    ax.set_title("Inverse camera response")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def plot_loglik(path: Path, loglik: Sequence[float], n_juggle: int) -> None:
    """Log-likelihood (eq. 8) per pass: the closed-form alternation, then the Newton iterations."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ll = np.asarray(loglik)
    it = np.arange(1, len(ll) + 1)
    ax.plot(it[:n_juggle], ll[:n_juggle], "o-", ms=3, label="alternation (10), (11), (13)")
    ax.plot(it[n_juggle:], ll[n_juggle:], "s-", ms=3, label="Newton on the profile likelihood")
    ax.set_xlabel("iteration")
    ax.set_ylabel("log-likelihood L (eq. 8)")
    ax.set_ylim(np.percentile(ll, 5) - 0.05 * abs(np.ptp(ll[n_juggle - 1:])), ll.max() + 0.05 * abs(np.ptp(ll[n_juggle - 1:])) + 1)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def plot_residuals(path: Path, dn: np.ndarray, residuals: dict) -> None:
    """Per-DN residual ln(mu/g): mean and standard deviation, with the observation count."""
    plt = _plt()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(5.5, 4.5), sharex=True, gridspec_kw=dict(height_ratios=(2, 1)))
    m, s = residuals["bias_log"], residuals["std_log"]
    a1.fill_between(dn, m - s, m + s, color="C1", alpha=0.3, lw=0, label="±1 std")
    a1.plot(dn, m, "-", color="C1", label="mean ln(μ/g)")
    a1.axhline(0, color="k", lw=0.5)
    a1.set_ylabel("residual ln(μ / g(z))")
    a1.set_title(f"Residuals: χ²/dof {residuals['chi2_per_dof']:.3g}, RMS {residuals['rms_log']:.3g} (log)")
    a1.legend(fontsize=8)
    a2.semilogy(dn, np.maximum(residuals["count"], 0.5), "-", color="grey")
    a2.set_ylabel("observations")
    a2.set_xlabel("pixel value z (DN)")
    fig.tight_layout()
    save_figure(fig, path)
