"""Descriptor distances by one product, and the ratio test and cross check read off it."""

from __future__ import annotations

import numpy as np
import pytest

from camnet.matching import nearest
from tests.test_matching import _reference_mutual_ratio


def _sift_like(rng: np.random.Generator, n: int) -> np.ndarray:
    """Whole numbers 0-255 in 128 dimensions, as OpenCV's SIFT rounds its descriptors (here up to 255)."""
    return rng.integers(0, 256, size=(n, 128)).astype(np.float32)


def test_one_product_gives_the_exact_squared_distances_and_hamming_distances():
    rng = np.random.default_rng(1)
    a, b = _sift_like(rng, 70), _sift_like(rng, 90)
    want = ((a[:, None, :].astype(np.int64) - b[None, :, :].astype(np.int64)) ** 2).sum(axis=2)
    got = nearest.distances(nearest.operands(a, binary=False), nearest.operands(b, binary=False))
    assert got.dtype == np.float32 and np.array_equal(got.astype(np.int64), want)
    bits_a, bits_b = rng.integers(0, 256, size=(40, 32), dtype=np.uint8), rng.integers(0, 256, size=(50, 32),
                                                                                     dtype=np.uint8)
    hamming = np.unpackbits(bits_a[:, None, :] ^ bits_b[None, :, :], axis=2).sum(axis=2)
    got = nearest.distances(nearest.operands(bits_a, binary=True), nearest.operands(bits_b, binary=True))
    assert np.array_equal(got.astype(np.int64), hamming)
    ops = nearest.operands(a, binary=False)
    assert np.array_equal(ops[30:].rows, ops.rows[30:]) and np.array_equal(ops[30:].columns, ops.columns[30:])


@pytest.mark.parametrize("row_block", [4096, 64])
@pytest.mark.parametrize("prior", [False, True])
def test_the_cross_check_read_off_the_rows_product_equals_the_whole_matrix_ties_included(row_block, prior,
                                                                                         monkeypatch):
    # One block (the columns' nearest rows read off the row pass's matrix) and several (a second product of
    # the chosen columns): the same matches as arg-mins both ways down the whole matrix. Repeated rows in both
    # images make equal distances, whose first row must win.
    monkeypatch.setattr(nearest, "ROW_BLOCK", row_block)
    rng = np.random.default_rng(7)
    base = rng.integers(0, 40, size=(300, 128)).astype(np.float32)
    da = np.vstack([base[:200], base[:20]])
    db = np.vstack([base[100:300] + rng.integers(0, 2, size=(200, 128)), base[150:170]]).astype(np.float32)
    uv_a, uv_b = rng.random((len(da), 2)) * 100, rng.random((len(db), 2)) * 100
    allowed = (np.abs(uv_a[:, None, 1] - uv_b[None, :, 1]) <= 30.0) if prior else None
    got = nearest.mutual_ratio(nearest.operands(da, binary=False), nearest.operands(db, binary=False),
                               ratio=0.9**2, cross_check=True,
                               allowed=None if allowed is None else (lambda rows: allowed[rows]),
                               outside_margin=1.1**2 if prior else np.inf)
    want = _reference_mutual_ratio(da, db, ratio=0.9, allowed=allowed, margin=1.1 if prior else np.inf)
    assert len(want[0]) > 20
    assert [x.tolist() for x in got] == [x.tolist() for x in want]
