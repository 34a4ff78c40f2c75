"""The vectorisable logarithm of the outlier test (model/vlog.py): logf (float32) within 1 ulp of log x over its
whole range (subnormals included) against an 80-bit long double reference, the special values as libm gives
them, the same bits in a vectorised loop as in one scalar call."""
from __future__ import annotations


import numpy as np
import pytest
from numba import njit

from lunaralbedo.model import vlog


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
