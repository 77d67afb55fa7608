"""A solved network (a frozen Calibration) and the typed report of its solve.

Pure values, no I/O: the JSON codec of these types is camnet.io.formats, and docs/calibration-keys.md
documents the report's keys. Conventions are those of camnet.model.camera: ``x_cam = R @ X_world + t``,
lengths in metres, pixels with the origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np

from camnet.model.camera import Camera, in_frame
from camnet.model.methods import Method


class StartKind(StrEnum):
    """How a solve started: the paper's solver, or a previous calibration (a warm start)."""

    COLD = "cold"
    WARM = "warm"  # every camera still fitted: only new tracks got the robust fit
    WARM_ROBUST = "warm, robust"  # some camera no longer fitted (it moved): the robust adjustment ran


@dataclass(frozen=True)
class Sigma:
    """A 1-sigma value that the data may not determine; then `value` is None and `reason` says why."""

    value: float | None
    reason: str = ""

    @staticmethod
    def unknown(reason: str) -> Sigma:
        return Sigma(None, reason)


@dataclass(frozen=True)
class CameraSigmas:
    """One camera's 1-sigma uncertainties (0 where a parameter is held).

    rotation_deg: 3 axes, left perturbation; centre_m: 3 axes of the camera centre.
    """

    f_px: float
    cx_px: float
    cy_px: float
    k1: float
    k2: float
    rotation_deg: tuple[float, float, float]
    centre_m: tuple[float, float, float]


@dataclass(frozen=True)
class Uncertainty:
    """The solution's uncertainty, from the Jacobian at the solution.

    scale_rel: relative 1 sigma of the network's scale (weighted by
    `point_weights`); scale_rel_if_pp_exact: the same were the guessed
    principal points exactly right; scale_rel_if_pair_exact: the same were
    the stereo pair's held rotation axes exactly as held (each is otherwise
    counted at the pair's tolerance); scale_rel_if_pp_and_pair_exact: were
    both exact, what the scene alone leaves (each of the three removes only
    the cause its name says); point_weights (N,): per reported point,
    its weight in the scale; point_sigma_m (N,): per reported point, its
    1-sigma position error in metres (RMS over the three axes); each None
    when not given.
    """

    sigma_px: float
    scale_rel: Sigma
    scale_rel_if_pp_exact: Sigma
    cameras: Mapping[str, CameraSigmas]
    point_weights: np.ndarray | None
    point_sigma_m: np.ndarray | None = None
    scale_rel_if_pair_exact: Sigma = Sigma(None, "no rotation axis of the stereo pair was held at a tolerance")
    scale_rel_if_pp_and_pair_exact: Sigma = Sigma(None, "not both a principal point guessed and a pair's axis held")


@dataclass(frozen=True)
class CameraStats:
    """One camera's inlier observations and their reprojection RMS (None without inliers)."""

    rms_px: float | None
    inliers: int


@dataclass(frozen=True)
class FreeSet:
    """Which parameters moved in a solve (reused by warm starts).

    intrinsics: per camera id, the names of camnet.model.projection.INTRINSIC_NAMES
    (FISHEYE_INTRINSIC_NAMES for a fisheye camera)
    that were free; stereo_rotation_axes: of "xyz", the right stereo camera's
    free rotation axes; stereo_direction: whether its baseline could turn.
    """

    intrinsics: Mapping[str, tuple[str, ...]]
    stereo_rotation_axes: tuple[str, ...]
    stereo_direction: bool


@dataclass(frozen=True)
class PointsLeftOut:
    """Tracks with a solution that a calibration does not report, by reason."""

    fewer_than_two_views: int = 0
    behind_a_camera: int = 0
    undetermined: int = 0


@dataclass(frozen=True)
class LensShift:
    """What one camera's solution does when its lens distortion, held at none because nobody gave it, is freed
    (camnet.solve.lens_check): f_rel, its focal length's relative move; in_sigmas, that move over its sigma with
    the lens free; k1, the k1 it then takes."""

    f_rel: float
    in_sigmas: float
    k1: float


