r"""Per-observation (scalar) form of a photometric model, shared by its NumPy API and the fused kernels.

A model may give ``point``: an ``@njit(cache=True)`` function
``point(l0, l1, l2, params) -> (R, dR/dp_0, dR/dp_1)`` of one observation's layers (the
model's ``point_layers``, at most three; unused ones receive another layer) and its
fitted parameters (at most two; unused derivatives are returned as anything of the
layers' type).  ``params`` has the layers' dtype, and every operation stays in it, so a
float32 cache gives float32 :math:`R` and the forward model float64.

:func:`evaluate` runs the model's loop over ``point`` on arrays (the model's
``reflectance_from``, ``derivatives_from`` and ``reflectance`` call it); the iterate kernel
(:mod:`lunaralbedo.engine.kernels`, which lists the models it inlines) calls the same ``point``,
so the formula has one implementation and both give the same bits.
"""
from __future__ import annotations

import numpy as np


def evaluate(loop, layers, params, n_out: int = 1) -> np.ndarray:
    """The model's ``loop`` over broadcast ``layers`` (1 to 3 arrays): ``(n_out, *shape)`` of R, dR/dp_0, dR/dp_1.

    ``loop(l0, l1, l2, params, out)`` is the model's ``@njit(cache=True)`` loop calling its
    ``point`` for every element (written in the model's module: a numba function passed as an
    argument would be compiled again in every process).  float32 when every layer is float32,
    else float64 (parameters cast to that dtype).
    """
    arrays = np.broadcast_arrays(*(np.asarray(a) for a in layers))
    dtype = np.float32 if all(a.dtype == np.float32 for a in arrays) else np.float64
    shape = arrays[0].shape
    flat = [np.ascontiguousarray(a, dtype=dtype).ravel() for a in arrays]
    flat += [flat[0]] * (3 - len(flat))
    out = np.empty((n_out, flat[0].size), dtype)
    loop(*flat, np.asarray(params, dtype=dtype).reshape(-1), out)
    return out.reshape((n_out, *shape))
