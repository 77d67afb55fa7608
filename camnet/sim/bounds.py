"""Cramér-Rao bounds of a solve on a simulated rig: its scale, shape and focal lengths at the ground truth.

The bound of a solve is the covariance of `camnet.solve.uncertainty` taken
at the true parameters, with the true pixel noise, for the problem the solve
ended with: the same inlier observations, the same free parameters (what the
free rule freed, what the observations held as given), the same known
distances weighted by the true pixel noise over their sigma, and each
camera's own lens model. Lengths in metres; the scale relative (0.001 =
0.1%). Simulated track ids are track rows (`camnet.sim.simulate.observe`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from camnet.model.accuracy import point_weights
from camnet.model.projection import N_INTRINSICS, intrinsics_from_K
from camnet.sim.simulate import SimRig
from camnet.solve import Result
from camnet.solve.bundle import State
from camnet.solve.report.camera_sigmas import camera_sigmas_by_id
from camnet.solve.uncertainty import Covariance, covariance, scale_sigma, scale_weights, shape_rms_bound_m


@dataclass(frozen=True)
class Bounds:
    scale_rel: float  # 1 sigma of the similarity scale, relative
    shape_m: float  # expected RMS point error after similarity alignment, metres
    focal_rel: Mapping[str, float] = field(default_factory=dict)  # camera id -> 1 sigma of f, relative (0 held)


def truth_state(rig: SimRig, result: Result) -> State:
    """The true parameters in the solve's problem order (cameras `result.order`, points `result.track_rows`).

    A fisheye's four coefficients leave the last intrinsic slot at zero.
    """
    cams = [rig.cameras[i] for i in result.order]
    intr = np.zeros((len(cams), N_INTRINSICS))
    for m, c in enumerate(cams):
        values = intrinsics_from_K(c.K, c.dist)
        intr[m, : len(values)] = values
    return State(intr, np.array([c.R for c in cams]), np.array([c.centre for c in cams]),
                 rig.points[np.asarray(result.track_rows)])


def truth_covariance(rig: SimRig, result: Result, noise_px: float) -> Covariance:
    """The covariance of the solve's problem at the truth with pixel noise `noise_px` (its Cramér-Rao bound)."""
    # The known distances' rows are weighted by the pixel sigma over their own sigma: here the true one.
    problem = replace(result.problem, distance_sigma_px=noise_px)
    return covariance(problem, truth_state(rig, result), sigma_px=noise_px)


def _points_only(cov: Covariance, kept: np.ndarray) -> Covariance:
    """`cov` restricted to the points `kept` (N,) bool: their marginal covariance, the cameras as they are."""
    columns = np.repeat(kept, 3)
    return replace(cov, W=cov.W[:, columns], V_inv=cov.V_inv[kept], V=cov.V[kept])


def cramer_rao(rig: SimRig, result: Result, noise_px: float) -> Bounds:
    """The bounds of `result`'s scale and shape, over the points its calibration reports.

    Focal lengths per camera, relative. The scale is weighted as the calibration weighs its points (its reported
    point weights; the truth's `scale_weights` where it has none), so the
    bound is that of the scale `camnet.model.accuracy.compare` measures.
    """
    cov = truth_covariance(rig, result, noise_px)
    cal = result.calibration
    kept = np.isin(np.asarray(result.track_rows), cal.point_ids)
    X = truth_state(rig, result).X
    reported = point_weights(cal)
    if reported is None:
        weights = scale_weights(cov, X, kept)
    else:
        weights = np.zeros(len(X))
        weights[kept] = reported
    scale = scale_sigma(cov, X, weights)
    truth = truth_state(rig, result)
    ids = [rig.cameras[i].id for i in result.order]
    focal = {cam_id: s.f_px / truth.intr[m, 0]
             for m, (cam_id, s) in enumerate(camera_sigmas_by_id(ids, result.problem, truth, cov).items())}
    return Bounds(scale, shape_rms_bound_m(_points_only(cov, kept), X[kept]), focal)
