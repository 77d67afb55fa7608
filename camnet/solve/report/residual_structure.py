"""Structure left in a solve's residuals: what a model that fits leaves as noise, and this does not.

Two patterns name their likely cause: residuals that grow with the distance
from the image centre (lens distortion the solve did not model), and one
camera whose residuals stand far above the others' (it moved while the
frames were taken, fires out of sync, or its lens is unlike theirs). Pixels
follow camnet's convention (origin at the centre of the top-left pixel);
residuals are predicted minus observed.
"""

from __future__ import annotations

import numpy as np

from camnet.model import rowwise

RADIAL_SIGNIFICANCE = 1e-4  # false-alarm rate of the radial pattern's chi-square test, per camera
RADIAL_MIN_PX = 1.0  # a radial pattern smaller than this at the edge of the observations is left alone
OUTLIER_CAMERA_RATIO = 2.0  # a camera's RMS this many times the others' median ...
OUTLIER_CAMERA_EXCESS_PX = 0.5  # ... and this much above it stands out
OUTLIER_CAMERA_REJECTED = 0.15  # as does a camera that lost this much more of its observations than twice theirs
MIN_OBSERVATIONS = 12


def radial_patterns_px(cam: np.ndarray, uv: np.ndarray, residuals: np.ndarray, intr: np.ndarray,
                       sigma_px: float) -> np.ndarray:
    """(M,) size (px, at the outermost observation) of a radial pattern in each camera's residuals; 0 if none.

    cam (n,), uv (n, 2), residuals (n, 2): observations by camera index;
    intr (M, 9): the intrinsics (camnet.model.projection). Per camera, the
    residuals' radial component is fitted with ``a rho + b rho^3 + c rho^5``
    (rho the normalised radius): the linear term is what a focal length
    absorbs, the others the shape of radial distortion. The pattern counts
    when the higher terms lower the sum of squares beyond chance (chi-square,
    2 dof, at `RADIAL_SIGNIFICANCE`, noise `sigma_px` per axis). Every camera
    at once: per-camera fits of a dozen numpy calls each cost more than the sums.
    """
    from scipy.special import chdtri

    M = len(intr)
    p = uv - intr[cam, 2:4]
    radius = rowwise.lengths(p)
    ok = radius > 1.0
    c = cam[ok]
    enough = (np.bincount(c, minlength=M) >= MIN_OBSERVATIONS) & (sigma_px > 0)
    if not enough.any():
        return np.zeros(M)
    e = np.einsum("ni,ni->n", residuals[ok], p[ok]) / radius[ok]
    rho = radius[ok] / intr[c, 0]
    A = np.stack([rho, rho**3, rho**5], axis=1)

    def per_camera(w: np.ndarray) -> np.ndarray:
        return np.bincount(c, weights=w, minlength=M)

    k = per_camera(rho * e) / np.maximum(per_camera(rho * rho), 1e-300)  # the linear term alone
    linear = per_camera((e - rho * k[c]) ** 2)
    AtA = np.stack([np.stack([per_camera(A[:, i] * A[:, j]) for j in range(3)], axis=1) for i in range(3)], axis=1)
    Ate = np.stack([per_camera(A[:, i] * e) for i in range(3)], axis=1)
    AtA[~enough] = np.eye(3)  # cameras with too few observations: any solvable system, their result is dropped
    try:
        coef = np.linalg.solve(AtA, Ate[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:  # a camera whose radii do not fix three terms: the least-squares solution
        coef = np.stack([np.linalg.lstsq(A[c == m], e[c == m], rcond=None)[0] if enough[m] else np.zeros(3)
                         for m in range(M)])
    full = per_camera((e - np.einsum("ni,ni->n", A, coef[c])) ** 2)
    significant = enough & ((linear - full) / max(sigma_px, 1e-300) ** 2 >= chdtri(2, RADIAL_SIGNIFICANCE))
    edge = np.zeros(M)
    np.maximum.at(edge, c, rho)
    return np.where(significant, np.abs(coef[:, 1] * edge**3 + coef[:, 2] * edge**5), 0.0)


def structure_warnings(camera_ids: list[str], cam: np.ndarray, uv: np.ndarray, residuals: np.ndarray,
                       intr: np.ndarray, distortion_free: np.ndarray, observed: np.ndarray) -> list[str]:
    """Warnings naming the cameras whose residuals show structure, with the likely cause.

    cam (n,), uv (n, 2), residuals (n, 2): the solve's inlier observations, by
    camera index into camera_ids; intr (M, 9): the solution's intrinsics
    (camnet.model.projection); distortion_free (M,): whether k1 moved;
    observed (M,): each camera's observations before outliers were rejected.
    """
    if not len(cam):
        return []
    sigma = float(np.sqrt(np.mean(residuals**2)))  # per axis
    M = len(camera_ids)
    counts = np.bincount(cam, minlength=M)
    with np.errstate(invalid="ignore", divide="ignore"):  # NaN: a camera without inliers
        rms = np.sqrt(np.bincount(cam, weights=rowwise.squared_lengths(residuals), minlength=M) / counts)
    rms[counts == 0] = np.nan
    radial = radial_patterns_px(cam, uv, residuals, intr, sigma)
    # Outlier rejection clips a bad camera's residuals: what it rejected shows it as well.
    rejected = 1.0 - counts / np.maximum(observed, 1)
    others = ~np.eye(M, dtype=bool)  # row m: every camera but m
    with np.errstate(all="ignore"):  # a lone camera has no others: NaN, no warning
        typicals = np.nanmedian(np.where(others, rms[None, :], np.nan), axis=1) if M > 1 else np.full(M, np.nan)
        typicals_rejected = np.median(rejected[None, :].repeat(M, axis=0)[others].reshape(M, M - 1), axis=1)
    warnings = []
    for m, cam_id in enumerate(camera_ids):
        typical, typical_rejected = typicals[m], typicals_rejected[m]
        high = rms[m] > OUTLIER_CAMERA_RATIO * typical and rms[m] > typical + OUTLIER_CAMERA_EXCESS_PX
        if high or rejected[m] > OUTLIER_CAMERA_RATIO * typical_rejected + OUTLIER_CAMERA_REJECTED:
            warnings.append(
                f"camera {cam_id}: residuals {rms[m]:.2f} px RMS with {100 * rejected[m]:.0f}% of its observations "
                f"rejected, against {typical:.2f} px and {100 * typical_rejected:.0f}% for the others: it may have "
                "moved while the frames were taken, fire out of sync, or have a lens unlike theirs"
            )
        if distortion_free[m]:
            continue
        edge_px = radial[m]
        if edge_px > RADIAL_MIN_PX:
            warnings.append(
                f"camera {cam_id}: its residuals grow with the distance from the image centre "
                f"({edge_px:.1f} px at the edge): lens distortion the solve held; give its dist or free k1, k2"
            )
    return warnings
