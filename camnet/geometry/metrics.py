"""Accuracy of a reconstruction against ground truth (both in metres)."""

from __future__ import annotations

import numpy as np


def similarity(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ~ s * R @ src + t`` (Umeyama 1991): (s, R, t).

    weights (n,): per-point weights of the squared distances (default equal).
    """
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    ms, md = w @ src, w @ dst
    a, b = src - ms, dst - md
    U, D, Vt = np.linalg.svd((b * w[:, None]).T @ a)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / np.sum(w[:, None] * a * a))
    return s, R, md - s * R @ ms


def scale_error(estimated: np.ndarray, true: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Relative scale error of an estimated cloud (n, 3): s - 1 for ``est ~ s R true + t``.

    weights (n,): as in `similarity`; camnet's reported scale uses the points'
    inverse variances (`camnet.geometry.uncertainty.scale_weights`).
    """
    s, _, _ = similarity(true, estimated, weights)
    return s - 1.0


def shape_rms_m(estimated: np.ndarray, true: np.ndarray) -> float:
    """RMS distance (m) between the true cloud and the estimate after similarity alignment."""
    s, R, t = similarity(estimated, true)
    aligned = s * estimated @ R.T + t
    return float(np.sqrt(np.mean(np.sum((aligned - true) ** 2, axis=1))))
