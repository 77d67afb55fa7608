"""Row-wise lengths and dot products: numpy's reductions over the last axis, bit for bit."""

import numpy as np
import pytest

from camnet.model import rowwise


@pytest.mark.parametrize("k", [2, 3])
def test_the_same_numbers_as_numpy_reductions(k):
    rng = np.random.default_rng(k)
    a = rng.normal(size=(5000, k)) * 10.0 ** rng.integers(-8, 8, size=(5000, 1))
    b = rng.normal(size=(5000, k))
    np.testing.assert_array_equal(rowwise.squared_lengths(a), np.sum(a * a, axis=1))
    np.testing.assert_array_equal(rowwise.lengths(a), np.linalg.norm(a, axis=1))
    np.testing.assert_array_equal(rowwise.dots(a, b), np.sum(a * b, axis=1))
    assert rowwise.lengths(np.zeros((0, k))).shape == (0,)
