r"""Per-observation (scalar) form of a photometric model, shared by its NumPy API and the fused kernels.

A model may give ``point``: an ``@njit(cache=True)`` function
``point(l0, l1, l2, params) -> (R, dR/dp_0, dR/dp_1)`` of one observation's layers (the
model's ``point_layers``, at most three; unused ones receive another layer) and its
fitted parameters (at most two; unused derivatives are returned as anything of the
layers' type).  ``params`` has the layers' dtype, and every operation stays in it, so a
float32 cache gives float32 :math:`R` and the forward model float64.

:func:`evaluate` runs ``point`` over arrays (the model's ``reflectance_from``,
``derivatives_from`` and ``reflectance`` call it); the iterate kernel
(:mod:`lunaralbedo.engine.kernels`) calls the same ``point`` inline, so the formula has one
implementation and both give the same bits.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _evaluate(point, l0, l1, l2, params, out):
    m = out.shape[0]
    for o in range(l0.shape[0]):
        r, d0, d1 = point(l0[o], l1[o], l2[o], params)
        out[0, o] = r
        if m > 1:
            out[1, o] = d0
        if m > 2:
            out[2, o] = d1


def evaluate(point, layers, params, n_out: int = 1) -> np.ndarray:
    """``point`` over broadcast ``layers`` (1 to 3 arrays): ``(n_out, *shape)`` of R, dR/dp_0, dR/dp_1.

    float32 when every layer is float32, else float64 (parameters cast to that dtype).
    """
    arrays = np.broadcast_arrays(*(np.asarray(a) for a in layers))
    dtype = np.float32 if all(a.dtype == np.float32 for a in arrays) else np.float64
    shape = arrays[0].shape
    flat = [np.ascontiguousarray(a, dtype=dtype).ravel() for a in arrays]
    flat += [flat[0]] * (3 - len(flat))
    out = np.empty((n_out, flat[0].size), dtype)
    _evaluate(point, *flat, np.asarray(params, dtype=dtype).reshape(-1), out)
    return out.reshape((n_out, *shape))
