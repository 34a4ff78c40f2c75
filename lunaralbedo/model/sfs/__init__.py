r"""Shape from shading: the heights of a DEM as unknowns of the albedo cost (``REFINE_DEM 1``).

The cost over the heights :math:`h` (metres) of one window of the tile grid, with the albedo
:math:`A`, the exposures :math:`T_k` and the photometric parameters held at the values of the
albedo solve, is a sum of *named terms* (:class:`Cost`), each a module of this package:

.. math::

    C(h) = \underbrace{\sum_k\sum_{ij} w_{kij}\Big(\frac{I_{kij}}{T_k A_{ij}} - R\big(\cos i_{kij}(h),
           \cos e_{kij}(h), \alpha_{kij}\big)\Big)^2}_{\text{shading (:mod:`.shading`)}}
         + \underbrace{\mu\sum_{ij}\Big(\frac{(\nabla^2 h)_{ij}}{\Delta}\Big)^2}_{\text{smoothness (:mod:`.smoothness`)}}
         + \underbrace{\lambda\sum_{ij}\Big(\frac{(S h)_{ij} - h^0_{ij}}{\Delta}\Big)^2}_{\text{fidelity (:mod:`.fidelity`)}}

where :math:`\Delta` is the ground size of a pixel (metres), :math:`\nabla^2` the five-point
Laplacian (so :math:`\nabla^2 h/\Delta` is the change of slope from one pixel to the next) and
:math:`S` a Gaussian that smooths the refined heights to the resolution of the input DEM
:math:`h^0`: the input is held only at the scale at which it is right.  The form is the cost of
ASP's ``sfs`` (Alexandrov and Beyer, "Multiview shape-from-shading for planetary images",
Earth and Space Science 2018): :math:`\sum[I - T A R - H]^2 + \mu\|\nabla^2 h\|^2 + \lambda(h - h_0)^2`,
here with the residual divided by :math:`T A` (reflectance units, so that :math:`\mu, \lambda`
are dimensionless and do not depend on the camera's gain) and with the fidelity term held at the
input's resolution.  Nefian et al. (LPSC), the albedo method this package implements, names
shape from shading to correct the DTM as its future work.

Other terms join as more named terms: a term is any object with ``name``, ``weight`` and
``value_grad(h) -> (value, gradient)`` (and ``diagonal(shape)``, its Gauss-Newton diagonal, for
:func:`height_uncertainty`).  Haze, outliers and registration act on the observations (the engine takes each
image's haze off :math:`I`, leaves rejected observations out with :math:`w = 0`, and reads the images at their
registered place).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Cost:
    """A sum of named terms over one array of heights (metres, float64, shape ``(H, W)``)."""

    terms: list

    def __call__(self, h: np.ndarray) -> tuple[float, np.ndarray]:
        """``(C, dC/dh)``: the weighted terms added in their list order (float64)."""
        total, grad = 0.0, np.zeros_like(h)
        for term in self.terms:
            if term.weight == 0:
                continue
            v, g = term.value_grad(h)
            total += term.weight * v
            grad += term.weight * g
        return total, grad

    def parts(self, h: np.ndarray) -> dict[str, float]:
        """Each term's weighted value by name (for the report)."""
        return {t.name: float(t.weight * t.value_grad(h)[0]) for t in self.terms}


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """``a . b`` without BLAS: a threaded BLAS dot of ~10^4 elements spent ~100x its arithmetic waiting for its
    threads on a busy machine (most of a window's time in L-BFGS)."""
    return float(np.einsum("i,i->", a, b))


