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

RADIAL_SIGNIFICANCE = 1e-4  # false-alarm rate of the radial pattern's chi-square test, per camera
RADIAL_MIN_PX = 1.0  # a radial pattern smaller than this at the edge of the observations is left alone
OUTLIER_CAMERA_RATIO = 2.0  # a camera's RMS this many times the others' median ...
OUTLIER_CAMERA_EXCESS_PX = 0.5  # ... and this much above it stands out
OUTLIER_CAMERA_REJECTED = 0.15  # as does a camera that lost this much more of its observations than twice theirs
MIN_OBSERVATIONS = 12


def radial_pattern_px(uv: np.ndarray, residuals: np.ndarray, principal_point: np.ndarray, f_px: float,
                      sigma_px: float) -> float:
    """Size (px, at the outermost observation) of a radial pattern in one camera's residuals; 0 if none.

    The residuals' radial component is fitted with ``a rho + b rho^3 + c rho^5``
    (rho the normalised radius): the linear term is what a focal length
    absorbs, the others the shape of radial distortion. The pattern counts
    when the higher terms lower the sum of squares beyond chance (chi-square,
    2 dof, at `RADIAL_SIGNIFICANCE`, noise `sigma_px` per axis).
    """
    from scipy.special import chdtri

    p = uv - principal_point
    radius = np.linalg.norm(p, axis=1)
    ok = radius > 1.0
    if ok.sum() < MIN_OBSERVATIONS or sigma_px <= 0:
        return 0.0
    e = np.einsum("ni,ni->n", residuals[ok], p[ok]) / radius[ok]
    rho = radius[ok] / f_px
    A = np.column_stack([rho, rho**3, rho**5])
    linear = np.sum((e - rho * (rho @ e) / (rho @ rho)) ** 2)
    coef, *_ = np.linalg.lstsq(A, e, rcond=None)
    full = np.sum((e - A @ coef) ** 2)
    if (linear - full) / sigma_px**2 < chdtri(2, RADIAL_SIGNIFICANCE):
        return 0.0
    edge = rho.max()
    return float(abs(coef[1] * edge**3 + coef[2] * edge**5))


def structure_warnings(camera_ids: list[str], cam: np.ndarray, uv: np.ndarray, residuals: np.ndarray,
                       intr: np.ndarray, distortion_free: np.ndarray, observed: np.ndarray) -> list[str]:
    """Warnings naming the cameras whose residuals show structure, with the likely cause.

    cam (n,), uv (n, 2), residuals (n, 2): the solve's inlier observations, by
    camera index into camera_ids; intr (M, 9): the solution's intrinsics
    (camnet.geometry.projection); distortion_free (M,): whether k1 moved;
    observed (M,): each camera's observations before outliers were rejected.
    """
    if not len(cam):
        return []
    sigma = float(np.sqrt(np.mean(residuals**2)))  # per axis
    M = len(camera_ids)
    by_camera = np.argsort(cam, kind="stable")  # camera m's rows, in order: by_camera[bounds[m]:bounds[m + 1]]
    bounds = np.searchsorted(cam[by_camera], np.arange(M + 1))
    rows = [by_camera[bounds[m] : bounds[m + 1]] for m in range(M)]
    rms = np.array([np.sqrt(np.mean(np.sum(residuals[mine] ** 2, axis=1))) if len(mine) else np.nan for mine in rows])
    # Outlier rejection clips a bad camera's residuals: what it rejected shows it as well.
    rejected = 1.0 - np.bincount(cam, minlength=M) / np.maximum(observed, 1)
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
        mine = rows[m]
        edge_px = radial_pattern_px(uv[mine], residuals[mine], intr[m, 2:4], intr[m, 0], sigma)
        if edge_px > RADIAL_MIN_PX:
            warnings.append(
                f"camera {cam_id}: its residuals grow with the distance from the image centre "
                f"({edge_px:.1f} px at the edge): lens distortion the solve held; give its dist or free k1, k2"
            )
    return warnings
