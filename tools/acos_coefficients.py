#!/usr/bin/env python3
"""Derive the coefficients of lunaralbedo.model.vacos (the arc cosine of the prepare step's phase angle).

P(u) = (asin(sqrt u) - sqrt u) / u^(3/2) = sum_{k>=1} c_k u^(k-1),  c_k = binom(2k, k) 4^-k / (2k + 1),

summed to 400 terms in extended precision at 4000 Chebyshev nodes of [0, 1/4], interpolated by a
Chebyshev series of degree 12 and written in powers of u.  Prints the coefficients and the largest
relative error of P over 200001 points of [0, 1/4].  Usage:

    python tools/acos_coefficients.py [--degree 12]
"""
from __future__ import annotations

import argparse

import numpy as np
from numpy.polynomial import chebyshev, polynomial


def series(u: np.ndarray, terms: int = 400) -> np.ndarray:
    """P(u) in extended precision (numpy.longdouble)."""
    u = np.asarray(u, np.longdouble)
    out, power, c = np.zeros_like(u), np.ones_like(u), np.longdouble(1)
    for k in range(1, terms):
        c = c * (2 * k - 1) / (2 * k)  # binom(2k, k) / 4^k
        out += c / (2 * k + 1) * power
        power = power * u
    return out


def coefficients(degree: int = 12, nodes: int = 4000) -> np.ndarray:
    t = np.cos(np.pi * (np.arange(nodes) + 0.5) / nodes)  # nodes on [-1, 1]; u = (t + 1) / 8
    cheb = chebyshev.chebfit(t, series((t + 1) / 8).astype(np.float64), degree)
    in_t = chebyshev.cheb2poly(cheb)
    in_u = np.zeros(1)
    for a in in_t[::-1]:  # Horner in t = 8u - 1
        in_u = polynomial.polyadd(polynomial.polymul(in_u, [-1.0, 8.0]), [a])
    return in_u


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--degree", type=int, default=12)
    coeffs = coefficients(parser.parse_args().degree)
    u = np.linspace(0.0, 0.25, 200001)
    ref = series(u)
    err = float(np.max(np.abs(polynomial.polyval(u, coeffs) - ref) / ref))
    print("COEFFS = (\n" + "".join(f"    {float(c)!r},\n" for c in coeffs) + ")")
    print(f"# largest relative error of P on [0, 1/4]: {err:.2e}")


if __name__ == "__main__":
    main()
