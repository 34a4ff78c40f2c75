r"""Cast shadows from a DEM: ground points whose ray to the Sun is blocked by terrain.

A ground point :math:`\mathbf{p}` (body-fixed, km; a DEM pixel centre at its height)
is in cast shadow when some point of its ray to the Sun,
:math:`\mathbf{q}(s) = \mathbf{p} + s\,\hat{\mathbf{l}}`, :math:`s > 0`, lies below the
terrain, i.e. :math:`|\mathbf{q}| < R + h(\lambda_q, \phi_q)/1000` with :math:`h` the
DEM height (metres, bilinear between pixel centres) under :math:`\mathbf{q}`.

The ray is marched in 3-D body-fixed coordinates, so the Moon's curvature is exact:
a ray leaving the ground horizontally is :math:`s^2/2R` above the sphere after
:math:`s` km (29 m at 10 km), which shortens long shadows (a 1 km wall under a Sun
1° high casts a 36 km shadow on the sphere, 57 km on a plane).  The march stops when
the ray is higher than the highest DEM point (it cannot be blocked any more) or
leaves the DEM grid (terrain beyond the grid cannot be seen: read the DEM with a
margin of :func:`shadow_reach_km` around the area of interest).

Frames and units: body-fixed km for positions, metres for heights above the
1737.4 km sphere, degrees for the north-up lon/lat grid (pixel centres at
``transform * (col + 0.5, row + 0.5)``).  Pure NumPy/numba, no I/O.
"""
from __future__ import annotations

import math
import threading

import numpy as np
from numba import njit

from ..constants import MOON_RADIUS_KM
from .march import _march_pixels, _trig_tables, extent, lit_cells

#: March step, in pixels of the DEM grid (half a pixel: no ridge of the bilinear DEM is stepped over
#: by more than half a pixel).
STEP_PX = 0.5
#: The ray must be this far below the bilinear terrain to count as blocked (metres): keeps the
#: first half-pixel steps on a smoothly curved slope (bilinear chords) from shadowing the point itself.
TOLERANCE_M = 0.5
#: Longest shadow searched for (km); terrain farther than this from a point is not considered.
MAX_REACH_KM = 150.0


def sun_elevation(points_km: np.ndarray, sun_km) -> np.ndarray:
    """Elevation (radians) of the Sun above the local horizon of the sphere at each point ``(..., 3)``."""
    p = np.asarray(points_km, dtype=np.float64)
    up = p / np.linalg.norm(p, axis=-1, keepdims=True)
    l = np.asarray(sun_km, dtype=np.float64) - p
    l /= np.linalg.norm(l, axis=-1, keepdims=True)
    return np.arcsin(np.clip(np.einsum("...i,...i->...", up, l), -1.0, 1.0))


def shadow_reach_km(relief_m: float, elevation_rad: float, max_km: float = MAX_REACH_KM) -> float:
    r"""Longest shadow (km) that terrain ``relief_m`` high can cast with the Sun ``elevation_rad`` high.

    On the sphere a ray rising at elevation :math:`\epsilon` is
    :math:`s\tan\epsilon + s^2/2R` above the start after :math:`s` km; the reach is the
    :math:`s` where that equals the relief, capped at ``max_km``.
    """
    h = max(float(relief_m), 0.0) / 1000.0
    t = math.tan(max(float(elevation_rad), 0.0))
    a = 1.0 / (2.0 * MOON_RADIUS_KM)
    s = (-t + math.sqrt(t * t + 4.0 * a * h)) / (2.0 * a)
    return min(s, max_km)


#: Cells (pixels) of the finest level of the maximum-height pyramid; each next level's cells are
#: :data:`LEVEL_RATIO` times larger (8, 64, 512 px ...), as long as they are smaller than the grid.
CELL_PX = 8
LEVEL_RATIO = 8
#: Safety factor on the terrain's slope bounds (second-order effects of the lon/lat grid over the reach).
SLOPE_SAFETY = 1.05
#: Lowest radius (km) a sample can have: below every lunar height (the ground-distance bounds use it).
LOW_RADIUS_KM = MOON_RADIUS_KM - 20.0

