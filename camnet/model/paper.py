"""The paper's method: Euclidean auto calibration from a parallel stereo pair
with known baseline (Vupparaboina, Raghavan and Jana, Sec. II-III).

All pixel coordinates here are *centred*: ``x = u - cx``, ``y = v - cy``,
with the principal point taken as known (the image centre unless the
observations give K). The stereo pair is ideal: both rotations identity, the
right camera at ``(l, 0, 0)`` in the left camera's frame.
"""

from __future__ import annotations

import numpy as np
import scipy.optimize

from camnet.errors import SolveError


def focal_ratio(y_left: np.ndarray, y_right: np.ndarray) -> float:
    """k = f_right / f_left from the rows of stereo matches (eq. 4), by least squares.

    An ideal parallel pair images a point on rows ``y_right = k * y_left``.
    Mismatched rows would drag a plain fit, so it starts from the median
    ratio of rows away from the centre line and refits on the rows that agree.
    """
    y1, y2 = np.asarray(y_left, float), np.asarray(y_right, float)
    away = np.abs(y1) > 0.25 * np.median(np.abs(y1))
    k = float(np.median(y2[away] / y1[away])) if away.sum() >= 3 else 1.0
    for _ in range(3):
        r = y2 - k * y1
        keep = np.abs(r) < max(5.0 * 1.4826 * np.median(np.abs(r)), 1.0)
        if keep.sum() < 2:
            break
        k = float(np.sum(y1[keep] * y2[keep]) / np.sum(y1[keep] ** 2))
    return k


