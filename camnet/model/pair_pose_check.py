"""A camera's solved pose against the relative pose its own two views with a neighbour give.

A bundle adjustment can settle a camera in a wrong place that the rest of
the network's tracks still fit: a ring's camera turned a few degrees with
its principal point, or placed beside its neighbour where it stands 30
degrees away. The essential matrix of the two cameras' shared observations
alone, through the calibration's own intrinsics, is an opinion the rest of
the network cannot bend. Where it and the solved relative pose differ by
more than the two-view estimate's own uncertainty, one of the two cameras is
not where the calibration says.

Conventions: ``x_cam = R X + t``; the relative pose of camera j from camera
i is ``x_j = R_ij x_i + t_ij`` with ``R_ij = R_j R_i^T`` and
``t_ij = t_j - R_ij t_i``; the two-view translation is a direction (unit).
Pixels are OpenCV's (origin at the first pixel's centre).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from camnet.model.calibration import Calibration, PairPoseCheck
from camnet.model.camera import Camera, LensModel
from camnet.model.observations import Observations
from camnet.model.projection import normalised
from camnet.model.two_view import relative_pose

NEIGHBOURS = 4  # each camera is checked with the cameras it shares the most tracks with, at most this many
MIN_SHARED = 30  # shared observations below which two views say too little to judge a pose
MAX_MATCHES = 300  # of a pair's shared observations, the most that enter its check
RANSAC_SEED = 0
THRESHOLD_PX = 2.0  # RANSAC's inlier distance for the essential matrix, pixels at the cameras' focal length


def pair_checks(cal: Calibration, obs: Observations, *,
                skip: frozenset[frozenset[str]] = frozenset()) -> list[PairPoseCheck]:
    """Each calibrated camera against its NEIGHBOURS neighbours (most tracks shared with it, at least
    MIN_SHARED) in `obs`, every pair once but those in `skip` (sets of two camera ids); a pair whose two views
    give no essential matrix is left out."""
    cameras = {c.id: c for c in cal.cameras}
    index = [obs.index_of(c) for c in cameras]
    seen = np.zeros((len(obs.cameras), len(obs.track_ids)), bool)
    seen[obs.cam_index, obs.track_index] = True
    shared = seen[index].astype(int) @ seen[index].T.astype(int)
    np.fill_diagonal(shared, 0)
    ids = list(cameras)
    pairs = set()
    for a in range(len(index)):
        for b in np.argsort(-shared[a], kind="stable")[:NEIGHBOURS]:
            if shared[a, b] >= MIN_SHARED and frozenset((ids[a], ids[int(b)])) not in skip:
                pairs.add((min(a, int(b)), max(a, int(b))))
    out = []
    for a, b in sorted(pairs):
        uv_a, uv_b = _shared_pixels(obs, index[a], index[b])
        check = check_pair(cameras[ids[a]], cameras[ids[b]], uv_a, uv_b)
        if check is not None:
            out.append(check)
    return out


def _shared_pixels(obs: Observations, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) in cameras i and j (observation indices) of the tracks both see, in one order."""
    uv = np.full((2, len(obs.track_ids), 2), np.nan)
    for k, cam in enumerate((i, j)):
        rows = obs.cam_index == cam
        uv[k, obs.track_index[rows]] = obs.uv[rows]
    both = np.isfinite(uv[0, :, 0]) & np.isfinite(uv[1, :, 0])
    return uv[0, both], uv[1, both]


