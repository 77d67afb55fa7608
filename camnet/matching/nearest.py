"""Nearest neighbours of descriptors by one matrix product: Lowe's ratio test and the cross check.

Squared L2 distances (SIFT) or Hamming distances (ORB's bits as 0/1) are
|a - b|^2 = |a|^2 + |b|^2 - 2 a.b. Each side's descriptors extended by two
columns, [a, 1, |a|^2] against [-2 b, |b|^2, 1], give every distance of a
block in one product (`Operands`): no passes over the matrix to scale it and
add the norms, a quarter of a pair's matching time. SIFT's descriptors are
whole numbers 0-255 (OpenCV rounds them) of norm about 512, so every term
and partial sum is an integer far below 2**24, exact in float32 whatever
the order BLAS sums in: the distances are those of the formula term by
term, and equal distances compare equal.

With every row of a in one block (the usual case: a few thousand
keypoints), the cross check takes each chosen column's nearest row from the
same matrix, instead of a second product.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

# Rows of the descriptor-distance matrix computed at once: bounds memory at
# ROW_BLOCK x n_b float32 whatever the feature count.
ROW_BLOCK = 2048


class Operands:
    """One image's descriptors as operands of the distance product, as rows or as columns of it.

    ``rows[i] @ columns[j]`` is the distance between descriptors i and j (squared L2, or Hamming of bits).
    Each form is made when first asked for: a pair needs its first camera's rows and its second's
    columns, and a product's operands and matrix held at once beyond glibc's trim threshold are handed
    back and faulted in again at every pair, which costs as much as the pair (docs/benchmarks.md, "The matcher").
    """

    def __init__(self, vectors: np.ndarray) -> None:
        self._vectors = vectors  # (n, d), any real dtype
        self._rows: np.ndarray | None = None
        self._columns: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self._vectors)

    def __getitem__(self, index) -> Operands:
        """The operands of a subset of the descriptors (of a slice: a view, no copy)."""
        return Operands(self._vectors[index])

    @property
    def rows(self) -> np.ndarray:
        """(n, d + 2) float32: [v, 1, |v|^2]."""
        if self._rows is None:
            n, d = self._vectors.shape
            rows = np.empty((n, d + 2), np.float32)
            rows[:, :d] = self._vectors
            rows[:, d], rows[:, d + 1] = 1.0, np.einsum("ij,ij->i", rows[:, :d], rows[:, :d])
            self._rows = rows
        return self._rows

    @property
    def columns(self) -> np.ndarray:
        """(n, d + 2) float32: [-2 v, |v|^2, 1]."""
        if self._columns is None:
            n, d = self._vectors.shape
            columns = np.empty((n, d + 2), np.float32)
            columns[:, :d] = self._vectors
            columns[:, d], columns[:, d + 1] = np.einsum("ij,ij->i", columns[:, :d], columns[:, :d]), 1.0
            columns[:, :d] *= np.float32(-2.0)
            self._columns = columns
        return self._columns


def operands(descriptors: np.ndarray, *, binary: bool) -> Operands:
    """`descriptors` (n, d) as distance operands: float vectors (SIFT), or unpacked bits (`binary`, ORB's uint8)."""
    return Operands(np.unpackbits(descriptors, axis=1) if binary else descriptors)


def distances(a: Operands, b: Operands) -> np.ndarray:
    """(len(a), len(b)) float32 distances; where descriptors are not whole numbers, rounding may leave a
    distance near 0 a little below it (`mutual_ratio` compares them clipped at 0)."""
    return a.rows @ b.columns.T


def mutual_ratio(a: Operands, b: Operands, *, ratio: float, cross_check: bool,
                 allowed: Callable[[np.ndarray], np.ndarray] | None = None,
                 outside_margin: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Indices (m,) into a and b: rows whose nearest column passes the ratio test `ratio` (on the
    distances as they are: squared for SIFT) and, with `cross_check`, has that row as its first nearest.

    `allowed(rows)` may return a boolean (len(rows), len(b)) mask: the test and the cross check then
    run among allowed candidates only, and the best allowed one must be within `outside_margin` times
    the best disallowed one (see `camnet.matching.features.mutual_ratio_matches`).
    """
    n = len(a)
    best = np.full(n, -1, dtype=np.int64)
    keep = np.zeros(n, dtype=bool)
    ratio_f, margin_f = np.float32(ratio), np.float32(outside_margin)
    d = None
    for start in range(0, n, ROW_BLOCK):
        rows = np.arange(start, min(start + ROW_BLOCK, n))
        local = np.arange(len(rows))
        d = a.rows[start:start + len(rows)] @ b.columns.T
        best_outside = np.full(len(rows), np.inf, dtype=d.dtype)
        if allowed is not None:
            outside = ~allowed(rows)
            best_outside = np.where(outside, d, np.inf).min(axis=1)
            d[outside] = np.inf
        # The two smallest of each row: the smallest, then the smallest with it set aside (and put back).
        first = np.argmin(d, axis=1)
        d1 = d[local, first]
        d[local, first] = np.inf
        d2 = d.min(axis=1)
        d[local, first] = d1
        best[rows] = first
        # Ratio on distances: an infinite second best (no other candidate) passes. Clipped here, not in a pass
        # over the matrix (a tenth of a pair's time): whole-number descriptors have no distance below 0.
        d1, d2, best_outside = (np.maximum(x, 0.0) for x in (d1, d2, best_outside))
        keep[rows] = np.isfinite(d1) & (d1 < ratio_f * d2) & (d1 <= margin_f * best_outside)
    ia = np.flatnonzero(keep)
    ib = best[ia]
    if cross_check and len(ia):
        columns, column = np.unique(ib, return_inverse=True)
        # One block holds every row: a chosen column's first nearest row is read off it (arg-min takes the
        # first of equal distances), as a second product of those columns against a would give.
        nearest = d.T[columns].argmin(axis=1) if n <= ROW_BLOCK else _nearest_rows(a, b, columns, allowed)
        mutual = nearest[column] == ia
        ia, ib = ia[mutual], ib[mutual]
    return ia.astype(np.int64), ib.astype(np.int64)


def _nearest_rows(a: Operands, b: Operands, columns: np.ndarray, allowed) -> np.ndarray:
    """For each of `columns` (indices into b), the first nearest row of a among the allowed ones (-1: none).

    For more rows than one block holds: a product of those columns against a is cheaper than an arg-min
    down the columns of every block (a strided pass). Distances are exact (module docstring), so they
    equal the row pass's.
    """
    out = np.full(len(columns), -1, dtype=np.int64)
    mask = None if allowed is None or len(columns) == 0 else allowed(np.arange(len(a)))[:, columns].T
    for start in range(0, len(columns), ROW_BLOCK):
        block = slice(start, min(start + ROW_BLOCK, len(columns)))
        d = distances(b[columns[block]], a)
        if mask is not None:
            d[~mask[block]] = np.inf
        nearest = np.argmin(d, axis=1)
        out[block] = np.where(np.isfinite(d[np.arange(len(nearest)), nearest]), nearest, -1)
    return out
