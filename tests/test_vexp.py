"""The vectorisable exponential of the phase factor (model/photometry/vexp.py): within 1 float32
ulp of e^x, the same bits in a vectorised loop as in one scalar call, libm for float64."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from lunaralbedo.model.photometry import vexp


@njit(cache=True)
def _over(x, out):
    for i in range(x.shape[0]):
        out[i] = vexp.exp(x[i])


@njit(cache=True)
def _one(x):
    return vexp.exp(x)


def _ulps(got, want):
    return np.abs(got.view(np.int32).astype(np.int64) - want.view(np.int32))


def _exp32(x):
    out = np.empty_like(x)
    _over(x, out)
    return out


def test_within_one_ulp_over_the_phase_factor_range():
    """Every 37th float32 of -pi * c1 .. 0 for c1 up to 10 (phase angles 0..180 degrees), against math.exp."""
    lo, hi = int(np.float32(-0.0).view(np.uint32)), int(np.float32(-math.pi * 10).view(np.uint32))
    worst, off, n = 0, 0, 0
    for a in range(lo, hi, 37 << 22):  # in parts of 4 M values
        x = np.arange(a, min(a + (37 << 22), hi), 37, dtype=np.uint32).view(np.float32)
        ref = np.exp(x.astype(np.float64)).astype(np.float32)  # correctly rounded (float64 exp, one rounding)
        d = _ulps(_exp32(x), ref)
        worst, off, n = max(worst, d.max()), off + np.count_nonzero(d), n + len(d)
    assert n > 25_000_000 and worst == 1
    assert off / n < 0.2  # glibc's expf: 0.06 %


def test_range_ends_subnormals_and_special_values():
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(-104, -87, 100_000), rng.uniform(80, 88.7, 100_000), rng.uniform(-5, 5, 100_000)]).astype(np.float32)
    with np.errstate(over="ignore"):
        ref = np.exp(x.astype(np.float64)).astype(np.float32)
    assert _ulps(_exp32(x), ref).max() <= 1  # subnormal results are rounded once too
    sp = np.array([0.0, -0.0, -200.0, -110.0, 88.8, 200.0, np.inf, -np.inf, np.nan], np.float32)
    got = _exp32(sp)
    np.testing.assert_array_equal(got[:8], [1, 1, 0, 0, np.inf, np.inf, np.inf, 0])
    assert np.isnan(got[8]) and got.dtype == np.float32


def test_vector_lanes_equal_scalar_calls_and_float64_is_libm():
    x = np.random.default_rng(1).uniform(-20, 0, 1000).astype(np.float32)
    vec = _exp32(x)
    assert all(_one(v) == vec[i] for i, v in enumerate(x[:200]))
    assert np.float32(_one(np.float32(-1.5))).dtype == np.float32
    y = np.random.default_rng(2).uniform(-20, 5, 100)
    assert all(_one(v) == math.exp(v) for v in y)  # float64: libm, bit for bit
