"""Structures that scale to 10^5 images: sparse overlap exposures and the tile x image index."""
from __future__ import annotations

import numpy as np
import pytest

from lunaralbedo.model import exposure_init


def _random_pairs(rng, k, per_image=4):
    pairs = {}
    for j in range(k):
        for i in rng.choice(k, per_image):
            if j < i:
                pairs[(j, int(i))] = (int(rng.integers(1, 1000)), float(rng.normal() * 50))
    return pairs


def test_sparse_overlap_exposure_equals_the_dense_least_squares():
    """Same minimiser as the stacked least-squares rows solved densely (independent formulation)."""
    rng = np.random.default_rng(3)
    k, mu = 120, 1e-6
    pairs = _random_pairs(rng, k)
    x0 = rng.normal(size=k) * 0.2
    lam = mu * np.mean([n for n, _ in pairs.values()])
    rows, rhs = [], []
    for (j, i), (n, d) in pairs.items():
        row = np.zeros(k)
        row[j], row[i] = np.sqrt(n), -np.sqrt(n)
        rows.append(row)
        rhs.append(np.sqrt(n) * d / n)
    a = np.vstack([np.array(rows), np.sqrt(lam) * np.eye(k)])
    b = np.concatenate([rhs, np.sqrt(lam) * x0])
    x = np.linalg.lstsq(a, b, rcond=None)[0]
    x += x0.mean() - x.mean()
    np.testing.assert_allclose(exposure_init.overlap_exposure(pairs, x0, mu=mu), np.exp(x), rtol=1e-7)


def test_overlap_exposure_of_a_long_strip_of_20000_images():
    """A chain of 2*10^4 images (each overlapping the next two): exposures recovered up to the free scale."""
    rng = np.random.default_rng(4)
    k = 20000
    x_true = rng.normal(size=k) * 0.3
    pairs = {}
    for j in range(k):
        for i in (j + 1, j + 2):
            if i < k:
                n = int(rng.integers(100, 5000))
                pairs[(j, i)] = (n, n * (x_true[j] - x_true[i]))
    x0 = np.zeros(k)
    t = exposure_init.overlap_exposure(pairs, x0)
    x = np.log(t)
    # mu pulls towards x0 a little; along 2*10^4 images that bends the solution by ~4e-3
    np.testing.assert_allclose(x - x.mean(), x_true - x_true.mean(), atol=1e-2)
    assert np.mean(x) == pytest.approx(0.0, abs=1e-12)