def triangulate_parallel(
    left: np.ndarray, right: np.ndarray, k: float, baseline_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Points of an ideal parallel pair, up to the left focal length (eqs. 2-5).

    left, right: centred pixels (n, 2). Returns ``(P0 (n, 3), valid (n,))``
    where the point in the left camera's frame is ``P0 * [1, 1, f_left]``:
    X and Y in metres do not depend on the focal length, Z is proportional
    to it. Written with the disparity ``d = x1 - x2 / k`` rather than the
    paper's y-products, which vanish for points level with the pair.
    Points with non-positive disparity (behind the pair or mismatched) are
    marked invalid.
    """
    x1, y1 = left[:, 0], left[:, 1]
    x2, y2 = right[:, 0] / k, right[:, 1] / k
    d = x1 - x2
    valid = d > 1e-6
    ds = np.where(valid, d, 1.0)
    P0 = np.stack([baseline_m * x1 / ds, baseline_m * 0.5 * (y1 + y2) / ds, baseline_m / ds], axis=1)
    return P0, valid


def _dlt_batch(X: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Projection matrices (H, 3, 4) from batches of 3-D/2-D matches (H, m, 3), (H, m, 2)."""
    H, m, _ = X.shape
    Xh = np.concatenate([X, np.ones((H, m, 1))], axis=2)
    A = np.zeros((H, 2 * m, 12))
    A[:, 0::2, 0:4] = Xh
    A[:, 0::2, 8:12] = -x[:, :, :1] * Xh
    A[:, 1::2, 4:8] = Xh
    A[:, 1::2, 8:12] = -x[:, :, 1:] * Xh
    _, _, vt = np.linalg.svd(A, full_matrices=False)
    return vt[:, -1, :].reshape(H, 3, 4)


def _reprojection_errors(P: np.ndarray, X: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(H, n) pixel errors of projection matrices (H, 3, 4) on points X (n, 3), pixels x (n, 2)."""
    Xh = np.concatenate([X, np.ones((len(X), 1))], axis=1)
    proj = np.einsum("hij,nj->hni", P, Xh)
    z = proj[:, :, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.linalg.norm(proj[:, :, :2] / z[:, :, None] - x[None], axis=2)
    return np.where(np.isfinite(err), err, np.inf)


def dlt_ransac(
    X: np.ndarray,
    x: np.ndarray,
    *,
    threshold_px: float,
    seed: int = 0,
    n_hypotheses: int = 256,
    confidence: float = 0.999,
) -> tuple[np.ndarray, np.ndarray]:
    """A general 3x4 projection matrix from 3-D points (n, 3) and pixels (n, 2), with RANSAC.

    Both sides are normalised (per axis) for conditioning; the result acts
    on the caller's coordinates. Hypotheses are drawn in batches until the
    best inlier share found so far makes an all-outlier draw unlikely
    (``confidence``), at most ``n_hypotheses``. Returns ``(P (3, 4),
    inliers (n,))``. Needs n >= 6 points not all on one plane.
    """
    n = len(X)
    if n < 6:
        raise SolveError(f"a camera shares only {n} points with the solved ones (need at least 6)")
    mX, sX = X.mean(axis=0), X.std(axis=0) + 1e-12
    mx, sx = x.mean(axis=0), x.std() + 1e-12
    Tx_inv = np.array([[sx, 0, mx[0]], [0, sx, mx[1]], [0, 0, 1]])
    TX = np.diag(np.append(1 / sX, 1.0))
    TX[:3, 3] = -mX / sX
    Xn, xn = (X - mX) / sX, (x - mx) / sx

    def denormalise(P: np.ndarray) -> np.ndarray:
        return Tx_inv @ P @ TX

    rng = np.random.default_rng(seed)
    # Score on a subset: a few hundred points rank hypotheses as well as all of them.
    probe = rng.choice(n, size=min(n, 300), replace=False)
    best_score, best_P, drawn, needed = np.inf, None, 0, n_hypotheses
    batch = 32
    while drawn < n_hypotheses:
        samples = np.argsort(rng.random((batch, n)), axis=1)[:, :6]
        P = denormalise(_dlt_batch(Xn[samples], xn[samples]))
        err = _reprojection_errors(P, X[probe], x[probe])
        score = np.sum(np.minimum(err, threshold_px) ** 2, axis=1)  # MSAC
        drawn += batch
        if score.min() < best_score:
            best_score, best_P = score.min(), P[np.argmin(score)]
            share = float(np.mean(err[np.argmin(score)] < threshold_px))
            needed = np.log(1.0 - confidence) / np.log1p(-min(max(share**6, 1e-12), 1.0 - 1e-12))
        if drawn >= needed:
            break
    inliers = _reprojection_errors(best_P[None], X, x)[0] < threshold_px
    for _ in range(3):  # refit on the consensus set
        if inliers.sum() < 6:
            break
        P_best = denormalise(_dlt_batch(Xn[inliers][None], xn[inliers][None])[0])
        new = _reprojection_errors(P_best[None], X, x)[0] < threshold_px
        if np.array_equal(new, inliers):
            break
        inliers = new
    if inliers.sum() < 6:
        raise SolveError("no consistent camera found among the matches (too many outliers)")
    P_best = denormalise(_dlt_batch(Xn[inliers][None], xn[inliers][None])[0])
    return P_best, inliers


def focals_from_stretched_dlt(P: np.ndarray) -> tuple[float, float]:
    """(f_i, f_left) from a DLT matrix fitted to the stereo cloud P0 (f_left = 1).

    With centred pixels and square pixels, ``P[:, :3] ~ diag(f_i, f_i, 1) R
    diag(1, 1, f_left)``: the columns of ``diag(1/f_i, 1/f_i, 1) P[:, :3]``
    must be orthogonal, the first two of equal length and the third
    ``f_left`` times as long. Four of those conditions are linear in
    ``1 / f_i**2``; NaN where the geometry does not fix them.
    """
    M = P[:, :3]
    xy = M[0][:, None] * M[0][None] + M[1][:, None] * M[1][None]
    zz = M[2][:, None] * M[2][None]
    a = np.array([xy[0, 1], xy[0, 0] - xy[1, 1], xy[0, 2], xy[1, 2]])
    b = np.array([zz[0, 1], zz[0, 0] - zz[1, 1], zz[0, 2], zz[1, 2]])
    w = -float(a @ b) / float(a @ a)
    if not w > 0:
        return float("nan"), float("nan")
    f_i = 1.0 / np.sqrt(w)
    A = M / np.array([f_i, f_i, 1.0])[:, None]
    rho2 = 0.5 * (A[:, 0] @ A[:, 0] + A[:, 1] @ A[:, 1])
    return f_i, float(np.linalg.norm(A[:, 2]) / np.sqrt(rho2))


def pose_from_dlt(P: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(f, R, C) from a metric DLT matrix on centred pixels, pixels taken as square."""
    import cv2

    K, R, Ch = cv2.decomposeProjectionMatrix(P)[:3]
    K = K / K[2, 2]
    # RQ leaves signs free: make the focal lengths positive and R proper.
    S = np.diag(np.sign(np.diag(K)))
    K, R = K @ S, S @ R
    if np.linalg.det(R) < 0:
        R = -R
    C = (Ch[:3] / Ch[3]).ravel()
    return float(0.5 * (K[0, 0] + K[1, 1])), R, C


def _rotvec_to_R(w: np.ndarray) -> np.ndarray:
    from camnet.model.projection import rotation_exp

    return rotation_exp(w)


def refine_eq13(
    f_left: float,
    f: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    P0: np.ndarray,
    cams: list[np.ndarray],
    *,
    ftol: float = 1e-8,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, float]:
    """Minimise eq. 13 jointly over f_left and every other camera's f, R, C.

    ``cams[j] = (tracks (n,), centred pixels (n, 2))`` for the j-th other
    camera; ``f, R, C`` hold their starting values in the same order. The
    points are ``P0 * [1, 1, f_left]``, so they move only through f_left.
    ftol: relative cost change at which to stop (SciPy's); a starting point
    for an adjustment needs far less than the paper's solution itself.
    """
    from scipy.spatial.transform import Rotation

    m = len(cams)
    x0 = [np.log(f_left)]
    for j in range(m):
        x0 += [np.log(f[j]), *Rotation.from_matrix(R[j]).as_rotvec(), *C[j]]
    x0 = np.asarray(x0)
    sizes = [2 * len(trk) for trk, _ in cams]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    tracks = np.concatenate([trk for trk, _ in cams])
    pixels = np.concatenate([xy for _, xy in cams])
    cam_of = np.repeat(np.arange(m), [len(trk) for trk, _ in cams])

    def unpack(x: np.ndarray):
        per = x[1:].reshape(m, 7)
        return np.exp(x[0]), np.exp(per[:, 0]), _rotvec_to_R(per[:, 1:4]), per[:, 4:7]

    def fun(x: np.ndarray) -> np.ndarray:
        fl, fs, Rs, Cs = unpack(x)
        X = P0[tracks] * np.array([1.0, 1.0, fl])
        xc = np.einsum("nij,nj->ni", Rs[cam_of], X - Cs[cam_of])
        with np.errstate(divide="ignore", invalid="ignore"):
            out = (fs[cam_of, None] * xc[:, :2] / xc[:, 2:3] - pixels).ravel()
        return np.where(np.isfinite(out), out, 1e6)

    sparsity = np.zeros((starts[-1], len(x0)), dtype=bool)
    sparsity[:, 0] = True
    for j in range(m):
        sparsity[starts[j] : starts[j + 1], 1 + 7 * j : 8 + 7 * j] = True
    res = scipy.optimize.least_squares(fun, x0, jac_sparsity=sparsity, method="trf", x_scale="jac", ftol=ftol)
    fl, fs, Rs, Cs = unpack(res.x)
    return float(fl), fs, Rs, Cs, float(res.cost)
