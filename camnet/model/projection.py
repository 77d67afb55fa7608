"""Projection through camnet's two lens models: OpenCV's pinhole with radial-tangential
distortion, and OpenCV's fisheye (Kannala-Brandt).

Conventions used across camnet:

- Camera axes: x right, y down, z forward (optical axis). Lengths in metres.
- Two ways to give a pose, one projection: `project` takes ``(R, t)`` with
  ``x_cam = R @ X_world + t`` (the camera centre is ``C = -R.T @ t``), as a
  `camnet.model.camera.Camera` holds it; the bundle adjustment's
  `project_points` and `project_with_jacobians` take ``(R, C)`` with
  ``x_cam = R @ (X_world - C)``, so ``t = -R @ C``.
- Pixels: ``u`` to the right, ``v`` down, origin at the centre of the top-left
  pixel (OpenCV's convention).
- Intrinsics ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels; the
  distortion ``dist`` in OpenCV's order ``[k1, k2, p1, p2, k3]``, applied to
  normalised coordinates ``x_cam[:2] / x_cam[2]`` before ``K``.
- The fisheye model (``cv2.fisheye``, for lenses wider than about 120
  degrees): ``dist = [k1, k2, k3, k4]``; a ray at angle ``theta`` (radians)
  from the optical axis lands at the distance ``theta_d = theta (1 + k1
  theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` from the principal point,
  in focal lengths, in the ray's azimuth, before ``K``.
- The bundle adjustment's intrinsic vector per camera is
  ``[f, a, cx, cy, d0, d1, d2, d3, d4]``: ``fx = f``, ``fy = a * f`` (``a`` is
  the pixel aspect, 1 for square pixels), no skew, principal point
  ``(cx, cy)`` in pixels, then the camera's ``dist`` as given: a pinhole's
  ``[k1, k2, p1, p2, k3]``, a fisheye's ``[k1, k2, k3, k4, 0]`` (its last slot
  unused and held). The slots' names are `INTRINSIC_NAMES` for a pinhole,
  `FISHEYE_INTRINSIC_NAMES` for a fisheye. A per-row ``fisheye`` mask says
  which model projects. Rotations are perturbed on
  the left, ``R <- expm([w]x) R``, which makes ``d x_cam / d w = -[x_cam]x``.
"""

from __future__ import annotations

import numpy as np

