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


# --------------------------------------------------------------------------- terrain and LOLA-like tracks
KM_PER_DEG = np.radians(1.0) * 1737.4


@dataclass
class Terrain:
    """Analytic heights (m) of craters on rolling plains around (lon0, lat0); local east/north in metres."""

    lon0: float
    lat0: float
    craters: np.ndarray  # (n, 4): x, y, radius, depth (m)
    hills: np.ndarray  # (m, 4): kx, ky (rad/m), phase, amplitude (m)

    @classmethod
    def random(cls, rng, lon0: float = 30.0, lat0: float = -10.0, size_m: float = 5000.0, n_craters: int = 40):
        half = size_m / 2
        cr = np.stack([rng.uniform(-half, half, n_craters), rng.uniform(-half, half, n_craters),
                       rng.uniform(80, 700, n_craters), np.zeros(n_craters)], axis=1)
        cr[:, 3] = cr[:, 2] * rng.uniform(0.1, 0.2, n_craters)
        k = 2 * np.pi / rng.uniform(800, 4000, 6)
        th = rng.uniform(0, 2 * np.pi, 6)
        hills = np.stack([k * np.cos(th), k * np.sin(th), rng.uniform(0, 2 * np.pi, 6), rng.uniform(5, 25, 6)], axis=1)
        return cls(lon0, lat0, cr, hills)

    def local(self, lon, lat):
        """East/north metres from (lon0, lat0) (equirectangular about the centre)."""
        x = (np.asarray(lon) - self.lon0) * KM_PER_DEG * 1000.0 * np.cos(np.radians(self.lat0))
        return x, (np.asarray(lat) - self.lat0) * KM_PER_DEG * 1000.0

    def lonlat(self, x, y):
        return (self.lon0 + np.asarray(x) / (KM_PER_DEG * 1000.0 * np.cos(np.radians(self.lat0))),
                self.lat0 + np.asarray(y) / (KM_PER_DEG * 1000.0))

    def height_xy(self, x, y):
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        h = np.zeros(np.broadcast(x, y).shape)
        for kx, ky, ph, a in self.hills:
            h += a * np.sin(kx * x + ky * y + ph)
        for cx, cy, r, d in self.craters:
            rr = np.hypot(x - cx, y - cy) / r
            h += -d * np.exp(-2.0 * rr ** 2) + 0.25 * d * np.exp(-((rr - 1.0) / 0.35) ** 2)
        return h

    def dem(self, size_m: float, res_m: float, shift_enu=(0.0, 0.0, 0.0)):
        """``(heights, transform)`` of a geographic DEM of the terrain moved by ``shift_enu`` (east, north, up m)."""
        from rasterio.transform import Affine

        n = int(round(size_m / res_m))
        dlon = res_m / (KM_PER_DEG * 1000.0 * np.cos(np.radians(self.lat0)))
        dlat = res_m / (KM_PER_DEG * 1000.0)
        west, north = self.lon0 - n / 2 * dlon, self.lat0 + n / 2 * dlat
        lon = west + (np.arange(n) + 0.5) * dlon
        lat = north - (np.arange(n) + 0.5) * dlat
        x, y = self.local(*np.meshgrid(lon, lat))
        h = self.height_xy(x - shift_enu[0], y - shift_enu[1]) + shift_enu[2]
        return h, Affine(dlon, 0, west, 0, -dlat, north)

    def tracks(self, rng, extent_m: float, spacing_m: float = 400.0, shot_m: float = 57.0, noise_m: float = 0.5):
        """LOLA-like points (lon, lat, radius km): near-N/S tracks of 5-spot shots across ``extent_m``."""
        half = extent_m / 2
        pts = []
        for x0 in np.arange(-half + spacing_m / 2, half, spacing_m):
            ys = np.arange(-half, half, shot_m) + rng.uniform(0, shot_m)
            tilt = rng.uniform(-0.05, 0.05)
            for dx, dy in ((0, 0), (-12, 12), (12, 12), (-12, -12), (12, -12)):
                x, y = x0 + dx + tilt * ys, ys + dy
                keep = (np.abs(x) < half) & (np.abs(y) < half)
                x, y = x[keep], y[keep]
                lon, lat = self.lonlat(x, y)
                h = self.height_xy(x, y) + noise_m * rng.standard_normal(x.size)
                pts.append(np.stack([lon, lat, 1737.4 + h / 1000.0], axis=1))
        return np.concatenate(pts)
