"""Two solutions of one rig compared parameter by parameter, and a calibration's sigmas widened to cover what
they disagree on beyond their own sigmas.

The two are the halves of camnet.solve.halves: each solved alone, in the
same world frame (the left stereo camera's) and at the same scale (the
known distance). Where the model fits the scene, they differ by what their
noise allows; where it does not (a lens the model lacks, false matches in
one part, a second minimum the curvature cannot see), they differ by more,
and that difference, not the curvature, is what the calibration knows.

Scale and focal lengths relative; rotations in degrees (``x_cam = R X + t``);
centres in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from camnet.model.accuracy import rotation_angle_deg, scale_error
from camnet.model.calibration import Calibration, CameraSigmas, Sigma, Uncertainty

DISAGREE_SIGMAS = 3.0  # halves further apart than this many sigmas of their difference disagree
MIN_SCALE_CAMERAS = 3  # a scale between two sets of centres needs a triangle
EXACT = 1e-9  # a half-difference below this (relative, degrees or metres) is rounding: a parameter held in both
# Where the half-differences' RMS in their sigmas passes this, every sigma is multiplied by it: where the model fits
# it lies within a few tenths of 1, and the parameters' correlations make it vary more than independent ones would.
INFLATE_FROM = 1.5
MIN_FACTOR_PARAMETERS = 6  # fewer parameters say too little of the sigmas as a whole


@dataclass(frozen=True)
class HalfDifference:
    """Half the difference of one parameter between two solutions, and the sigma of that half-difference from
    their own sigmas (NaN where either has none)."""

    half: float
    sigma: float

    @property
    def in_sigmas(self) -> float:
        """half / sigma; 0 where the two agree to rounding, infinite where they differ and neither has a sigma."""
        if self.half <= EXACT:
            return 0.0
        return self.half / self.sigma if self.sigma > 0.0 else float("inf")

    @property
    def disagrees(self) -> bool:
        return self.in_sigmas > DISAGREE_SIGMAS


def differences(a: Calibration, b: Calibration) -> dict[str, HalfDifference]:
    """Per parameter ("scale", "f CAM", "rotation CAM", "centre CAM"), how `a` and `b` differ: over the cameras
    both hold, the left camera's pose (the frame) aside."""
    ua, ub = a.report.uncertainty if a.report else None, b.report.uncertainty if b.report else None
    cams_b = {c.id: c for c in b.cameras}
    common = [(ca, cams_b[ca.id]) for ca in a.cameras if ca.id in cams_b]
    out: dict[str, HalfDifference] = {}
    if len(common) >= MIN_SCALE_CAMERAS:
        d = scale_error(np.array([ca.centre for ca, _ in common]), np.array([cb.centre for _, cb in common]))
        out["scale"] = HalfDifference(abs(d) / 2, _half_sigma(_scale(ua), _scale(ub)))
    for ca, cb in common:
        sa, sb = _camera(ua, ca.id), _camera(ub, cb.id)
        fa, fb = float(ca.K[0, 0]), float(cb.K[0, 0])
        out[f"f {ca.id}"] = HalfDifference(abs(fa - fb) / (fa + fb),
                                       _half_sigma(sa.f_px / fa if sa else np.nan, sb.f_px / fb if sb else np.nan))
        if ca.id == a.world_frame:
            continue
        out[f"rotation {ca.id}"] = HalfDifference(
            rotation_angle_deg(ca.R @ cb.R.T) / 2,
            _half_sigma(np.linalg.norm(sa.rotation_deg) if sa else np.nan,
                        np.linalg.norm(sb.rotation_deg) if sb else np.nan))
        out[f"centre {ca.id}"] = HalfDifference(
            float(np.linalg.norm(ca.centre - cb.centre)) / 2,
            _half_sigma(np.linalg.norm(sa.centre_m) if sa else np.nan, np.linalg.norm(sb.centre_m) if sb else np.nan))
    return out


def _half_sigma(sigma_a: float, sigma_b: float) -> float:
    """The sigma of half the difference of two independent estimates."""
    return float(np.hypot(sigma_a, sigma_b)) / 2


def _scale(u: Uncertainty | None) -> float:
    return u.scale_rel.value if u is not None and u.scale_rel.value is not None else np.nan


def _camera(u: Uncertainty | None, cam_id: str) -> CameraSigmas | None:
    return u.cameras.get(cam_id) if u is not None else None


def widest(per_split: list[dict[str, HalfDifference]]) -> dict[str, HalfDifference]:
    """Per parameter, the split whose halves differ most in their sigmas (then most)."""
    out: dict[str, HalfDifference] = {}
    for diffs in per_split:
        for name, d in diffs.items():
            if name not in out or (d.in_sigmas, d.half) > (out[name].in_sigmas, out[name].half):
                out[name] = d
    return out