@njit(cache=True, nogil=True)
def _blocks(dem, cell):
    """Per ``cell`` x ``cell`` block, with its next row and column (the bilinear neighbours of its samples):
    the highest height (-inf: none) and the largest |dh| between x-, y-neighbours (inf if a height is NaN);
    and the lowest finite height of the block's own pixels (inf: none).

    Each row of blocks is reduced first down its rows, column by column (loops over whole rows
    that LLVM vectorises), then across each block's columns: the same maxima and minima, which
    are exact whatever their order.
    """
    h_, w_ = dem.shape
    ni, nj = (h_ + cell - 1) // cell, (w_ + cell - 1) // cell
    top, low = np.full((ni, nj), -np.inf), np.full((ni, nj), np.inf)
    gx, gy = np.zeros((ni, nj)), np.zeros((ni, nj))
    ctop, clow, cax, cay, cnan = np.empty(w_), np.empty(w_), np.empty(w_), np.empty(w_), np.empty(w_, np.uint8)
    for bi in range(ni):
        i0, i1 = bi * cell, min(bi * cell + cell, h_ - 1)  # rows i0..i1 (inclusive); own rows below i0 + cell
        ctop[:], clow[:], cax[:], cay[:], cnan[:] = -np.inf, np.inf, 0.0, 0.0, 0
        for i in range(i0, i1 + 1):
            own = i < i0 + cell
            below = i < i1
            row, nxt = dem[i], dem[i + 1 if below else i]
            for j in range(w_):  # column-wise over the block row (one vectorised loop): maxima, minima, NaN flags
                v = np.float64(row[j])
                cnan[j] |= np.uint8(v != v)
                ctop[j] = v if v > ctop[j] else ctop[j]
                clow[j] = v if (own and v < clow[j]) else clow[j]
                d = abs(np.float64(nxt[j]) - v)  # the y-pair (i, j)-(i + 1, j); 0 on the last row, which has none
                cay[j] = d if d > cay[j] else cay[j]
            for j in range(w_ - 1):  # the x-pairs (i, j)-(i, j + 1)
                d = abs(np.float64(row[j + 1]) - np.float64(row[j]))
                cax[j] = d if d > cax[j] else cax[j]
        for bj in range(nj):
            j0, j1 = bj * cell, min(bj * cell + cell, w_ - 1)  # columns j0..j1; own columns below j0 + cell
            t, lo, ax, ay, nan = -np.inf, np.inf, 0.0, 0.0, False
            for j in range(j0, j1 + 1):
                nan |= cnan[j] != 0
                if ctop[j] > t:
                    t = ctop[j]
                if j < j0 + cell and clow[j] < lo:
                    lo = clow[j]
                if j < j1 and cax[j] > ax:
                    ax = cax[j]
                if cay[j] > ay:
                    ay = cay[j]
            top[bi, bj], low[bi, bj] = t, lo
            gx[bi, bj], gy[bi, bj] = (np.inf, np.inf) if nan else (ax, ay)
    return top, gx, gy, low


