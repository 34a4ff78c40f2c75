"""Frame-camera and line-scanner models: ground point <-> cube pixel (pure NumPy math).

Pixel coordinates are ISIS's: 1-based, the centre of the first pixel is (1, 1),
``sample`` along a line, ``line`` down the image.  Positions are body-fixed km.

The ephemeris is sampled once on a time grid (a single time for a frame camera,
``n_knots`` times across the image for a line scanner) and interpolated linearly
between knots, so projecting millions of points costs no SPICE calls.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .optics import FocalPlane


@dataclass
class DetectorMap:
    """Cube pixel -> detector pixel: AlphaCube crop, summing and first detector pixel.

    ``alpha = a0 + (beta - 0.5) * a_scale`` per axis; detector coordinate
    ``= start + (alpha - 0.5) * summing - 0.5``.
    """

    sample_alpha: tuple[float, float] = (0.5, 1.0)  # (a0, scale)
    line_alpha: tuple[float, float] = (0.5, 1.0)
    sample_summing: float = 1.0
    line_summing: float = 1.0
    start_sample: float = 1.0
    start_line: float = 1.0

    @classmethod
    def from_alpha_cube(cls, alpha_cube, sample_summing: float = 1.0, line_summing: float = 1.0,
                        start_sample: float = 1.0) -> "DetectorMap":
        """The map of a cube whose label's AlphaCube is ``alpha_cube`` (``IsisLabel.alpha_cube()``, None: no crop)."""
        if alpha_cube is None:
            return cls(sample_summing=sample_summing, line_summing=line_summing, start_sample=start_sample)
        s0, l0, s1, l1, ns, nl = alpha_cube
        return cls((s0, (s1 - s0) / ns), (l0, (l1 - l0) / nl), sample_summing, line_summing, start_sample, 1.0)

    def alpha(self, sample, line):
        return (self.sample_alpha[0] + (np.asarray(sample) - 0.5) * self.sample_alpha[1],
                self.line_alpha[0] + (np.asarray(line) - 0.5) * self.line_alpha[1])

    def beta(self, alpha_s, alpha_l):
        return ((alpha_s - self.sample_alpha[0]) / self.sample_alpha[1] + 0.5,
                (alpha_l - self.line_alpha[0]) / self.line_alpha[1] + 0.5)

    def detector_sample(self, alpha_s):
        return self.start_sample + (alpha_s - 0.5) * self.sample_summing - 0.5

    def alpha_sample(self, det_s):
        return (det_s + 0.5 - self.start_sample) / self.sample_summing + 0.5

    def detector_line(self, alpha_l):
        return self.start_line + (alpha_l - 0.5) * self.line_summing - 0.5

    def alpha_line(self, det_l):
        return (det_l + 0.5 - self.start_line) / self.line_summing + 0.5


@dataclass
class LineTiming:
    """Line-scanner timing: parent (alpha) line ``L`` is exposed at ``et0 + (L - 0.5) * rate`` (s)."""

    et0: float
    rate: float

    def et(self, alpha_line):
        return self.et0 + (np.asarray(alpha_line, dtype=np.float64) - 0.5) * self.rate