@dataclass(frozen=True)
class PairPoseCheck:
    """The solved relative pose of cameras `first`, `second` against their own two-view geometry
    (camnet.model.pair_pose_check).

    rotation_deg: the angle between the solved relative rotation and the two-view one; direction_deg: the angle
    between the solved baseline direction and the two-view one; in_sigmas: the solved pose's excess cost over the
    two views' best fit (squared Sampson distances, over their inliers), its square root in units of the
    distances' own sigma (about sqrt(5) for a pose that agrees); shared: tracks both see; inliers: of the at most
    MAX_MATCHES checked, those within THRESHOLD_PX of the two views' best fit.
    """

    first: str
    second: str
    rotation_deg: float
    direction_deg: float
    in_sigmas: float
    shared: int
    inliers: int


@dataclass(frozen=True)
class HalvesCheck:
    """A second opinion: the scene split in two halves across its point cloud, each half solved alone, and the
    halves compared (camnet.solve.halves).

    splits: how many splits were solved and compared (0: none could be, `reason` says why); ruled_out: the splits
    not compared because a half's cold solve fell short of its own minimum (camnet.solve.halves);
    half_differences: per parameter, half the largest difference between two halves over the splits: "scale"
    (relative), "f CAM" (relative), "rotation CAM" (degrees), "centre CAM" (metres); in_sigmas: that difference
    over the sigma the two halves' own uncertainties give it; widened: the parameters the halves disagreed on
    beyond their sigmas, whose reported sigma was widened to the half-difference; sigma_factor: what every reported
    sigma was multiplied by, where the halves differ more than their sigmas allow over all parameters (1: not);
    from_whole: the halves compared at their solution from the whole's start, which fit them better than their cold
    one ("half 2 across the widest axis").
    """

    splits: int
    half_differences: Mapping[str, float] = field(default_factory=dict)
    in_sigmas: Mapping[str, float] = field(default_factory=dict)
    widened: tuple[str, ...] = ()
    sigma_factor: float = 1.0
    reason: str = ""
    ruled_out: tuple[str, ...] = ()  # by name ("across the widest axis")
    from_whole: tuple[str, ...] = ()


@dataclass(frozen=True)
class RivalDifference:
    """One parameter in which a rival solution differs from the kept one by more than RIVAL_SIGMAS (three) of the kept
    solution's 1 sigma (as solved, before it was widened to cover both).

    parameter: "scale" (the network's, relative: `kept` 1, `rival` the
    rival's scale over the kept one's), "f_px" (a camera's focal length,
    pixels) or "rotation_deg" (a camera's rotation: `kept` 0, `rival` the
    angle from the kept rotation to the rival's, degrees); camera: its id,
    None for the scale.
    """

    parameter: str
    camera: str | None
    kept: float
    rival: float
    kept_sigma: float


@dataclass(frozen=True)
class Rival:
    """A converged, sound solution from another start whose cost the noise could have made equal to the kept
    one's, yet which differs in `differences` (camnet.solve.report.rivals).

    start: how that solve started (camnet.solve.start.state.PairStart's
    value); cost_px2, kept_cost_px2: the truncated quadratic (MSAC) cost
    of every observation under it and under the kept solution, px^2;
    cost_noise_px2: the cost difference the noise can make.
    """

    start: str
    cost_px2: float
    kept_cost_px2: float
    cost_noise_px2: float
    differences: tuple[RivalDifference, ...]