def sigma_factor(diffs: dict[str, HalfDifference]) -> float:
    """The root mean square of the half-differences in their sigmas, over the parameters the halves estimate;
    1 where it is below INFLATE_FROM or too few parameters give it.

    Where the model fits it is about 1. Above, the curvature's sigmas are
    too small all over (errors that correlate across the scene, which no
    one parameter's disagreement shows): each is multiplied by it.
    """
    z = [d.in_sigmas for d in diffs.values() if d.half > EXACT and np.isfinite(d.sigma) and d.sigma > 0.0]
    if len(z) < MIN_FACTOR_PARAMETERS:
        return 1.0
    k = float(np.sqrt(np.mean(np.square(z))))
    return k if k > INFLATE_FROM else 1.0


def widened(u: Uncertainty, cal: Calibration, diffs: dict[str, HalfDifference]
            ) -> tuple[Uncertainty, tuple[str, ...], float]:
    """(`u` widened, the parameters the halves disagree on beyond their sigmas, the factor every sigma took).

    Every sigma is multiplied by `sigma_factor`; then the sigma of each
    parameter the halves disagree on beyond DISAGREE_SIGMAS is raised to
    their half-difference where that is larger. Where the model fits, half
    the difference of two halves is about one sigma of the whole, and
    raising every sigma to it would only add its noise. The scale's
    conditional sigmas (if the principal points or the pair's pose were
    exact) are raised alike, for the halves differ whatever is exact.
    """
    k = sigma_factor(diffs)
    raised: list[str] = []

    def at_least(sigma: float, name: str, value: float) -> float:
        sigma = k * sigma
        d = diffs.get(name)
        if d is None or not d.disagrees or not np.isfinite(sigma) or sigma >= value:
            return sigma
        raised.append(name)
        return value

    conditional = ("scale_rel_if_pp_exact", "scale_rel_if_pair_exact", "scale_rel_if_pp_and_pair_exact")
    if u.scale_rel.value is not None:
        half = diffs["scale"].half if "scale" in diffs else 0.0
        new = at_least(u.scale_rel.value, "scale", half)
        floor = half if new > k * u.scale_rel.value else 0.0  # raised: what is exact changes nothing of it
        u = replace(u, scale_rel=Sigma(new), **{key: Sigma(max(k * getattr(u, key).value, floor))
                                                 for key in conditional if getattr(u, key).value is not None})
    cameras = dict(u.cameras)
    for cam in cal.cameras:
        s = cameras.get(cam.id)
        if s is None:
            continue

        def half(name: str, unit: float = 1.0) -> float:
            return diffs[name].half * unit if name in diffs else 0.0

        cameras[cam.id] = replace(
            s, f_px=at_least(s.f_px, f"f {cam.id}", half(f"f {cam.id}", float(cam.K[0, 0]))),
            cx_px=k * s.cx_px, cy_px=k * s.cy_px, k1=k * s.k1, k2=k * s.k2,
            rotation_deg=_axes_at_least(_times(s.rotation_deg, k), at_least(
                float(np.linalg.norm(s.rotation_deg)), f"rotation {cam.id}", half(f"rotation {cam.id}"))),
            centre_m=_axes_at_least(_times(s.centre_m, k), at_least(
                float(np.linalg.norm(s.centre_m)), f"centre {cam.id}", half(f"centre {cam.id}"))))
    return replace(u, cameras=cameras), tuple(raised), k


def _times(axes: tuple[float, float, float], k: float) -> tuple[float, float, float]:
    return tuple(float(x) * k for x in axes)


def _axes_at_least(axes: tuple[float, float, float], norm: float) -> tuple[float, float, float]:
    """Per-axis sigmas scaled so that their root sum of squares is `norm` (equal axes where all were 0)."""
    now = float(np.linalg.norm(axes))
    if norm <= now:
        return axes
    if now == 0.0:
        return (norm / np.sqrt(3.0),) * 3
    return tuple(float(x) * norm / now for x in axes)


def disagreement_warning(diffs: dict[str, HalfDifference], names: tuple[str, ...], factor: float) -> str:
    """The warning of sigmas widened: by what factor, which parameters beyond it and by how much, what would
    decide."""
    shown = []
    for name in sorted(names, key=lambda n: -diffs[n].in_sigmas)[:4]:
        d = diffs[name]
        value = (f"{100 * d.half:.2g}%" if name == "scale" or name.startswith("f ")
                 else f"{d.half:.2g} deg" if name.startswith("rotation") else f"{1e3 * d.half:.0f} mm")
        shown.append(f"{name} by {value} ({d.in_sigmas:.0f} sigma)")
    more = f" and {len(names) - len(shown)} more" if len(names) > len(shown) else ""
    said = []
    if factor > 1.0:
        said.append(f"differ by {factor:.1f} times what their sigmas allow, over every parameter, so every sigma is "
                    f"multiplied by {factor:.1f}")
    if shown:
        said.append(f"disagree beyond their sigmas on {', '.join(shown)}{more}, whose sigmas are widened to cover "
                    "both halves")
    return (f"the two halves of the scene, solved apart, {'; and '.join(said)}. The model does not fit the whole "
            "scene alike (a lens the model lacks, false matches in one part, or a second solution as good as this "
            "one); another frame set, the cameras' K and dist, or a second known distance would decide")
