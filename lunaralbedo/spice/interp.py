"""Pure math for SPICE caches: interpolation of positions and rotations (NumPy only).

Quaternions are SPICE's (scalar first); a quaternion ``q`` stands for the matrix
``q2m(q)`` that rotates vectors from the reference frame (J2000) into the moving frame.
"""
from __future__ import annotations

import numpy as np


def _bracket(times: np.ndarray, et: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the left record of the interval holding each ``et`` and the fraction in it."""
    i = np.clip(np.searchsorted(times, et, side="right") - 1, 0, len(times) - 2)
    dt = times[i + 1] - times[i]
    return i, (et - times[i]) / np.where(dt == 0, 1.0, dt)


def interp_linear(times, values, et) -> np.ndarray:
    """Piecewise-linear interpolation of ``values`` (N, k) at ``et`` (any shape); linear extrapolation."""
    times = np.asarray(times, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    et = np.asarray(et, dtype=np.float64)
    if len(times) == 1:
        return np.broadcast_to(values[0], et.shape + values.shape[1:]).copy()
    i, u = _bracket(times, et)
    return values[i] + (values[i + 1] - values[i]) * u[..., None]


def interp_hermite(times, pos, vel, et) -> np.ndarray:
    """Cubic Hermite interpolation of positions ``pos`` (N, 3) with derivatives ``vel`` (N, 3)."""
    times = np.asarray(times, dtype=np.float64)
    pos = np.asarray(pos, dtype=np.float64)
    vel = np.asarray(vel, dtype=np.float64)
    et = np.asarray(et, dtype=np.float64)
    if len(times) == 1:
        return pos[0] + vel[0] * (et - times[0])[..., None]
    i, u = _bracket(times, et)
    h = (times[i + 1] - times[i])[..., None]
    u = u[..., None]
    h00 = 2 * u**3 - 3 * u**2 + 1
    h10 = u**3 - 2 * u**2 + u
    h01 = -2 * u**3 + 3 * u**2
    h11 = u**3 - u**2
    return h00 * pos[i] + h10 * h * vel[i] + h01 * pos[i + 1] + h11 * h * vel[i + 1]


def poly_function(coeffs, base_time, time_scale, et) -> np.ndarray:
    """ISIS ``PolyFunction`` cache: ``sum_k c_k ((et - base) / scale)^k`` per column of ``coeffs`` (deg+1, 3)."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    t = (np.asarray(et, dtype=np.float64) - base_time) / time_scale
    out = np.zeros(t.shape + (coeffs.shape[1],))
    for k in range(coeffs.shape[0] - 1, -1, -1):
        out = out * t[..., None] + coeffs[k]
    return out


def quat_to_matrix(q) -> np.ndarray:
    """SPICE ``q2m`` vectorised: ``(..., 4)`` scalar-first unit quaternions to ``(..., 3, 3)`` matrices."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    s, x, y, z = np.moveaxis(q, -1, 0)
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = 1 - 2 * (y * y + z * z)
    m[..., 0, 1] = 2 * (x * y - s * z)
    m[..., 0, 2] = 2 * (x * z + s * y)
    m[..., 1, 0] = 2 * (x * y + s * z)
    m[..., 1, 1] = 1 - 2 * (x * x + z * z)
    m[..., 1, 2] = 2 * (y * z - s * x)
    m[..., 2, 0] = 2 * (x * z - s * y)
    m[..., 2, 1] = 2 * (y * z + s * x)
    m[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def interp_quaternions(times, quats, et) -> np.ndarray:
    """Spherical-linear interpolation of quaternions (N, 4) at ``et``; constant outside with 1 record."""
    times = np.asarray(times, dtype=np.float64)
    quats = np.asarray(quats, dtype=np.float64)
    et = np.asarray(et, dtype=np.float64)
    if len(times) == 1:
        return np.broadcast_to(quats[0], et.shape + (4,)).copy()
    i, u = _bracket(times, et)
    q0, q1 = quats[i], quats[i + 1]
    dot = np.sum(q0 * q1, axis=-1)
    q1 = np.where((dot < 0)[..., None], -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-10
    sin_t = np.where(small, 1.0, np.sin(theta))
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / sin_t)
    w1 = np.where(small, u, np.sin(u * theta) / sin_t)
    q = w0[..., None] * q0 + w1[..., None] * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def apply(matrix, vectors) -> np.ndarray:
    """``matrix @ v`` for ``(..., 3, 3)`` matrices and ``(..., 3)`` vectors (broadcasting)."""
    return np.einsum("...ij,...j->...i", matrix, vectors)
