"""The standard deviations of each camera's parameters in a solve's report, from the cameras' covariance.

Units: pixels for the intrinsics, degrees for the rotation axes, metres for
the centre; infinite where a direction no observation fixes touches a block.
"""

from __future__ import annotations

import numpy as np

from camnet.model.calibration import CameraSigmas
from camnet.model.projection import INTRINSIC_NAMES
from camnet.solve.bundle import CEN, ROT, CentreMode, _tangent_basis
from camnet.solve.uncertainty import Covariance


def camera_sigmas_by_id(ids: list[str], problem, state, cov: Covariance) -> dict[str, CameraSigmas]:
    """Each camera's sigmas (`camera_sigmas`), by id; problem camera m is camera ids[m]."""
    camera_cov, undetermined = cov.cameras, cov.undetermined
    variances = np.diag(camera_cov)
    return {cam_id: camera_sigmas(m, problem, state, cov.columns[m], camera_cov, undetermined, variances)
            for m, cam_id in enumerate(ids)}


def camera_sigmas(m: int, problem, state, cols: np.ndarray, camera_cov: np.ndarray, undetermined: np.ndarray,
                  variances: np.ndarray) -> CameraSigmas:
    """Camera m's sigmas from its columns `cols` (15,) of the covariance `camera_cov` (Pc, Pc), its diagonal
    `variances` (Pc,) and its `undetermined` columns (Pc,) (`Covariance.cameras`, `.undetermined`, formed once
    for every camera)."""

    def deviations(slots: slice) -> np.ndarray:
        """The standard deviations of a block of slots (0 where held; infinite where a direction nothing
        fixes touches the block)."""
        c = cols[slots]
        ok = c >= 0
        if undetermined[c[ok]].any():
            return np.full(len(c), np.inf)
        out = np.zeros(len(c))
        out[ok] = variances[c[ok]]
        return np.sqrt(np.maximum(out, 0.0))

    sd = {}
    for slot, name in enumerate(INTRINSIC_NAMES):
        if cols[slot] >= 0:
            variance = variances[cols[slot]]
            sd[name] = np.inf if undetermined[cols[slot]] else float(np.sqrt(max(variance, 0.0)))
    mode = problem.centre_mode[m]
    if mode == CentreMode.FREE:
        centre = deviations(CEN)
    elif mode == CentreMode.ON_BASELINE:
        centre = _tangent_deviations(problem, state, m, cols[CEN.start : CEN.start + 2], camera_cov, undetermined)
    else:
        centre = np.zeros(3)
    return CameraSigmas(
        f_px=sd.get("f", 0.0),
        cx_px=sd.get("cx", 0.0),
        cy_px=sd.get("cy", 0.0),
        k1=sd.get("k1", 0.0),
        k2=sd.get("k2", 0.0),
        rotation_deg=tuple(np.degrees(deviations(ROT)).tolist()),
        centre_m=tuple(centre.tolist()),
    )


def _tangent_deviations(problem, state, m: int, c: np.ndarray, camera_cov: np.ndarray, undetermined: np.ndarray
                        ) -> np.ndarray:
    """(3,) standard deviations of camera m's centre, metres, from the covariance of its two tangent slots (columns
    `c`, -1 where held) on the sphere about the left camera; infinite where a direction nothing fixes touches them."""
    ok = c >= 0
    tangent = np.zeros((2, 2))
    tangent[np.ix_(ok, ok)] = camera_cov[np.ix_(c[ok], c[ok])]
    if undetermined[c[ok]].any() or np.isinf(tangent).any():
        return np.full(3, np.inf)
    B = problem.baseline_m * _tangent_basis(state.C[m] / np.linalg.norm(state.C[m]))
    return np.sqrt(np.maximum(np.diag(B @ tangent @ B.T), 0.0))


def undetermined_names(s: CameraSigmas) -> list[str]:
    """The names of a camera's parameters whose sigma is infinite (nothing fixes them)."""
    names = [n for n in ("f_px", "cx_px", "cy_px", "k1", "k2") if not np.isfinite(getattr(s, n))]
    names += [n for n in ("rotation_deg", "centre_m") if not np.all(np.isfinite(getattr(s, n)))]
    return names
