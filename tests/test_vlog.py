"""The vectorisable logarithms of the outlier test (model/vlog.py): log (float64) and logf (float32) within
1 ulp of log x over their whole range (subnormals included) against an 80-bit long double reference, the
special values as libm gives them, the same bits in a vectorised loop as in one scalar call."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from lunaralbedo.model import vlog


@njit(cache=True, error_model="numpy")
def _over(x, out):
    for i in range(x.shape[0]):
        out[i] = vlog.log(x[i])


@njit(cache=True)
def _one(x):
    return vlog.log(x)


@njit(cache=True, error_model="numpy")
def _over_f(x, out):
    for i in range(x.shape[0]):
        out[i] = vlog.logf(x[i])


@njit(cache=True)
def _one_f(x):
    return vlog.logf(x)


def _logf(x):
    out = np.empty_like(x)
    _over_f(x, out)
    return out


def _log(x):
    out = np.empty_like(x)
    _over(x, out)
    return out


def _ulps(got, want):
    return np.abs(got.view(np.int64) - want.view(np.int64))


@pytest.mark.skipif(np.finfo(np.longdouble).nmant < 60, reason="needs an 80-bit long double for the reference")
def test_within_one_ulp_over_the_whole_float64_range():
    """Evenly spaced bit patterns from the least subnormal to the largest float64 (every exponent, ~1000
    mantissas each), 2 M random ones near 1 (where log x is small), against logl rounded to float64."""
    top = int(np.float64(np.finfo(np.float64).max).view(np.int64))
    bits = np.append(np.arange(1, top, top // 2_000_000, dtype=np.int64), top)
    rng = np.random.default_rng(0)
    x = np.concatenate([bits.view(np.float64), rng.uniform(0.5, 2.0, 1_000_000), 1.0 + rng.uniform(-1e-6, 1e-6, 1_000_000)])
    x = x[x != 1.0]
    ref = np.log(x.astype(np.longdouble)).astype(np.float64)  # 64-bit mantissa: correctly rounded but for rare ties
    d = _ulps(_log(x), ref)
    assert d.max() <= 1
    assert np.count_nonzero(d) / len(d) < 0.05  # fdlibm's log: < 1 ulp, most results correctly rounded
    rel = np.abs(_log(x) - ref) / np.abs(ref)
    assert rel.max() < 2.3e-16


def test_special_values_as_libm():
    sp = np.array([0.0, -0.0, 1.0, np.inf, -np.inf, -1.0, -1e-300, np.nan, 5e-324, np.finfo(np.float64).max,
                   np.finfo(np.float64).tiny])
    got = _log(sp)
    np.testing.assert_array_equal(got[:4], [-np.inf, -np.inf, 0.0, np.inf])
    assert np.isnan(got[4:8]).all()
    np.testing.assert_allclose(got[8:], [math.log(5e-324), math.log(np.finfo(np.float64).max),
                                         math.log(np.finfo(np.float64).tiny)], rtol=2.3e-16)


def test_vector_lanes_equal_scalar_calls():
    x = np.exp(np.random.default_rng(1).uniform(-700, 700, 1000))
    vec = _log(x)
    assert all(_one(v) == vec[i] for i, v in enumerate(x[:300]))


@pytest.mark.skipif(np.finfo(np.longdouble).nmant < 60, reason="needs an 80-bit long double for the reference")
def test_logf_within_one_float32_ulp_over_the_whole_float32_range():
    """Every 499th positive float32 (subnormals to the largest), against logl rounded to float32."""
    top = int(np.float32(np.finfo(np.float32).max).view(np.int32))
    x = np.append(np.arange(1, top, 499, dtype=np.int32), top).view(np.float32)
    got = _logf(x)
    ref = np.log(x.astype(np.longdouble)).astype(np.float32)
    d = np.abs(got.view(np.int32).astype(np.int64) - ref.view(np.int32))
    assert got.dtype == np.float32 and d.max() <= 1
    assert np.count_nonzero(d) / len(d) < 0.02  # Cephes' logf: most results correctly rounded


def test_logf_special_values_and_vector_lanes():
    sp = np.array([0.0, -0.0, 1.0, np.inf, -np.inf, -1.0, np.nan], np.float32)
    got = _logf(sp)
    np.testing.assert_array_equal(got[:4], [-np.inf, -np.inf, 0.0, np.inf])
    assert np.isnan(got[4:]).all()
    x = np.exp(np.random.default_rng(2).uniform(-80, 80, 1000)).astype(np.float32)
    vec = _logf(x)
    assert all(_one_f(v) == vec[i] for i, v in enumerate(x[:300]))
