"""Points from the rays of placed cameras, where the rays part enough to fix a depth.

Cameras in problem order, pixels centred (relative to the principal
point), poses ``x_cam = R (X - C)``, metres, focal lengths in pixels;
points one per track row, NaN where not known.
"""

from __future__ import annotations

import numpy as np

# A track's rays must part by this many pixels to place its point: less leaves its depth undetermined (an
# error of the order of the pixel noise moves it along its ray without bound; two views of 0.5 px noise each
# part by noise alone by more than 2 px in 2% of their tracks, by more than 1 px in 37%).
MIN_PARALLAX_PX = 2.0


def triangulate_missing(order, xy, rows, f, R, C, X, registered) -> int:
    """Midpoint triangulation, in place, of tracks without a point seen by >= 2 placed cameras.

    A track whose rays part by less than MIN_PARALLAX_PX (as pixels of its
    cameras' mean focal length) is left unknown: its depth is not
    determined (two views from one viewpoint, a pure rotation between them,
    triangulate nothing), and a point free along its ray stalls the adjustment.
    """
    todo = np.flatnonzero(~np.all(np.isfinite(X), axis=1))
    A, b, enough = _rays(todo, order, xy, rows, f, R, C, registered)
    good = todo[enough]
    X[good] = np.linalg.solve(A[enough], b[enough][:, :, None])[:, :, 0]
    return len(good)


def ray_points(tracks: np.ndarray, order, xy, rows, f, R, C, registered) -> np.ndarray:
    """(n, 3) midpoints of `tracks` (n,) from the rays of the `registered` (M,) cameras; NaN where fewer than
    two see a track or its rays part by less than MIN_PARALLAX_PX."""
    A, b, parted = _rays(tracks, order, xy, rows, f, R, C, registered)
    X = np.full((len(tracks), 3), np.nan)
    X[parted] = np.linalg.solve(A[parted], b[parted][:, :, None])[:, :, 0]
    return X


def _rays(tracks, order, xy, rows, f, R, C, registered) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A (n, 3, 3), b (n, 3), parted (n,) bool) for `tracks` (n,): the midpoint's normal equations A X = b over
    the placed cameras' rays, and whether they part by MIN_PARALLAX_PX, over at least two cameras."""
    A = np.zeros((len(tracks), 3, 3))
    b = np.zeros((len(tracks), 3))
    count = np.zeros(len(tracks), dtype=int)
    f_sum = np.zeros(len(tracks))
    for m in np.flatnonzero(registered):
        here = np.flatnonzero(rows[tracks, order[m]] >= 0)
        if not len(here):
            continue
        p = xy[rows[tracks[here], order[m]]] / f[m]
        d = np.concatenate([p, np.ones((len(here), 1))], axis=1) @ R[m]  # rays in the world
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        Pm = np.eye(3) - d[:, :, None] * d[:, None, :]
        A[here] += Pm
        b[here] += Pm @ C[m]
        count[here] += 1
        f_sum[here] += f[m]
    parted = count >= 2
    ok = np.flatnonzero(parted)
    if len(ok):
        # Two rays an angle a apart leave A's least eigenvalue at 1 - cos a, about a^2 / 2; more rays, more.
        least = np.linalg.eigvalsh(A[ok])[:, 0]
        parallax_rad = MIN_PARALLAX_PX * count[ok] / f_sum[ok]
        parted[ok] = least >= 0.5 * parallax_rad**2
    return A, b, parted
