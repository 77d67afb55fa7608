"""The observations of a bundle adjustment taken camera by camera, as its normal equations take them.

Arrays of indices only: which row of the reordered observations is which
observation, where each camera's run of rows lies, and the sparse sum that
adds per-row terms into their points.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def camera_by_camera(
    cam: np.ndarray, pt: np.ndarray, n_cameras: int, n_points: int, cameras: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """(order (n,), runs (M, 2), point_sum (N, n)) of observations (camera `cam`, point `pt`) taken camera by
    camera in the sequence `cameras` (every camera once).

    order: the observation index of each row; runs[m]: camera m's rows [start, stop); point_sum: sums
    per-row terms into their points. Within a camera, rows keep the observations' order.
    """
    counts = np.bincount(cam, minlength=n_cameras)
    by_camera = np.argsort(cam, kind="stable")
    bounds = np.searchsorted(cam[by_camera], np.arange(n_cameras + 1))
    order = np.concatenate([by_camera[bounds[m] : bounds[m + 1]] for m in cameras] or [np.zeros(0, int)])
    sequence = list(cameras)
    runs = np.zeros((n_cameras, 2), dtype=int)
    runs[sequence, 1] = np.cumsum(counts[sequence])
    runs[sequence, 0] = runs[sequence, 1] - counts[sequence]
    pt = pt[order]
    n = len(order)
    by_point = np.argsort(pt, kind="stable")  # CSR by hand: scipy's COO conversion costs milliseconds
    indptr = np.searchsorted(pt[by_point], np.arange(n_points + 1))
    point_sum = sp.csr_matrix((np.ones(n), by_point, indptr), shape=(n_points, n))
    return order, runs, point_sum