class CameraModel:
    """A frame camera (``timing is None``) or a line scanner on a sampled ephemeris.

    ``ephemeris`` provides ``spacecraft(et)`` and ``camera_to_body(et)``;
    ``shape`` is the cube's ``(lines, samples)``; ``frame_et`` the exposure time of
    a frame camera (s, TDB).
    """

    def __init__(self, focal: FocalPlane, detector: DetectorMap, shape, ephemeris,
                 frame_et: float | None = None, timing: LineTiming | None = None, n_knots: int = 33):
        self.focal = focal
        self.detector = detector
        self.lines, self.samples = int(shape[0]), int(shape[1])
        self.timing = timing
        if timing is None:
            if frame_et is None:
                raise ValueError("a frame camera needs frame_et")
            self.knots = np.array([float(frame_et)])
        else:
            l0 = self.detector.alpha(1.0, 0.5)[1]
            l1 = self.detector.alpha(1.0, self.lines + 0.5)[1]
            pad = 0.05 * (l1 - l0) + 2
            self.knot_lines = np.linspace(l0 - pad, l1 + pad, n_knots)
            self.knots = timing.et(self.knot_lines)
        self.positions = np.asarray(ephemeris.spacecraft(self.knots), dtype=np.float64).reshape(-1, 3)
        self.rotations = np.asarray(ephemeris.camera_to_body(self.knots), dtype=np.float64).reshape(-1, 3, 3)

    @property
    def is_line_scanner(self) -> bool:
        return self.timing is not None

    @property
    def center_et(self) -> float:
        """Exposure time (s, TDB) of the cube's centre pixel (the ``campt`` default)."""
        if self.timing is None:
            return float(self.knots[0])
        return float(self.timing.et(self.detector.alpha((self.samples + 1) / 2, (self.lines + 1) / 2)[1]))

    def pixel_et(self, sample, line):
        """Exposure time (s, TDB) of cube pixels (the frame time for a frame camera)."""
        if self.timing is None:
            return np.full(np.broadcast(np.asarray(sample), np.asarray(line)).shape, float(self.knots[0]))
        return self.timing.et(self.detector.alpha(sample, line)[1])

    # -- state at an alpha line (line scanner) or the frame time ---------------------
    def _state(self, alpha_line):
        if self.timing is None:
            shape = np.shape(alpha_line)
            return np.broadcast_to(self.positions[0], shape + (3,)), np.broadcast_to(self.rotations[0], shape + (3, 3))
        x = np.asarray(alpha_line, dtype=np.float64)
        i = np.clip(np.searchsorted(self.knot_lines, x) - 1, 0, len(self.knot_lines) - 2)
        u = ((x - self.knot_lines[i]) / (self.knot_lines[i + 1] - self.knot_lines[i]))
        pos = self.positions[i] + (self.positions[i + 1] - self.positions[i]) * u[..., None]
        rot = self.rotations[i] + (self.rotations[i + 1] - self.rotations[i]) * u[..., None, None]
        return pos, rot

    # -- image -> ground ------------------------------------------------------------
    def rays(self, sample, line):
        """Origins (km) and unit directions (body-fixed) of the rays through cube pixels."""
        sample = np.asarray(sample, dtype=np.float64)
        line = np.asarray(line, dtype=np.float64)
        a_s, a_l = self.detector.alpha(sample, line)
        ds = self.detector.detector_sample(a_s) - self.focal.origin_sample
        if self.timing is None:
            dl = self.detector.detector_line(a_l) - self.focal.origin_line
        else:
            dl = np.full(np.shape(a_l), 0.0 - self.focal.origin_line)
        pos, rot = self._state(a_l)
        look = np.einsum("...ij,...j->...i", rot, self.focal.look(ds, dl))
        return np.array(pos), look / np.linalg.norm(look, axis=-1, keepdims=True)

    # -- ground -> image --------------------------------------------------------------
    def _project_at(self, points, alpha_line):
        pos, rot = self._state(alpha_line)
        v = np.einsum("...ji,...j->...i", rot, points - pos)  # body -> camera (transpose)
        return self.focal.project(v)

    def ground_to_image(self, points, iterations: int = 12, clip: bool = True):
        """Cube ``(sample, line)`` (1-based) of body-fixed points ``(..., 3)`` km; NaN when not imaged.

        With ``clip=False`` points just outside the cube keep their coordinates (NaN only
        behind the camera, or for a line scanner beyond its padded time range).
        """
        points = np.asarray(points, dtype=np.float64)
        if self.timing is None:
            ds, dl = self._project_at(points, np.zeros(points.shape[:-1]))
            a_s = self.detector.alpha_sample(ds + self.focal.origin_sample)
            a_l = self.detector.alpha_line(dl + self.focal.origin_line)
        else:
            a_l = self._find_lines(points, iterations)
            ds, _ = self._project_at(points, a_l)
            a_s = self.detector.alpha_sample(ds + self.focal.origin_sample)
        s, l = self.detector.beta(a_s, a_l)
        if not clip:
            return s, l
        inside = (s >= 0.5) & (s <= self.samples + 0.5) & (l >= 0.5) & (l <= self.lines + 0.5)
        return np.where(inside, s, np.nan), np.where(inside, l, np.nan)

    def _line_residual(self, points, alpha_line):
        _, dl = self._project_at(points, alpha_line)
        return dl - (0.0 - self.focal.origin_line)

    def _find_lines(self, points, iterations):
        """Per point, the alpha line whose exposure sees it (coarse scan, then secant steps)."""
        grid = self.knot_lines[::4] if len(self.knot_lines) > 9 else self.knot_lines
        res = np.stack([self._line_residual(points, np.full(points.shape[:-1], g)) for g in grid], axis=0)
        sign_change = np.signbit(res[:-1]) != np.signbit(res[1:])
        sign_change &= np.isfinite(res[:-1]) & np.isfinite(res[1:])
        k = np.argmax(sign_change, axis=0)
        found = np.any(sign_change, axis=0)
        lo, hi = grid[k], grid[k + 1]
        idx = np.indices(k.shape)
        r_lo, r_hi = res[(k,) + tuple(idx)], res[(k + 1,) + tuple(idx)]
        with np.errstate(invalid="ignore", divide="ignore"):
            x = lo - r_lo * (hi - lo) / (r_hi - r_lo)
        x = np.where(found, x, np.nan)
        for _ in range(iterations):
            r = self._line_residual(points, x)
            r2 = self._line_residual(points, x + 0.5)
            with np.errstate(invalid="ignore", divide="ignore"):
                step = r * 0.5 / (r2 - r)
            x = x - np.clip(np.nan_to_num(step), -50.0, 50.0)
            if np.nanmax(np.abs(step), initial=0.0) < 1e-4:
                break
        return x
