"""A calibration against a data set's reference, judged by its own sigmas: right, wrong and saying so, or wrong
in silence.

A run of `camnet calibrate` (or `camnet up`) ends in one of five ways
(`Outcome`): it crashed (a traceback), it refused (exit 2 with a one-line
reason), or it wrote a calibration that is right (its scale, every focal
length and every rotation within `K_SIGMAS` of its reported 1 sigma of the
reference), or wrong and its verdict says poor (honest), or wrong while its
verdict says good or usable: wrong in silence.

The errors: the scale is the similarity that best maps the calibrated camera
centres onto the reference's (`camnet.model.accuracy.scale_error`, cameras in
both, at least three: with two, the known distance fixes it by
construction); focal lengths relative to the reference's ``K[0, 0]``;
rotations and centres in the known pair's left camera's frame, which is the
calibration's world frame (`camnet.datasets.published.compare_cameras`).
Sigmas are the calibration's own: a rotation's and a centre's the root of
their summed per-axis variances, 0 for what was held as given.

A calibration with a floor frame has its up direction checked too, against
the reference's: the normal of the plane its camera centres lie in (a
photographer walking a scene, a rig's cameras at one height), where they lie
in one (`reference_up`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from camnet.datasets.published import compare_cameras, in_frame_of
from camnet.model.accuracy import angle_between_deg, scale_error, scale_sigma_rel
from camnet.model.calibration import Calibration
from camnet.model.camera import Camera
from camnet.solve.report.verdict import Level, judge
from camnet.solve.world_frame import camera_down

K_SIGMAS = 3.0  # an error within this many of its reported sigmas is right
EXACT = 1e-9  # an error this small (relative, degrees, millimetres) is a value held as given: rounding
REFUSED_EXIT = 2  # the CLI's exit status for a one-line error (camnet.cli)
TRACEBACK = "Traceback (most recent call last)"


class Outcome(StrEnum):
    """How a run ended, against the reference."""

    RIGHT = "right"  # within K_SIGMAS everywhere, whatever its verdict
    REFUSED = "refused"  # exit 2 with a reason: nothing written
    POOR_AND_WRONG = "poor and wrong"  # beyond K_SIGMAS somewhere, and its verdict says poor: honest
    WRONG_IN_SILENCE = "WRONG IN SILENCE"  # beyond K_SIGMAS somewhere, and its verdict says good or usable
    CRASH = "CRASH"  # a traceback, or another exit status


@dataclass(frozen=True)
class Measure:
    """One error beside its reported 1 sigma (0: held as given; NaN: none reported)."""

    error: float
    sigma: float

    @property
    def in_sigmas(self) -> float:
        """|error| / sigma: 0 for an exact value held, inf for a wrong one held or an error with no sigma."""
        if abs(self.error) <= EXACT:
            return 0.0
        if not self.sigma > 0.0:  # 0 or NaN
            return float("inf")
        return abs(self.error) / self.sigma

    def within(self, k: float = K_SIGMAS) -> bool:
        return bool(self.in_sigmas <= k)


@dataclass(frozen=True)
class CameraCheck:
    """One calibrated camera against its reference (the left camera's frame)."""

    id: str
    level: str | None  # its verdict: good, usable, poor (None without a report)
    focal_rel: Measure  # f / f_reference - 1
    rotation_deg: Measure  # angle of R R_reference^T
    centre_mm: Measure  # |C - C_reference|
    distance_rel: float  # |C| / |C_reference| - 1: its distance from the left camera (NaN for the left one)


@dataclass(frozen=True)
class FloorCheck:
    """A calibration's up against the reference's: the angle between them (degrees) beside the floor's normal
    sigma; where the scene showed no floor (`found` false), up is the cameras' down and no sigma judges it."""

    tilt_deg: Measure
    found: bool


@dataclass(frozen=True)
class Check:
    """A calibration against its reference."""

    level: str | None  # the rig's verdict
    findings: tuple[str, ...]  # the rig's own findings short of good: "level: what"
    scale_rel: Measure | None  # None with fewer than three cameras calibrated
    cameras: tuple[CameraCheck, ...]
    left_out: dict[str, str]  # camera id -> why the calibration left it out
    rms_px: float
    floor: FloorCheck | None = None  # None: no floor frame, or a reference that gives no up

    def beyond(self, k: float = K_SIGMAS) -> list[tuple[str, float]]:
        """(what, error in sigmas) of the scale, focal lengths and rotations beyond `k` sigmas, worst first."""
        found = [("scale", self.scale_rel.in_sigmas)] if self.scale_rel and not self.scale_rel.within(k) else []
        for c in self.cameras:
            found += [(f"f {c.id}", c.focal_rel.in_sigmas)] if not c.focal_rel.within(k) else []
            found += [(f"rotation {c.id}", c.rotation_deg.in_sigmas)] if not c.rotation_deg.within(k) else []
        if self.floor is not None and self.floor.found and not self.floor.tilt_deg.within(k):
            found.append(("floor", self.floor.tilt_deg.in_sigmas))
        return sorted(found, key=lambda item: -item[1])

    def silent(self, k: float = K_SIGMAS) -> list[str]:
        """Cameras whose own verdict is good or usable, yet whose focal length or rotation lies beyond `k` sigmas
        (whatever the rig's verdict)."""
        quiet = (Level.GOOD.value, Level.USABLE.value)
        return [c.id for c in self.cameras
                if c.level in quiet and not (c.focal_rel.within(k) and c.rotation_deg.within(k))]


def check_calibration(cal: Calibration, reference: dict[str, Camera], left: str) -> Check:
    """`cal` against `reference` (in any world frame; every calibrated camera in it); `left`: the known pair's
    left camera, whose frame is the calibration's world frame (ValueError if not)."""
    missing = sorted(c.id for c in cal.cameras if c.id not in reference)
    if missing:
        raise ValueError(f"cameras {', '.join(missing)} have no reference")
    if cal.world_frame != left:
        raise ValueError(f"the calibration's world frame is {cal.world_frame!r}, not camera {left!r}'s")
    verdict = judge(cal)
    levels = {c.camera: c.level.value for c in verdict.cameras} if verdict is not None else {}
    cameras = []
    for c in compare_cameras(cal, in_frame_of(reference, left)):
        # The left camera is the frame: its pose is no result (0 by construction, to rounding).
        rotation, centre = (Measure(0.0, 0.0),) * 2 if c.id == left else (
            Measure(c.rotation_deg, c.rotation_sigma_deg), Measure(c.centre_mm, c.centre_sigma_mm))
        cameras.append(CameraCheck(c.id, levels.get(c.id), Measure(c.focal_rel, c.focal_sigma_rel), rotation,
                                   centre, c.distance_rel))
    scale = None
    if len(cal.cameras) >= 3:
        centres = np.array([c.centre for c in cal.cameras])
        truth = np.array([reference[c.id].centre for c in cal.cameras])
        scale = Measure(scale_error(centres, truth), scale_sigma_rel(cal))
    left_out = dict(cal.report.cameras_left_out) if cal.report is not None else {}
    findings = tuple(f"{f.level.value}: {f.what}" for f in verdict.findings) if verdict is not None else ()
    return Check(verdict.level.value if verdict is not None else None, findings, scale, tuple(cameras), left_out,
                 cal.rms_reprojection_px, _floor_check(cal, in_frame_of(reference, left)))


MIN_FLATNESS = 10.0  # camera centres lie in a plane where it is this many times wider, both ways, than thick


def reference_up(cameras: Sequence[Camera]) -> np.ndarray | None:
    """The up direction (3,) the cameras' centres give: the normal of the plane they lie in, on the side their
    image y axes point away from (down); None where they lie along a line, spread in height as much as across, or
    look sideways to the plane."""
    if len(cameras) < 3:
        return None
    centres = np.array([c.centre for c in cameras])
    _, spread, axes = np.linalg.svd(centres - centres.mean(axis=0), full_matrices=False)
    if not spread[1] >= MIN_FLATNESS * spread[2]:
        return None
    try:
        up = -camera_down(np.array([c.R for c in cameras]))
    except ValueError:  # their image y axes cancel out: no up from them
        return None
    normal = axes[2] if axes[2] @ up >= 0 else -axes[2]
    return normal if normal @ up >= np.cos(np.radians(45.0)) else None


def _floor_check(cal: Calibration, reference: dict[str, Camera]) -> FloorCheck | None:
    """`cal`'s up (its floor frame's Z in its left camera's frame) against `reference` in that frame."""
    frame = cal.floor_frame
    up = reference_up(list(reference.values())) if frame is not None else None
    if up is None:
        return None
    tilt = angle_between_deg(up, frame.R[2])
    sigma = frame.normal_sigma_deg if frame.found else float("nan")
    return FloorCheck(Measure(tilt, sigma), frame.found)


def error_line(stderr: str) -> str:
    """The line a failed command ends on: its one-line error, or a traceback's exception."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    errors = [line for line in lines if ": error: " in line and line.startswith("camnet ")]
    if TRACEBACK in stderr or not errors:
        return lines[-1] if lines else ""
    return errors[-1].split(": error: ", 1)[1]


def classify(returncode: int, stderr: str, check: Check | None, k: float = K_SIGMAS) -> Outcome:
    """The outcome of a command that exited with `returncode` and wrote `stderr`; `check`: what it wrote
    against the reference (None when it wrote nothing)."""
    if returncode not in (0, REFUSED_EXIT) or (returncode != 0 and TRACEBACK in stderr):
        return Outcome.CRASH
    if returncode == REFUSED_EXIT:
        return Outcome.REFUSED
    if check is None:
        raise ValueError("a run that exited 0 wrote a calibration: check it")
    if not check.beyond(k):
        return Outcome.RIGHT
    return Outcome.POOR_AND_WRONG if check.level == Level.POOR.value else Outcome.WRONG_IN_SILENCE
