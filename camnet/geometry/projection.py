"""Projection through the pinhole camera with OpenCV distortion: camnet's one lens model.

Conventions used across camnet:

- Camera axes: x right, y down, z forward (optical axis). Lengths in metres.
- Two ways to give a pose, one projection: `project` takes ``(R, t)`` with
  ``x_cam = R @ X_world + t`` (the camera centre is ``C = -R.T @ t``), as a
  `camnet.geometry.model.Camera` holds it; the bundle adjustment's
  `project_points` and `project_with_jacobians` take ``(R, C)`` with
  ``x_cam = R @ (X_world - C)``, so ``t = -R @ C``.
- Pixels: ``u`` to the right, ``v`` down, origin at the centre of the top-left
  pixel (OpenCV's convention).
- Intrinsics ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels; the
  distortion ``dist`` in OpenCV's order ``[k1, k2, p1, p2, k3]``, applied to
  normalised coordinates ``x_cam[:2] / x_cam[2]`` before ``K``.
- The bundle adjustment's intrinsic vector per camera is
  ``[f, a, cx, cy, k1, k2, p1, p2, k3]``: ``fx = f``, ``fy = a * f`` (``a`` is
  the pixel aspect, 1 for square pixels), no skew, principal point
  ``(cx, cy)`` in pixels, the distortion after it. Rotations are perturbed on
  the left, ``R <- expm([w]x) R``, which makes ``d x_cam / d w = -[x_cam]x``.
"""

from __future__ import annotations

import numpy as np

