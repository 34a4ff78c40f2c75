"""Forward models for the NAC tools' tests, docs and benchmarks (pure NumPy).

:class:`WaveTexture` is a band-limited random surface texture evaluated exactly at
any real position (a sum of plane waves with a power-law spectrum), so a shifted
image is rendered, not interpolated.  :func:`jitter_pair` renders an LE/RE pair on
one ideal-camera grid with a known, line-dependent offset.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class WaveTexture:
    """``sum_k a_k cos(kx_k x + ky_k y + phi_k)``; wavelengths between ``1/fmax`` and ``1/fmin`` pixels."""

    kx: np.ndarray
    ky: np.ndarray
    phase: np.ndarray
    amp: np.ndarray

    @classmethod
    def random(cls, rng, n_waves: int = 300, fmin: float = 0.01, fmax: float = 0.4, slope: float = 1.0) -> "WaveTexture":
        f = rng.uniform(fmin, fmax, n_waves)
        th = rng.uniform(0, 2 * np.pi, n_waves)
        k = 2 * np.pi * f
        return cls(k * np.cos(th), k * np.sin(th), rng.uniform(0, 2 * np.pi, n_waves), (f / fmin) ** -slope)

    def __call__(self, x, y, block: int = 40) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        out = np.zeros(np.broadcast(x, y).shape)
        for i in range(0, self.kx.size, block):
            sl = slice(i, i + block)
            arg = x[..., None] * self.kx[sl] + y[..., None] * self.ky[sl] + self.phase[sl]
            out += np.cos(arg) @ self.amp[sl]
        return out


def sinusoid(lines, mean: float, amplitude: float, period: float, phase: float = 0.0) -> np.ndarray:
    """A jitter series ``mean + amplitude * sin(2 pi line / period + phase)`` (pixels)."""
    return mean + amplitude * np.sin(2 * np.pi * np.asarray(lines, dtype=np.float64) / period + phase)


def jitter_pair(texture: WaveTexture, lines: int, samples: int, overlap: int, sample_offset, line_offset,
                noise: float = 0.01, rng=None):
    """LE (left part) and RE (right part) of one ground texture; NaN outside each CCD.

    ``sample_offset``/``line_offset`` (scalars or per-line arrays, pixels) follow the
    convention of :mod:`lunaralbedo.nac.jitreg`: RE(x, y) = ground(x + so(y), y + lo(y))
    while LE(x, y) = ground(x, y).  ``noise`` is Gaussian, relative to the texture's std.
    """
    rng = rng or np.random.default_rng(0)
    y, x = np.mgrid[0:lines, 0:samples].astype(np.float64)
    so = np.broadcast_to(np.asarray(sample_offset, dtype=np.float64), (lines,))[:, None]
    lo = np.broadcast_to(np.asarray(line_offset, dtype=np.float64), (lines,))[:, None]
    half = (samples + overlap) // 2
    le = np.full((lines, samples), np.nan)
    re = np.full((lines, samples), np.nan)
    le[:, :half] = texture(x[:, :half], y[:, :half])
    re[:, samples - half:] = texture(x[:, samples - half:] + so, y[:, samples - half:] + lo)
    scale = noise * np.nanstd(le)
    le += scale * rng.standard_normal(le.shape)
    re += scale * rng.standard_normal(re.shape)
    return le.astype(np.float32), re.astype(np.float32)
