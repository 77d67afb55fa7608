"""Squared lengths, lengths and dot products of many short rows ((n, 2) or (n, 3) arrays).

The same numbers as numpy's reductions over the last axis (``np.sum(x * x,
axis=1)``, ``np.linalg.norm(x, axis=1)``), bit for bit: those add the two or
three products of a row in this order too. A reduction pays a per-row cost
that a column-wise sum does not, several times the sum's own on rows this
short, and a solve's report takes a dozen of them (docs/benchmarks.md,
"Evidence behind the solver's thresholds").
"""

from __future__ import annotations

import numpy as np


def dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) the dot product of each row of a (n, k) with the same row of b (n, k)."""
    out = a[:, 0] * b[:, 0]
    for k in range(1, a.shape[1]):
        out += a[:, k] * b[:, k]
    return out


def squared_lengths(x: np.ndarray) -> np.ndarray:
    """(n,) the squared length of each row of x (n, k)."""
    return dots(x, x)


def lengths(x: np.ndarray) -> np.ndarray:
    """(n,) the length of each row of x (n, k)."""
    return np.sqrt(dots(x, x))