def relative(cam_i: Camera, cam_j: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(R_ij, t_ij): camera j's pose in camera i's frame, ``x_j = R_ij x_i + t_ij`` (metres)."""
    R = cam_j.R @ cam_i.R.T
    return R, cam_j.t - R @ cam_i.t


def check_pair(cam_i: Camera, cam_j: Camera, uv_i: np.ndarray, uv_j: np.ndarray) -> PairPoseCheck | None:
    """Cameras i and j's solved relative pose against the essential matrix of their matched pixels uv_i, uv_j
    (n, 2), undistorted through each camera's own intrinsics, at most MAX_MATCHES of them; None where fewer than
    MIN_SHARED matches remain or no essential matrix is found."""
    import cv2

    n_i, J_i = _rays(cam_i, uv_i)
    n_j, J_j = _rays(cam_j, uv_j)
    ok = (np.isfinite(n_i).all(axis=1) & np.isfinite(n_j).all(axis=1)
          & np.isfinite(J_i).all(axis=(1, 2)) & np.isfinite(J_j).all(axis=(1, 2)))
    # Evenly thinned: a few hundred matches tell a misplaced camera as well as thousands, at a fraction of the time.
    rows = np.flatnonzero(ok)[:: max(1, int(np.ceil(ok.sum() / MAX_MATCHES)))]
    n_i, n_j, J_i, J_j = n_i[rows], n_j[rows], J_i[rows], J_j[rows]
    if len(n_i) < MIN_SHARED:
        return None
    f_i, f_j = float(cam_i.K[0, 0]), float(cam_j.K[0, 0])
    cv2.setRNGSeed(RANSAC_SEED)  # the same observations give the same check, whatever ran before
    pose = relative_pose(n_i * f_i, n_j * f_j, f_i, f_j, threshold_px=THRESHOLD_PX)
    if pose is None or pose.inliers.sum() < MIN_SHARED:
        return None
    R_solved, t_solved = relative(cam_i, cam_j)
    norm = np.linalg.norm(t_solved)
    if norm == 0:  # one viewpoint: no baseline direction to compare
        return None
    t_solved = t_solved / norm

    def distances(R: np.ndarray, t: np.ndarray, rows=slice(None)) -> np.ndarray:
        return _sampson_px(n_i[rows], n_j[rows], J_i[rows], J_j[rows], R, t)

    def cost(R: np.ndarray, t: np.ndarray) -> float:  # MSAC's: each match's squared distance, at most THRESHOLD's
        return float(np.sum(np.minimum(distances(R, t) ** 2, THRESHOLD_PX**2)))

    def refined(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rows = np.abs(distances(R, t)) < THRESHOLD_PX
        if rows.sum() < MIN_SHARED:
            return R, t
        # To a thousandth of the cost: the ratio it feeds is read to a sigma, not to its last digit.
        fit = least_squares(lambda p: distances(*_perturbed(p, R, t), rows), np.zeros(5), method="lm", ftol=1e-3)
        return _perturbed(fit.x, R, t)

    # The two views' best fit: refined from the solved pose, and from RANSAC's minimal sample where that fits
    # better still (on repeated structure it may explain fewer matches than the solved one), the least cost kept.
    starts = [(R_solved, t_solved)] + ([(pose.R, pose.t)] if cost(pose.R, pose.t) < cost(R_solved, t_solved) else [])
    R_pair, t_pair = min((refined(R, t) for R, t in starts), key=lambda rt: cost(*rt))
    r = distances(R_pair, t_pair)
    inliers = np.abs(r) < THRESHOLD_PX
    if inliers.sum() < MIN_SHARED:
        return None
    # The distances' spread, robustly, at least a tenth of a pixel (features are no better).
    sigma_px = max(1.4826 * float(np.median(np.abs(r[inliers]))), 0.1)
    # The likelihood ratio of the solved pose against the best, not a linearised covariance: exact along the
    # curved valleys of far, shallow scenes; about chi-square with 5 degrees of freedom for a pose that agrees.
    excess = cost(R_solved, t_solved) - cost(R_pair, t_pair)
    return PairPoseCheck(
        first=cam_i.id, second=cam_j.id,
        rotation_deg=float(np.degrees(Rotation.from_matrix(R_solved @ R_pair.T).magnitude())),
        direction_deg=float(np.degrees(np.arccos(np.clip(t_solved @ t_pair, -1.0, 1.0)))),
        in_sigmas=float(np.sqrt(max(excess, 0.0)) / sigma_px), shared=int(ok.sum()), inliers=int(inliers.sum()),
    )


def _rays(cam: Camera, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised coordinates (n, 2) of pixels uv (n, 2) through `cam`'s lens, and their Jacobian (n, 2, 2)
    with respect to the pixel (d normalised / d pixel, by one-pixel differences)."""
    fisheye = cam.model == LensModel.FISHEYE
    n = normalised(uv, K=cam.K, dist=cam.dist, fisheye=fisheye)
    du = normalised(uv + [1.0, 0.0], K=cam.K, dist=cam.dist, fisheye=fisheye) - n
    dv = normalised(uv + [0.0, 1.0], K=cam.K, dist=cam.dist, fisheye=fisheye) - n
    return n, np.stack([du, dv], axis=2)


def _tangent(t: np.ndarray) -> np.ndarray:
    """(2, 3): an orthonormal basis of the plane normal to the unit vector t."""
    a = np.eye(3)[int(np.argmin(np.abs(t)))]
    b1 = np.cross(t, a)
    b1 /= np.linalg.norm(b1)
    return np.stack([b1, np.cross(t, b1)])


def _perturbed(p: np.ndarray, R0: np.ndarray, t0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R0 and unit t0 moved by p (5,): R = exp([p[:3]]) R0, t along t0's tangent plane by p[3:], renormalised."""
    import cv2

    t = t0 + _tangent(t0).T @ p[3:]
    return cv2.Rodrigues(p[:3])[0] @ R0, t / np.linalg.norm(t)


def _sampson_px(x_i: np.ndarray, x_j: np.ndarray, J_i: np.ndarray, J_j: np.ndarray, R: np.ndarray,
                t: np.ndarray) -> np.ndarray:
    """Sampson distances (n,), pixels, of normalised matches x_i, x_j (n, 2) to the essential matrix [t]x R:
    the epipolar constraint over its gradient with respect to the four pixel coordinates (J: d normalised /
    d pixel, so that a wide lens's stretched edge counts as the pixels it was measured in)."""
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R
    h_i = np.column_stack([x_i, np.ones(len(x_i))])
    h_j = np.column_stack([x_j, np.ones(len(x_j))])
    Ex = h_i @ E.T  # the epipolar line in view j
    Etx = h_j @ E  # and in view i
    grad_j = np.einsum("nab,na->nb", J_j, Ex[:, :2])
    grad_i = np.einsum("nab,na->nb", J_i, Etx[:, :2])
    return np.einsum("ij,ij->i", h_j, Ex) / np.sqrt((grad_j**2).sum(axis=1) + (grad_i**2).sum(axis=1))