@njit(cache=True, nogil=True)
def _coarsen(a, ratio):
    """Maximum over ``ratio`` x ``ratio`` blocks of ``a``."""
    ni, nj = (a.shape[0] + ratio - 1) // ratio, (a.shape[1] + ratio - 1) // ratio
    out = np.full((ni, nj), -np.inf)
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            out[i // ratio, j // ratio] = max(out[i // ratio, j // ratio], a[i, j])
    return out


@njit(cache=True, nogil=True)
def _dilate3(a):
    """Maximum over the 3 x 3 neighbourhood of every cell."""
    ni, nj = a.shape
    out = np.empty_like(a)
    for i in range(ni):
        for j in range(nj):
            m = -np.inf
            for ii in range(max(i - 1, 0), min(i + 2, ni)):
                for jj in range(max(j - 1, 0), min(j + 2, nj)):
                    m = max(m, a[ii, jj])
            out[i, j] = m
    return out


def _ground_px_km(transform, shape):
    """(smallest x pixel, y pixel) in km of ground at :data:`LOW_RADIUS_KM`; None when the grid reaches a pole."""
    far = max(abs(transform.f), abs(transform.f + transform.e * shape[0]))
    if far >= 89.0:
        return None
    km_per_deg = math.radians(1.0) * LOW_RADIUS_KM
    return km_per_deg * abs(transform.a) * math.cos(math.radians(far)), km_per_deg * abs(transform.e)


def _skip_steps(transform, shape, step_km: float, cell: int) -> int:
    """Steps that certainly stay within ``cell - 1`` pixels of the grid (0: never skip)."""
    px = _ground_px_km(transform, shape)
    if cell < 2 or px is None:
        return 0
    return max(0, int((cell - 1) / (1.01 * step_km / min(px))) - 1)


def _as_heights(dem_m) -> np.ndarray:
    """Heights as a C-contiguous float32 or float64 array (float32 is marched as is: the same answers, half the memory)."""
    dem = np.asarray(dem_m)
    return np.ascontiguousarray(dem, dtype=dem.dtype if dem.dtype in (np.float32, np.float64) else np.float64)


def _global_slope(blocks, px) -> float:
    """The largest slope bound (m/km, x 1.05) over all blocks; 0 (no bound) at a pole or with a NaN height."""
    if px is None or blocks[1].size == 0:
        return 0.0
    g = SLOPE_SAFETY * (float(blocks[1].max()) / px[0] + float(blocks[2].max()) / px[1])
    return g if math.isfinite(g) else 0.0


def slope_bound(dem_m, transform) -> float:
    r"""The steepest rise (m per km of ground) the bilinear terrain can have anywhere on the grid, x 1.05.

    A ray whose Sun is higher than this (:math:`\tan\epsilon \ge` bound / 1000) cannot be
    blocked: it rises at least :math:`s\sin\epsilon` over a ground distance of at most
    :math:`s\cos\epsilon`, along which the terrain rises at most bound x distance.  0 (no
    bound) when the grid reaches a pole or holds a NaN height (a hole breaks the bound: the
    terrain beyond it is not reached by a path of neighbours).
    """
    dem = _as_heights(dem_m)
    if min(dem.shape) < 2:
        return 0.0
    return _global_slope(_blocks(dem, CELL_PX), _ground_px_km(transform, dem.shape))


class MarchGrid:
    """What the march needs of one DEM grid, built once and shared by every image and pixel list.

    ``dem``: the heights (:func:`_as_heights`); the cosine and sine tables of the pixel
    centres; the step and number of steps; the highest height; the global :func:`slope_bound`;
    and, built on first need (:meth:`pyramid`), the maximum-height and slope pyramid.
    Cells are powers of 2 (:data:`CELL_PX`, :data:`LEVEL_RATIO`): the march finds them by shifts.

    ``band``: ``(grid_transform, row0, grid_height)`` when ``dem`` (on ``transform``) is rows
    ``row0:row0 + h`` of a taller grid: the step, the tables and the samples' coordinates are
    then the whole grid's (the same bits as its march), a ray leaving the band is lit.
    """

    def __init__(self, dem_m, transform, *, max_reach_km: float = MAX_REACH_KM, step_px: float = STEP_PX,
                 tolerance_m: float = TOLERANCE_M, band: tuple | None = None):
        self.dem = dem = _as_heights(dem_m)
        h, w = dem.shape
        self.transform = transform
        grid, self.row0, grid_h = band if band is not None else (transform, 0, h)
        self.grid_transform, self.banded = grid, band is not None
        lat_mid = math.radians(grid.f + grid.e * grid_h / 2.0)
        px_km = math.radians(1.0) * MOON_RADIUS_KM * min(abs(grid.a) * max(math.cos(lat_mid), 1e-3), abs(grid.e))
        self.step_km = step_px * px_km
        self.max_steps = max(1, int(math.ceil(max_reach_km / self.step_km)))
        self.blocks = _blocks(dem, CELL_PX)  # level 0 of the pyramid; its maxima give the global figures
        self.hmax = float(self.blocks[0].max()) if self.blocks[0].size else -np.inf
        self.empty = h < 2 or w < 2 or not np.isfinite(self.hmax)
        self.tables = _trig_tables(float(grid.c), float(grid.a), w, float(grid.f), float(grid.e), h, self.row0)
        self.slope = 0.0 if self.empty else _global_slope(self.blocks, _ground_px_km(transform, dem.shape))
        self.tolerance_m = float(tolerance_m)
        self._pyramid = None
        self._lock = threading.Lock()

    def pyramid(self):
        """Per level (cells of 8, 64, 512 ... px): the highest height and the slope bound (m/km, x 1.05) over the
        3 x 3 cells around each cell, flattened, with each level's offset, width, log2 cell size and skippable steps
        (built once, by the first thread that asks)."""
        with self._lock:
            if self._pyramid is None:
                self._pyramid = self._build_pyramid()
        return self._pyramid

    def _build_pyramid(self):
        dem, tr = self.dem, self.transform
        px = _ground_px_km(tr, dem.shape)
        tops, slopes, offs, widths, cells, skips = [], [], [0], [], [], []
        cell = CELL_PX
        if px is not None and not self.empty:
            top, gx, gy = self.blocks[:3]
            while cell < max(dem.shape):
                tops.append(_dilate3(top).ravel())
                slopes.append((SLOPE_SAFETY * (_dilate3(gx) / px[0] + _dilate3(gy) / px[1])).ravel())
                offs.append(offs[-1] + top.size)
                widths.append(top.shape[1])
                cells.append(int(round(math.log2(cell))))
                skips.append(_skip_steps(tr, dem.shape, self.step_km, cell))
                top, gx, gy = (_coarsen(a, LEVEL_RATIO) for a in (top, gx, gy))
                cell *= LEVEL_RATIO
        cat = (lambda a: np.concatenate(a)) if tops else (lambda a: np.zeros(0))
        return (cat(tops), cat(slopes), np.array(offs[:-1], np.int64), np.array(widths, np.int64),
                np.array(cells, np.int64), np.array(skips, np.int64))

    def _lit_flags(self, sun, rows, cols, offset):
        """``(flags, bi0, bj0, shift)``: 1 for every block of :data:`CELL_PX` pixels around the pixels that
        :func:`.march.lit_cells` finds lit (its first block row and column ``bi0, bj0``; a pixel's block is its
        coordinates shifted right by ``shift``); None when it cannot tell any (no ground-distance bounds near a pole).
        With a global slope bound, that alone first; the pyramid (built then, as the march would) if it leaves a block."""
        px = _ground_px_km(self.transform, self.dem.shape)
        if px is None:
            return None
        roff, coff = offset if isinstance(offset, tuple) else (offset, offset)
        shift = int(round(math.log2(CELL_PX)))
        r0, r1, c0, c1 = extent(rows, cols)
        bi0, bi1, bj0, bj1 = (roff + r0) >> shift, ((roff + r1) >> shift) + 1, (coff + c0) >> shift, ((coff + c1) >> shift) + 1
        tr = self.transform
        prm = np.array([tr.c, tr.a, tr.f, tr.e, self.step_km, self.hmax, self.tolerance_m, MOON_RADIUS_KM, self.slope])
        if self._pyramid is None and self.slope > 0.0:  # the global bound alone first: the pyramid if it is not enough
            flags = lit_cells(self.blocks[3], self.blocks[0], prm, sun, bi0, bi1, bj0, bj1, CELL_PX,
                              np.zeros(0), np.zeros(0), *(np.zeros(0, np.int64),) * 4)
            if flags.all():
                return flags, bi0, bj0, shift
        flags = lit_cells(self.blocks[3], self.blocks[0], prm, sun, bi0, bi1, bj0, bj1, CELL_PX, *self.pyramid())
        return flags, bi0, bj0, shift

    def march(self, sun_km, rows, cols, *, offset: int | tuple[int, int] = 0, skip: bool = True,
              exact: bool = False, cells: bool = True) -> np.ndarray:
        """Is DEM pixel ``(row_offset + rows[o], col_offset + cols[o])`` in the cast shadow of the Sun at ``sun_km``? (1-D bool)

        ``offset``: ``(row_offset, col_offset)``, or one offset for both.

        ``skip=False``: every step of every ray, ``exact=True``: the sample coordinates from
        ``atan2``/``asin`` (the reference the shortcuts are tested against).  ``cells``: first
        the blocks of :data:`CELL_PX` pixels whose every pixel is certainly lit
        (:func:`.march.lit_cells`), then the march of the other pixels only: the same answers
        (``cells=False`` marches every pixel; ``tests/test_cast_shadows.py`` compares them).
        """
        rows, cols = np.ascontiguousarray(rows), np.ascontiguousarray(cols)
        out = np.zeros(rows.shape, np.int8)
        if self.empty or rows.size == 0:
            return out.astype(bool)
        lit = self._lit_flags(np.asarray(sun_km, dtype=np.float64), rows, cols, offset) if (cells and skip and not exact) else None
        if lit is not None and lit[0].all():
            return out.astype(bool)
        lit = lit if lit is not None else (np.zeros((0, 0), np.int8), 0, 0, 0)  # the march skips the pixels of lit blocks
        tr = self.grid_transform
        prm = np.array([tr.c, tr.a, tr.f, tr.e, self.step_km, self.hmax, self.tolerance_m, MOON_RADIUS_KM,
                        self.slope if skip else 0.0, *(offset if isinstance(offset, tuple) else (offset, offset)),
                        *((self.row0,) if self.banded else ())])
        sun = np.asarray(sun_km, dtype=np.float64)
        none = (np.zeros(0), np.zeros(0), *(np.zeros(0, np.int64),) * 4)
        if skip and self.slope > 0.0:  # first the rays the global slope bound answers; the pyramid if some ray needs it
            _march_pixels(self.dem, prm, self.max_steps, exact, True, *self.tables, sun, rows, cols, *none, *lit, out)
            todo = np.flatnonzero(out == 2)
            if todo.size:
                part = np.zeros(todo.size, np.int8)
                _march_pixels(self.dem, prm, self.max_steps, exact, False, *self.tables, sun, rows[todo],
                              cols[todo], *self.pyramid(), *lit, part)
                out[todo] = part
        else:
            _march_pixels(self.dem, prm, self.max_steps, exact, False, *self.tables, sun, rows, cols,
                          *(self.pyramid() if skip else none), *lit, out)
        return out == 1


def cast_shadow_mask(dem_m, transform, sun_km, window=None, *, max_reach_km: float = MAX_REACH_KM,
                     step_px: float = STEP_PX, tolerance_m: float = TOLERANCE_M, skip: bool = True,
                     exact: bool = False) -> np.ndarray:
    """True where a DEM pixel centre is in the cast shadow of the terrain for the Sun at ``sun_km``.

    ``dem_m``: heights (metres above the 1737.4 km sphere, NaN where unknown) on the
    north-up lon/lat grid of the affine ``transform`` (degrees); ``sun_km``: Sun
    position, body-fixed km; ``window``: ``(row0, row1, col0, col1)`` of the pixels to
    decide (default: all; the rest of the grid is the margin that can cast shadows
    into it).  Returns a bool array of the window's shape.  Pixels whose own height is
    NaN are reported lit (they have no ground point); NaN terrain blocks nothing.
    ``skip=False`` marches every step of every ray, ``exact=True`` finds each sample's
    lon/lat with ``atan2``/``asin`` (together: the reference the shortcuts are tested against).
    """
    h, w = np.shape(dem_m)
    r0, r1, c0, c1 = window if window is not None else (0, h, 0, w)
    rows, cols = np.mgrid[r0:r1, c0:c1]
    grid = MarchGrid(dem_m, transform, max_reach_km=max_reach_km, step_px=step_px, tolerance_m=tolerance_m)
    return grid.march(sun_km, rows.ravel(), cols.ravel(), skip=skip, exact=exact).reshape(r1 - r0, c1 - c0)