DIST_SIZE = 5  # k1, k2, p1, p2, k3
FISHEYE_DIST_SIZE = 4  # k1, k2, k3, k4 of the fisheye model
INTRINSIC_NAMES = ("f", "a", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
FISHEYE_INTRINSIC_NAMES = ("f", "a", "cx", "cy", "k1", "k2", "k3", "k4", "unused")  # the same slots, a fisheye's
N_INTRINSICS = len(INTRINSIC_NAMES)
ArrayOrFloat = np.ndarray | float


def full_dist(dist: np.ndarray | list | None, size: int = DIST_SIZE) -> np.ndarray:
    """OpenCV distortion padded with zeros to `size` coefficients (the pinhole's [k1, k2, p1, p2, k3])."""
    out = np.zeros(size)
    if dist is not None and len(dist):
        d = np.asarray(dist, dtype=float).ravel()
        if d.size > size:
            raise ValueError(f"distortion has {d.size} coefficients; the lens model has {size}")
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


def fisheye_terms(
    xc: np.ndarray, k1: ArrayOrFloat, k2: ArrayOrFloat, k3: ArrayOrFloat, k4: ArrayOrFloat
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The fisheye model at camera-frame points xc (n, 3): ``(theta, rho, theta_d, dtheta_d, s)``.

    theta: the ray's angle from the optical axis (rad), rho: its distance
    from the axis (in xc's units), theta_d: the distorted angle, dtheta_d:
    d theta_d / d theta, s: theta_d / rho, the factor that takes ``xc[:, :2]``
    to the distorted normalised point (1 / z on the axis). The angle is
    ``atan2(rho, z)``, which equals OpenCV's ``atan(r)`` in front of the
    camera and stays smooth beyond 90 degrees.
    """
    rho = np.hypot(xc[:, 0], xc[:, 1])
    theta = np.arctan2(rho, xc[:, 2])
    t2 = theta * theta
    theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    dtheta_d = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(rho > 0, theta_d / rho, 1.0 / xc[:, 2])
    return theta, rho, theta_d, dtheta_d, s


def distort_fisheye(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV's fisheye model ``[k1, k2, k3, k4]`` to normalised points (n, 2)."""
    xc = np.column_stack([xn, np.ones(len(xn))])
    s = fisheye_terms(xc, *full_dist(dist, FISHEYE_DIST_SIZE))[4]
    return xn * s[:, None]


def project(
    points_world: np.ndarray,
    *,
    K: np.ndarray,
    dist: np.ndarray | None = None,
    R: np.ndarray | None = None,
    t: np.ndarray | None = None,
    fisheye: bool = False,
) -> np.ndarray:
    """Pixels (n, 2) of world points (n, 3) in metres, pose ``x_cam = R @ X + t``.

    R and t default to the identity and zero; K may have a skew ``K[0, 1]``.
    fisheye: `dist` is the fisheye model's ``[k1, k2, k3, k4]`` (as
    cv2.fisheye.projectPoints), else the pinhole's. Points at or behind the
    camera (z <= 0) give NaN pixels.
    """
    X = np.asarray(points_world, dtype=float).reshape(-1, 3)
    R = np.eye(3) if R is None else np.asarray(R, dtype=float)
    t = np.zeros(3) if t is None else np.asarray(t, dtype=float)
    xc = X @ R.T + t
    z = xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = xc[:, :2] / z[:, None]
    xn[z <= 0] = np.nan
    xd = distort_fisheye(xn, dist) if fisheye else distort(xn, dist)
    K = np.asarray(K, dtype=float)
    u = K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2]
    v = K[1, 1] * xd[:, 1] + K[1, 2]
    return np.stack([u, v], axis=1)


def normalised(uv: np.ndarray, *, K: np.ndarray, dist: np.ndarray | None, fisheye: bool = False) -> np.ndarray:
    """Undistorted normalised coordinates (n, 2), ``x_cam[:2] / x_cam[2]``, of pixels uv (n, 2).

    OpenCV's inverse of `project` (cv2.undistortPoints, or cv2.fisheye.undistortPoints
    when `fisheye`, then `dist` is ``[k1, k2, k3, k4]``). OpenCV clamps a fisheye's
    distorted angle at 90 degrees: a fisheye pixel at or beyond that distance
    from the principal point (in focal lengths) gives NaN rather than a wrong ray.
    """
    import cv2

    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    if not len(pts):  # OpenCV answers no points with None
        return np.empty((0, 2))
    if not fisheye:
        return cv2.undistortPoints(pts, K, full_dist(dist)).reshape(-1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)  # wide angles need more than the default
    D = full_dist(dist, FISHEYE_DIST_SIZE)
    out = cv2.fisheye.undistortPoints(pts, K, D, criteria=criteria).reshape(-1, 2)
    theta_d = np.linalg.norm(cv2.undistortPoints(pts, K, None).reshape(-1, 2), axis=1)
    out[~(theta_d < np.pi / 2)] = np.nan
    return out


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


def _model_rows(fisheye: np.ndarray | None, n: int) -> list[tuple[slice | np.ndarray, bool]]:
    """(rows, is fisheye) per lens model present among n rows; a slice of all rows when only one is."""
    if fisheye is None or not np.any(fisheye):
        return [(slice(None), False)]
    fisheye = np.asarray(fisheye, bool)
    if fisheye.all():
        return [(slice(None), True)]
    return [(~fisheye, False), (fisheye, True)]


def project_points(
    intr: np.ndarray, R: np.ndarray, C: np.ndarray, X: np.ndarray, fisheye: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) and camera-frame points (n, 3), one camera per row.

    intr (n, 9), R (n, 3, 3), C (n, 3) and X (n, 3) are per observation;
    fisheye (n,) bool marks the rows of fisheye cameras (None: none).
    """
    xc = np.einsum("nij,nj->ni", R, X - C)
    xd = np.empty((len(xc), 2))
    for rows, fish in _model_rows(fisheye, len(xc)):
        if fish:
            xd[rows] = xc[rows, :2] * fisheye_terms(xc[rows], *intr[rows, 4:8].T)[4][:, None]
        else:
            x = xc[rows, 0] / xc[rows, 2]
            y = xc[rows, 1] / xc[rows, 2]
            if intr[rows, 4:].any():
                _, radial, dx, dy = lens_terms(x, y, *intr[rows, 4:].T)
                x, y = x * radial + dx, y * radial + dy
            xd[rows] = np.stack([x, y], axis=1)
    f, a, cx, cy = intr[:, :4].T
    return np.stack([f * xd[:, 0] + cx, a * f * xd[:, 1] + cy], axis=1), xc


def _pinhole_jacobians(xc: np.ndarray, dist: np.ndarray, distortion: bool = True):
    """Distorted normalised points (n, 2) and their derivatives by dist (n, 2, 5; None unless
    `distortion`) and by xc (n, 2, 3)."""
    iz = 1.0 / xc[:, 2]
    x = xc[:, 0] * iz
    y = xc[:, 1] * iz
    if not distortion and not dist.any():
        # No distortion (as most live rigs solve): the lens terms are exact ones and zeros, so
        # this is the general case's result without its arithmetic.
        J_xc = np.zeros((len(xc), 2, 3))
        J_xc[:, 0, 0] = J_xc[:, 1, 1] = iz
        J_xc[:, 0, 2] = -x * iz
        J_xc[:, 1, 2] = -y * iz
        return np.stack([x, y], axis=1), None, J_xc
    k1, k2, p1, p2, k3 = dist.T
    r2, radial, dx, dy = lens_terms(x, y, k1, k2, p1, p2, k3)
    J_dist = None
    if distortion:
        J_dist = np.zeros((len(xc), 2, 5))
        for col, power in ((0, 1), (1, 2), (4, 3)):
            rp = r2**power
            J_dist[:, 0, col] = x * rp
            J_dist[:, 1, col] = y * rp
        J_dist[:, 0, 2] = 2.0 * x * y
        J_dist[:, 1, 2] = r2 + 2.0 * y * y
        J_dist[:, 0, 3] = r2 + 2.0 * x * x
        J_dist[:, 1, 3] = 2.0 * x * y
    # d(xd, yd) / d(x, y)
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    dn = np.empty((len(xc), 2, 2))
    dn[:, 0, 0] = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    dn[:, 0, 1] = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    dn[:, 1, 0] = dn[:, 0, 1]
    dn[:, 1, 1] = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    # Through the normalised point (x, y) = (xc_0 / xc_2, xc_1 / xc_2).
    J_xc = np.empty((len(xc), 2, 3))
    J_xc[:, :, :2] = dn * iz[:, None, None]
    J_xc[:, :, 2] = -(dn[:, :, 0] * x[:, None] + dn[:, :, 1] * y[:, None]) * iz[:, None]
    return np.stack([x * radial + dx, y * radial + dy], axis=1), J_dist, J_xc


def _fisheye_jacobians(xc: np.ndarray, dist: np.ndarray, distortion: bool = True):
    """As `_pinhole_jacobians` for the fisheye model (dist (n, 5): k1..k4 and an unused slot)."""
    theta, rho, theta_d, dtheta_d, s = fisheye_terms(xc, *dist[:, :4].T)
    z = xc[:, 2]
    xd = xc[:, :2] * s[:, None]
    J_dist = None
    if distortion:
        J_dist = np.zeros((len(xc), 2, 5))
        theta_over_rho = np.where(rho > 0, theta / np.where(rho > 0, rho, 1.0), 1.0 / z)
        for col in range(4):
            J_dist[:, :, col] = xc[:, :2] * (theta_over_rho * theta ** (2 * col + 2))[:, None]
    # s = theta_d / rho with theta = atan2(rho, z): d s / d xc = (g x0, g x1, h), where
    # g = (dtheta_d z / (rho^2 + z^2) - s) / rho^2, h = -dtheta_d / (rho^2 + z^2). g's difference
    # cancels near the axis, but only g x0 x0 and g x0 x1 enter, whose error stays at rounding.
    rr = rho * rho + z * z
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(rho > 0, (dtheta_d * z / rr - s) / (rho * rho), 0.0)
    ds = np.column_stack([g * xc[:, 0], g * xc[:, 1], -dtheta_d / rr])
    J_xc = xc[:, :2, None] * ds[:, None, :]
    J_xc[:, 0, 0] += s
    J_xc[:, 1, 1] += s
    return xd, J_dist, J_xc


def project_with_jacobians(
    intr: np.ndarray, R: np.ndarray, C: np.ndarray, X: np.ndarray, fisheye: np.ndarray | None = None, *,
    distortion: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixels and their derivatives, one observation per row (fisheye as in `project_points`).

    Returns ``(uv (n,2), J_intr (n,2,9), J_rot (n,2,3), J_centre (n,2,3),
    J_point (n,2,3))``: derivatives of the pixel with respect to the
    intrinsic vector, a left rotation perturbation, the camera centre and
    the world point. distortion=False skips the derivatives by the
    distortion coefficients (J_intr[..., 4:] stays zero), for a caller that
    holds them.
    """
    f, a = intr[:, 0], intr[:, 1]
    xc = np.einsum("nij,nj->ni", R, X - C)
    n = len(xc)
    models = _model_rows(fisheye, n)
    if len(models) == 1:  # one lens model: no rows to pick out and copy back
        lens = _fisheye_jacobians if models[0][1] else _pinhole_jacobians
        xd, J_dist, J_xc = lens(xc, intr[:, 4:], distortion)
    else:
        xd, J_dist, J_xc = np.empty((n, 2)), np.empty((n, 2, 5)), np.empty((n, 2, 3))
        for rows, fish in models:
            lens = _fisheye_jacobians if fish else _pinhole_jacobians
            xd[rows], J_dist_rows, J_xc[rows] = lens(xc[rows], intr[rows, 4:], distortion)
            if distortion:
                J_dist[rows] = J_dist_rows
    fy = a * f
    uv = np.stack([f * xd[:, 0] + intr[:, 2], fy * xd[:, 1] + intr[:, 3]], axis=1)
    scale = np.stack([f, fy], axis=1)[:, :, None]  # d pixel / d distorted normalised point, per axis

    J_intr = np.zeros((n, 2, 9))
    J_intr[:, 0, 0] = xd[:, 0]
    J_intr[:, 1, 0] = a * xd[:, 1]
    J_intr[:, 1, 1] = f * xd[:, 1]
    J_intr[:, 0, 2] = 1.0
    J_intr[:, 1, 3] = 1.0
    if distortion:
        J_intr[:, :, 4:] = scale * J_dist
    duv_dxc = scale * J_xc
    # a^T [xc]x = a x xc, so d pixel / d w = -duv_dxc [xc]x = xc x duv_dxc (row-wise).
    J_rot = np.empty((n, 2, 3))
    x0, x1, x2 = xc[:, 0, None], xc[:, 1, None], xc[:, 2, None]
    J_rot[:, :, 0] = x1 * duv_dxc[:, :, 2] - x2 * duv_dxc[:, :, 1]
    J_rot[:, :, 1] = x2 * duv_dxc[:, :, 0] - x0 * duv_dxc[:, :, 2]
    J_rot[:, :, 2] = x0 * duv_dxc[:, :, 1] - x1 * duv_dxc[:, :, 0]
    J_point = duv_dxc @ R  # a batched matmul: faster than broadcasting for 2x3 by 3x3
    J_centre = -J_point
    return uv, J_intr, J_rot, J_centre, J_point