DIST_SIZE = 5  # k1, k2, p1, p2, k3
INTRINSIC_NAMES = ("f", "a", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
N_INTRINSICS = len(INTRINSIC_NAMES)
ArrayOrFloat = np.ndarray | float


def full_dist(dist: np.ndarray | list | None) -> np.ndarray:
    """OpenCV distortion padded with zeros to [k1, k2, p1, p2, k3]."""
    out = np.zeros(DIST_SIZE)
    if dist is not None and len(dist):
        d = np.asarray(dist, dtype=float).ravel()
        if d.size > DIST_SIZE:
            raise ValueError(f"distortion has {d.size} coefficients; camnet supports at most 5")
        out[: d.size] = d
    return out


def lens_terms(
    x: np.ndarray, y: np.ndarray,
    k1: ArrayOrFloat, k2: ArrayOrFloat, p1: ArrayOrFloat, p2: ArrayOrFloat, k3: ArrayOrFloat,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's distortion at normalised points (x, y): ``(r2, radial, dx, dy)``.

    The distorted point is ``(x * radial + dx, y * radial + dy)``: a radial
    factor and a tangential shift. The coefficients are scalars or arrays
    broadcasting with x and y (one camera per row).
    """
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return r2, radial, dx, dy


def distort(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV's radial-tangential distortion to normalised points (n, 2)."""
    x, y = xn[:, 0], xn[:, 1]
    _, radial, dx, dy = lens_terms(x, y, *full_dist(dist))
    return np.stack([x * radial + dx, y * radial + dy], axis=1)


def project(
    points_world: np.ndarray,
    *,
    K: np.ndarray,
    dist: np.ndarray | None = None,
    R: np.ndarray | None = None,
    t: np.ndarray | None = None,
) -> np.ndarray:
    """Pixels (n, 2) of world points (n, 3) in metres, pose ``x_cam = R @ X + t``.

    R and t default to the identity and zero; K may have a skew ``K[0, 1]``.
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
    xd = distort(xn, dist)
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


def intrinsics_from_K(K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """The intrinsic vector of a K matrix (zero skew assumed) and OpenCV distortion."""
    return np.array([K[0, 0], K[1, 1] / K[0, 0], K[0, 2], K[1, 2], *dist])


def K_from_intrinsics(intr: np.ndarray) -> np.ndarray:
    f, a, cx, cy = intr[:4]
    return np.array([[f, 0.0, cx], [0.0, a * f, cy], [0.0, 0.0, 1.0]])


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of vectors (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rotation_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) in radians (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    W = skew(w)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    A = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    B = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + A * W + B * (W @ W)


def project_points(intr: np.ndarray, R: np.ndarray, C: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) and camera-frame points (n, 3), one camera per row.

    intr (n, 9), R (n, 3, 3), C (n, 3) and X (n, 3) are per observation.
    """
    xc = np.einsum("nij,nj->ni", R, X - C)
    return _pixels(intr, xc), xc


def _pixels(intr: np.ndarray, xc: np.ndarray) -> np.ndarray:
    f, a, cx, cy = intr[:, :4].T
    x = xc[:, 0] / xc[:, 2]
    y = xc[:, 1] / xc[:, 2]
    _, radial, dx, dy = lens_terms(x, y, *intr[:, 4:].T)
    return np.stack([f * (x * radial + dx) + cx, a * f * (y * radial + dy) + cy], axis=1)


def project_with_jacobians(
    intr: np.ndarray, R: np.ndarray, C: np.ndarray, X: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixels and their derivatives, one observation per row.

    Returns ``(uv (n,2), J_intr (n,2,9), J_rot (n,2,3), J_centre (n,2,3),
    J_point (n,2,3))``: derivatives of the pixel with respect to the
    intrinsic vector, a left rotation perturbation, the camera centre and
    the world point.
    """
    f, a, cx, cy, k1, k2, p1, p2, k3 = intr.T
    xc = np.einsum("nij,nj->ni", R, X - C)
    iz = 1.0 / xc[:, 2]
    x = xc[:, 0] * iz
    y = xc[:, 1] * iz
    r2, radial, dx, dy = lens_terms(x, y, k1, k2, p1, p2, k3)
    xd = x * radial + dx
    yd = y * radial + dy
    fy = a * f
    uv = np.stack([f * xd + cx, fy * yd + cy], axis=1)

    n = len(xc)
    J_intr = np.zeros((n, 2, 9))
    J_intr[:, 0, 0] = xd
    J_intr[:, 1, 0] = a * yd
    J_intr[:, 1, 1] = f * yd
    J_intr[:, 0, 2] = 1.0
    J_intr[:, 1, 3] = 1.0
    for col, power in ((4, 1), (5, 2), (8, 3)):
        rp = r2**power
        J_intr[:, 0, col] = f * x * rp
        J_intr[:, 1, col] = fy * y * rp
    J_intr[:, 0, 6] = f * 2.0 * x * y
    J_intr[:, 1, 6] = fy * (r2 + 2.0 * y * y)
    J_intr[:, 0, 7] = f * (r2 + 2.0 * x * x)
    J_intr[:, 1, 7] = fy * 2.0 * x * y

    # d(xd, yd) / d(x, y)
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    dxd_dx = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    dxd_dy = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    dyd_dx = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    dyd_dy = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    # d pixel / d xc through the normalised point (x, y) = (xc_0 / xc_2, xc_1 / xc_2).
    duv_dn = np.empty((n, 2, 2))
    duv_dn[:, 0, 0] = f * dxd_dx
    duv_dn[:, 0, 1] = f * dxd_dy
    duv_dn[:, 1, 0] = fy * dyd_dx
    duv_dn[:, 1, 1] = fy * dyd_dy
    duv_dxc = np.empty((n, 2, 3))
    duv_dxc[:, :, :2] = duv_dn * iz[:, None, None]
    duv_dxc[:, :, 2] = -(duv_dn[:, :, 0] * x[:, None] + duv_dn[:, :, 1] * y[:, None]) * iz[:, None]
    # a^T [xc]x = a x xc, so d pixel / d w = -duv_dxc [xc]x = xc x duv_dxc (row-wise).
    J_rot = np.cross(xc[:, None, :], duv_dxc)
    J_point = duv_dxc[:, :, :1] * R[:, None, 0] + duv_dxc[:, :, 1:2] * R[:, None, 1] + duv_dxc[:, :, 2:] * R[:, None, 2]
    J_centre = -J_point
    return uv, J_intr, J_rot, J_centre, J_point
