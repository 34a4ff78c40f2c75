"""The arc cosine of the phase angle (``model/vacos.py``) against NumPy's, and the loops it lets LLVM vectorise."""
from __future__ import annotations

import platform
import re

import numpy as np
import pytest
from numba import njit

from lunaralbedo.model import vacos


@njit(cache=True)
def _over(x, out):
    for i in range(x.shape[0]):
        out[i] = vacos.acos(x[i])


def _ulps(got, want):
    return np.abs(got - want) / np.spacing(want)


def test_acos_is_within_one_ulp_of_numpy_everywhere_in_its_range():
    rng = np.random.default_rng(7)
    half = np.nextafter(0.5, 1.0)
    x = np.concatenate([np.linspace(-1.0, 1.0, 2_000_001), rng.uniform(-1.0, 1.0, 1_000_000),
                        1.0 - rng.uniform(0, 1e-6, 100_000), rng.uniform(-1e-9, 1e-9, 100_000),  # near 0 and 1 (alpha ~ 0)
                        [0.5, -0.5, half, -half, np.nextafter(0.5, 0.0), 1.0 - 2**-53, -1.0 + 2**-53, 5e-324]])
    got = np.empty_like(x)
    _over(x, got)
    want = np.arccos(x)
    assert _ulps(got, want).max() <= 1.0
    assert 0.5 < np.mean(got == want) < 1.0  # mostly the correctly rounded value, not always
    assert np.all(np.diff(got[:2_000_001]) <= 0)  # monotonic over the ordered samples
    special = np.array([-1.0, -0.0, 0.0, 1.0])
    out = np.empty(4)
    _over(special, out)
    assert out[0] == np.pi and out[1] == out[2] == np.pi / 2 and out[3] == 0.0


def test_acos_outside_numba_is_the_same_function():
    assert vacos.acos(0.3) == pytest.approx(np.arccos(0.3), rel=2e-16, abs=0)


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="checks x86 packed instructions")
def test_a_loop_of_acos_is_vectorised():
    """No call to libm and packed square roots: the loop runs several values per instruction (a fresh compile)."""
    fresh = njit(_over.py_func)
    fresh(np.linspace(-1, 1, 64), np.empty(64))
    asm = fresh.inspect_asm(fresh.signatures[0])
    assert "vsqrtpd" in asm and not re.search(r"call.*\bacos", asm)