def lbfgs(fg, x0: np.ndarray, max_iter: int, memory: int = 10, first_step: float = 0.05,
          tol: float = 1e-9) -> tuple[np.ndarray, float, int]:
    """Minimise ``fg(x) -> (f, grad)`` by limited-memory BFGS (Nocedal and Wright, *Numerical Optimization*,
    algorithm 7.4: the two-loop recursion) with a backtracking (Armijo) line search that also doubles
    a full step while the cost keeps falling.

    SciPy's L-BFGS-B reached the same costs per iteration but spent more time in its own work than
    in the cost on a 17 000-height window; the two-loop recursion here is a few vector operations
    (dot products without BLAS: :func:`_dot`).  The first step moves the largest unknown by ``first_step``.
    Stops after ``max_iter`` iterations or when the cost falls by less than ``tol`` of itself.
    Deterministic: the same bytes on any machine count.  Returns ``(x, f, iterations)``.
    """
    x = np.array(x0, dtype=np.float64)
    f, g = fg(x)
    pairs: list[tuple[np.ndarray, np.ndarray, float]] = []
    it = 0
    for it in range(1, max_iter + 1):
        q = -g
        alphas = []
        for s_, y_, rho in reversed(pairs):
            a = rho * _dot(s_, q)
            alphas.append(a)
            q = q - a * y_
        if pairs:
            s_, y_, _ = pairs[-1]
            q = q * (_dot(s_, y_) / _dot(y_, y_))
        else:
            q = q * (first_step / max(float(np.max(np.abs(g))), 1e-300))
        for (s_, y_, rho), a in zip(pairs, reversed(alphas)):
            q = q + s_ * (a - rho * _dot(y_, q))
        slope = _dot(g, q)
        if slope >= 0:  # not a descent direction: restart from the gradient
            pairs.clear()
            q = -g * (first_step / max(float(np.max(np.abs(g))), 1e-300))
            slope = _dot(g, q)
        t = 1.0
        for _ in range(30):
            f_new, g_new = fg(x + t * q)
            if f_new <= f + 1e-4 * t * slope:
                break
            t *= 0.5
        else:
            break
        for _ in range(10) if t == 1.0 else ():  # a full step was good: longer ones while the cost falls
            f_try, g_try = fg(x + 2 * t * q)
            if not f_try < f_new:
                break
            t, f_new, g_new = 2 * t, f_try, g_try
        s_, y_ = t * q, g_new - g
        sy = _dot(s_, y_)
        if sy > 1e-12:
            pairs.append((s_, y_, 1.0 / sy))
            del pairs[:-memory]
        x, done = x + s_, f - f_new <= tol * max(abs(f), 1e-300)
        f, g = f_new, g_new
        if done:
            break
    return x, f, it


def minimise(cost: Cost, h_start: np.ndarray, scale_m: float, max_iter: int = 200) -> tuple[np.ndarray, dict]:
    """Minimise ``cost`` over the heights from ``h_start`` (:func:`lbfgs`).

    The unknowns are the changes in units of ``scale_m`` (the pixel size, metres), so that a unit
    step is a slope change of order one whatever the resolution.  Returns the heights (metres,
    float64) and ``{"iterations", "evaluations", "cost_start", "cost_end"}``.
    """
    shape = h_start.shape
    h0 = np.asarray(h_start, dtype=np.float64)
    calls = [0]

    def f(x):
        calls[0] += 1
        v, g = cost(h0 + scale_m * x.reshape(shape))
        return v, (scale_m * g).ravel()

    c0 = f(np.zeros(h0.size))[0]
    x, c1, it = lbfgs(f, np.zeros(h0.size), max_iter)
    return h0 + scale_m * x.reshape(shape), {"iterations": it, "evaluations": calls[0], "cost_start": float(c0),
                                             "cost_end": float(c1)}


def height_uncertainty(cost: Cost, h: np.ndarray) -> tuple[np.ndarray, float]:
    r"""Each height's standard error (metres) from the diagonal of the Gauss-Newton matrix at ``h``, and the
    residuals' variance :math:`s^2`.

    With residuals of variance :math:`s^2` (estimated as the data term's value over its degrees of freedom: the
    observations less one per pixel whose albedo floats; NaN, no value anywhere, when none are left, as under one
    image, where the residuals are zero whatever the heights and only the priors hold them) the cost is
    :math:`2 s^2` times a negative log posterior, whose Gauss-Newton Hessian is
    :math:`H = (J^\top J + \mu L^\top L/\Delta^2 + \lambda S^\top S/\Delta^2)/s^2`.  The standard error is taken as
    :math:`s/\sqrt{H_{pp} s^2}`: the spread of one height with its neighbours held (ASP ``sfs``'s
    ``--estimate-height-errors`` also perturbs one height at a time).  It is a lower bound of the marginal
    :math:`\sqrt{(H^{-1})_{pp}}` (the inverse of a diagonal element is never larger than the diagonal element of the
    inverse): it says where the images pin the heights and where only the priors do, not the error of relief
    that moves together over many pixels.  The terms are found by name (``shading``, ``smoothness``, ``fidelity``).
    """
    terms = {t.name: t for t in cost.terms}
    diag, misfit, n, dof = terms["shading"].gauss_newton_diagonal(h)
    s2 = misfit / dof if dof > 0 else float("nan")
    for name in ("smoothness", "fidelity"):
        if name in terms and terms[name].weight:
            diag = diag + terms[name].weight * terms[name].diagonal(h.shape)
    with np.errstate(divide="ignore"):
        return np.sqrt(s2 / diag), s2