@dataclass(frozen=True)
class SolveReport:
    """How a calibration was solved and how well it is determined (docs/calibration-keys.md).

    converged, reason, iterations: the final adjustment's; observations,
    inliers: used and kept after outlier rejection; free_rule: the automatic
    rule's decisions; warnings: near-degenerate geometry; notes: what the
    reader should know of a good solve (what a guessed principal point
    costs); timings_s: seconds per stage; cameras_left_out: camera id -> why
    the solve could not place it (the calibration holds the others). Fields
    a document may lack are None (`free`, `start`, `points_left_out`,
    `uncertainty`, `median_parallax_deg`).
    """

    method: Method
    converged: bool
    reason: str
    iterations: int
    observations: int
    inliers: int
    cameras: Mapping[str, CameraStats]
    median_parallax_deg: float | None
    free: FreeSet | None
    free_rule: tuple[str, ...]
    warnings: tuple[str, ...]
    points_left_out: PointsLeftOut | None
    start: StartKind | None
    timings_s: Mapping[str, float]
    uncertainty: Uncertainty | None = None
    cameras_left_out: Mapping[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    # Whether some rotation axis of the stereo pair was held, and at a pose given (a factory head's R, t, or that of
    # the calibration a warm start began from: camnet.solve.report.scale_cause.held_at_given_pose), not the
    # parallel pair.
    pair_pose_given: bool = False
    halves: HalvesCheck | None = None  # None: not checked (a solve asked not to, or a document from before)
    # Solutions from other starts that the data cannot tell from the kept one; the sigmas are widened to cover them.
    rivals: tuple[Rival, ...] = ()
    # Camera id -> how far its freed principal point moved from where it was given (the image centre where it was
    # not), as a share of the image's width or height, where that is farther than any lens's.
    far_principal_points: Mapping[str, float] = field(default_factory=dict)
    # Each camera against the two-view geometry with its neighbours (None: not checked).
    pair_checks: tuple[PairPoseCheck, ...] | None = None
    # Camera id -> what freeing its undescribed lens's k1 moves (None: not checked: distortion was free or given).
    lens_shifts: Mapping[str, LensShift] | None = None


@dataclass(frozen=True)
class FloorFrame:
    """The frame found from the scene that a calibration is written in (the calibration document's ``"floor"``
    world frame): ``X_world = R @ X_left + t`` (metres), Z up, origin on the floor, X toward the rig's front.

    normal_sigma_deg, height_sigma_m: 1 sigma of the floor's normal (degrees) and of its height (metres); both None
    where the scene showed no floor, `reason` then saying why and what the frame rests on instead. ambiguity:
    where another plane could be the floor, which, and that the lowest was taken ("": none).
    """

    R: np.ndarray
    t: np.ndarray
    normal_sigma_deg: float | None = None
    height_sigma_m: float | None = None
    reason: str = ""
    ambiguity: str = ""

    @property
    def found(self) -> bool:
        """Whether the scene showed a floor."""
        return self.normal_sigma_deg is not None


@dataclass(frozen=True)
class Calibration:
    """A solved network: cameras in the left stereo camera's frame, metric points.

    rms_reprojection_px is NaN when no observation went into it (a factory
    stereo head); report is None when no solve made it. floor_frame: the
    frame the calibration is written in where that is not the left
    camera's (its cameras and points here stay in the left camera's).
    """

    cameras: tuple[Camera, ...]
    point_ids: np.ndarray  # (N,) int, the track ids kept
    points: np.ndarray  # (N, 3) metres, world frame
    rms_reprojection_px: float
    world_frame: str
    report: SolveReport | None = None
    floor_frame: FloorFrame | None = None

    @property
    def uncertainty(self) -> Uncertainty | None:
        """The report's uncertainty; None without a report or without uncertainty in it."""
        return self.report.uncertainty if self.report is not None else None

    @property
    def warnings(self) -> tuple[str, ...]:
        """The report's warnings; none without a report."""
        return self.report.warnings if self.report is not None else ()

    def warned(self, *said: str) -> Calibration:
        """This calibration with `said` added to its report's warnings (itself where it has no report)."""
        if self.report is None or not said:
            return self
        return replace(self, report=replace(self.report, warnings=(*self.report.warnings, *said)))


FLOOR_FRAME = "floor"  # the name a calibration's floor frame (FloorFrame) is written under


@dataclass(frozen=True)
class WorldPosed:
    """A calibration's cameras and points in the frame it is written in (see `in_world_frame`)."""

    frame: str  # FLOOR_FRAME, or the left camera's (Calibration.world_frame)
    cameras: tuple[Camera, ...]  # x_cam = R @ X_world + t
    points: np.ndarray  # (N, 3) metres, in `frame`


def in_world_frame(cal: Calibration) -> WorldPosed:
    """The cameras and points of `cal` in the frame its document and exports are written in.

    With a floor frame, the floor's: ``X_world = R @ X_left + t`` (metres, Z up, origin on the floor); without
    one, the left camera's: the cameras and points as `cal` holds them.
    """
    frame = cal.floor_frame
    if frame is None:
        return WorldPosed(cal.world_frame, cal.cameras, cal.points)
    R, t = np.asarray(frame.R, dtype=float), np.asarray(frame.t, dtype=float)
    cameras = tuple(in_frame(cam, R, t) for cam in cal.cameras)
    return WorldPosed(FLOOR_FRAME, cameras, np.asarray(cal.points, dtype=float).reshape(-1, 3) @ R.T + t)
