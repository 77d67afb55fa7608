"""Solutions from other starts that the data cannot tell from the kept one, named, and the sigmas widened to
cover them.

A cold solve runs from several starts and keeps the one of least truncated
quadratic (MSAC) cost. Another converged, sound solution is its rival where
(1) its cost is nearly equal: the two costs differ by no more than
NEAR_COST_SIGMAS times the spread the noise gives a cost (`cost_noise_px2`:
under Gaussian noise of sigma_px per axis, each inlier observation's squared
error over sigma_px^2 is chi-square with 2 degrees of freedom, variance 4,
so n inliers sum to a cost of standard deviation 2 sqrt(n) sigma_px^2),
and (2) it differs from the kept solution in the scale, a focal length or a
rotation by more than RIVAL_SIGMAS of the kept solution's own 1 sigma. Its
curvature then says nothing of which minimum is the right one: every sigma
in which they differ is widened to cover both (the half difference added in
quadrature, so that the rival lies within two reported sigmas), and a
warning names what differs and what evidence would decide.

Scale: relative, the rival's points over the kept ones' (the similarity of
the tracks both keep, weighted as the reported scale is); focal lengths in
pixels; rotations in degrees, the angle from the kept rotation to the rival's
in the world frame (the left stereo camera's).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from camnet.model.accuracy import scale_error
from camnet.model.calibration import Calibration, Rival, RivalDifference, Sigma, Uncertainty

NEAR_COST_SIGMAS = 3.0  # a cost difference within this many of the noise's standard deviations is nearly equal
RIVAL_SIGMAS = 3.0  # a parameter differing by more than this many of the kept solution's sigmas differs
MIN_SHARED_POINTS = 3  # a similarity between the two point clouds needs three points
SCALE_KEYS = ("scale_rel", "scale_rel_if_pp_exact", "scale_rel_if_pair_exact", "scale_rel_if_pp_and_pair_exact")
TO_DECIDE = "add a frame set, give the stereo pair's K, or give a second known distance"


def cost_noise_px2(sigma_px: float, inliers: int) -> float:
    """The standard deviation (px^2) that Gaussian noise of sigma_px per axis gives the cost of `inliers`
    observations (the module docstring)."""
    return 2.0 * float(np.sqrt(inliers)) * sigma_px**2


def rival(kept: Calibration, kept_cost_px2: float, other: Calibration, other_cost_px2: float,
          start: str) -> Rival | None:
    """`other` as a rival of `kept` (the module docstring's rule), or None where it is none: its cost is not
    nearly equal, it differs in nothing beyond RIVAL_SIGMAS, or `kept` has no uncertainty to judge by."""
    u = kept.uncertainty
    if u is None or kept.report is None:
        return None
    noise = cost_noise_px2(u.sigma_px, kept.report.inliers)
    if not abs(other_cost_px2 - kept_cost_px2) <= NEAR_COST_SIGMAS * noise:
        return None
    found = differences(kept, other)
    return Rival(start, other_cost_px2, kept_cost_px2, noise, found) if found else None


def differences(kept: Calibration, other: Calibration) -> tuple[RivalDifference, ...]:
    """The scale, focal lengths and rotations in which `other` differs from `kept` by more than RIVAL_SIGMAS of
    kept's sigmas (a parameter held, or not determined, is not judged)."""
    u = kept.uncertainty
    if u is None:
        return ()
    out = []
    scale = _relative_scale(kept, other)
    sigma = u.scale_rel.value
    if scale is not None and _beyond(scale, sigma):
        out.append(RivalDifference("scale", None, 1.0, 1.0 + scale, sigma))
    theirs = {c.id: c for c in other.cameras}
    for cam in kept.cameras:
        s, o = u.cameras.get(cam.id), theirs.get(cam.id)
        if s is None or o is None:
            continue
        f_kept, f_other = float(cam.K[0, 0]), float(o.K[0, 0])
        if _beyond(f_other - f_kept, s.f_px):
            out.append(RivalDifference("f_px", cam.id, f_kept, f_other, s.f_px))
        angle = float(np.linalg.norm(_turn_deg(cam.R, o.R)))
        rotation_sigma = float(np.linalg.norm(s.rotation_deg))
        if _beyond(angle, rotation_sigma):
            out.append(RivalDifference("rotation_deg", cam.id, 0.0, angle, rotation_sigma))
    return tuple(out)


def _beyond(difference: float, sigma: float | None) -> bool:
    return sigma is not None and 0.0 < sigma < np.inf and abs(difference) > RIVAL_SIGMAS * sigma


def _turn_deg(R_kept: np.ndarray, R_other: np.ndarray) -> np.ndarray:
    """The rotation vector (deg, world frame) that turns R_kept into R_other: R_other = exp(w) R_kept."""
    return np.degrees(Rotation.from_matrix(R_other @ R_kept.T).as_rotvec())


def _relative_scale(kept: Calibration, other: Calibration) -> float | None:
    """other's scale over kept's, minus 1, from the tracks both keep (kept's point weights); None with too few."""
    common, at_kept, at_other = np.intersect1d(kept.point_ids, other.point_ids, return_indices=True)
    if len(common) < MIN_SHARED_POINTS:
        return None
    w = kept.uncertainty.point_weights if kept.uncertainty is not None else None
    weights = np.asarray(w, dtype=float)[at_kept] if w is not None and len(w) == len(kept.points) else None
    return scale_error(other.points[at_other], kept.points[at_kept], weights)


def with_rivals(kept: Calibration, found: list[tuple[Rival, Calibration]]) -> Calibration:
    """`kept` with the rivals found (each beside its solution) in its report, each differing sigma widened to
    cover them, and a warning naming what differs and what would decide."""
    if not found or kept.report is None or kept.uncertainty is None:
        return kept
    rivals = tuple(r for r, _ in found)
    report = replace(kept.report, rivals=rivals, uncertainty=_widened(kept, kept.uncertainty, found),
                     warnings=(*kept.report.warnings, *(_warning(r) for r in rivals)))
    return replace(kept, report=report)


def _widened(kept: Calibration, u: Uncertainty, found: list[tuple[Rival, Calibration]]) -> Uncertainty:
    """u with each sigma a rival differs in grown by half the difference, in quadrature."""
    half_scale = max((abs(d.rival - d.kept) / 2 for r, _ in found for d in r.differences if d.parameter == "scale"),
                     default=0.0)
    scales = {key: Sigma(float(np.hypot(s.value, half_scale)), s.reason)
              for key in SCALE_KEYS if (s := getattr(u, key)).value is not None}
    cameras = dict(u.cameras)
    mine = {c.id: c for c in kept.cameras}
    for r, other in found:
        theirs = {c.id: c for c in other.cameras}
        for d in r.differences:
            if d.camera is None:
                continue
            s = cameras[d.camera]
            if d.parameter == "f_px":
                cameras[d.camera] = replace(s, f_px=float(np.hypot(s.f_px, (d.rival - d.kept) / 2)))
            else:  # each axis by half its share of the turn
                half = np.abs(_turn_deg(mine[d.camera].R, theirs[d.camera].R)) / 2
                axes = np.hypot(np.asarray(s.rotation_deg, dtype=float), half)
                cameras[d.camera] = replace(s, rotation_deg=tuple(float(x) for x in axes))
    return replace(u, cameras=cameras, **scales)


def named(d: RivalDifference) -> str:
    """One difference in words, with how many of the kept solution's sigmas it is."""
    times = abs(d.rival - d.kept) / d.kept_sigma
    if d.parameter == "scale":
        return f"the scale by {100 * (d.rival - d.kept):+.2f}% ({times:.0f} sigma)"
    if d.parameter == "f_px":
        return f"camera {d.camera}'s focal length, {d.rival:.0f} against {d.kept:.0f} px ({times:.0f} sigma)"
    return f"camera {d.camera}'s rotation, by {d.rival:.2f} deg ({times:.0f} sigma)"


def named_parameter(d: RivalDifference) -> str:
    """The parameter a difference is in, in words: "the scale", "camera c2's focal length"."""
    what = {"scale": "the scale", "f_px": "focal length", "rotation_deg": "rotation"}[d.parameter]
    return what if d.camera is None else f"camera {d.camera}'s {what}"


def _warning(r: Rival) -> str:
    shown = [named(d) for d in r.differences[:4]]
    more = len(r.differences) - len(shown)
    listed = "; ".join(shown) + (f"; and {more} more" if more > 0 else "")
    return (f"competing solution: the solve from the {r.start} start fits nearly as well (MSAC cost "
            f"{r.cost_px2:.0f} against {r.kept_cost_px2:.0f} px^2, within {NEAR_COST_SIGMAS:g} times the "
            f"{r.cost_noise_px2:.0f} px^2 the noise can make) yet differs in {listed}; the data do not decide "
            f"between them, and the sigmas are widened to cover both: to decide, {TO_DECIDE}")
