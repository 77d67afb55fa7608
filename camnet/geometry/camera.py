"""The pinhole camera with OpenCV distortion: projection and poses (the Camera type is
camnet.geometry.model.Camera).

Conventions used across camnet:

- Pose: ``x_cam = R @ X_world + t``; the camera centre is ``C = -R.T @ t``.
  Camera axes: x right, y down, z forward (optical axis). Lengths in metres.
- Pixels: ``u`` to the right, ``v`` down, origin at the centre of the top-left
  pixel (OpenCV's convention).
- Intrinsics ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels; the
  distortion ``dist`` in OpenCV's order ``[k1, k2, p1, p2, k3]``, applied to
  normalised coordinates ``x_cam[:2] / x_cam[2]`` before ``K``.
"""

from __future__ import annotations

import numpy as np

DIST_SIZE = 5  # k1, k2, p1, p2, k3


def full_dist(dist: np.ndarray | list | None) -> np.ndarray:
    """OpenCV distortion padded with zeros to [k1, k2, p1, p2, k3]."""
    out = np.zeros(DIST_SIZE)
    if dist is not None and len(dist):
        d = np.asarray(dist, dtype=float).ravel()
        if d.size > DIST_SIZE:
            raise ValueError(f"distortion has {d.size} coefficients; camnet supports at most 5")
        out[: d.size] = d
    return out


def distort(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV's radial-tangential distortion to normalised points (n, 2)."""
    k1, k2, p1, p2, k3 = full_dist(dist)
    x, y = xn[:, 0], xn[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def project(
    points_world: np.ndarray,
    *,
    K: np.ndarray,
    dist: np.ndarray | None = None,
    R: np.ndarray | None = None,
    t: np.ndarray | None = None,
) -> np.ndarray:
    """Project world points (n, 3) in metres to pixels (n, 2).

    Points at or behind the camera (z <= 0) give NaN pixels.
    """
    X = np.asarray(points_world, dtype=float).reshape(-1, 3)
    R = np.eye(3) if R is None else np.asarray(R, dtype=float)
    t = np.zeros(3) if t is None else np.asarray(t, dtype=float)
    xc = X @ R.T + t
    z = xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = xc[:, :2] / z[:, None]
    xn[z <= 0] = np.nan
    xd = distort(xn, full_dist(dist))
    K = np.asarray(K, dtype=float)
    u = K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2]
    v = K[1, 1] * xd[:, 1] + K[1, 2]
    return np.stack([u, v], axis=1)


def look_at(centre: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, -1.0, 0.0)) -> tuple:
    """(R, t) of a camera at `centre` (m) looking at `target`, image-up along `up`.

    `up` is in world coordinates; the default suits a world whose y axis points
    down, as in the left camera's frame.
    """
    centre = np.asarray(centre, dtype=float)
    z = np.asarray(target, dtype=float) - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre
