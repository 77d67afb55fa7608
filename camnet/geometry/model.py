"""The domain model: cameras, what observations say of them, the stereo pair, and a
solved network with the typed report of its solve.

Pure values, no I/O: the JSON codec of these types is camnet.io.formats, and
docs/calibration-keys.md documents the report's keys. Conventions are those of
camnet.geometry.projection: ``x_cam = R @ X_world + t``, lengths in metres, pixels
with ``u`` right, ``v`` down, origin at the centre of the top-left pixel, ``K``
in pixels and ``dist`` in OpenCV's order: ``[k1, k2, p1, p2, k3]`` for the pinhole
lens model, ``[k1, k2, k3, k4]`` for the fisheye.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from camnet.geometry.choices import Loss as Loss  # the domain's names, defined apart (see choices)
from camnet.geometry.choices import Method
from camnet.geometry.projection import DIST_SIZE, FISHEYE_DIST_SIZE, normalised, project


class LensModel(StrEnum):
    """A camera's lens model (camnet.geometry.projection): its `dist` is in that model's order."""

    PINHOLE = "pinhole"  # OpenCV's radial-tangential distortion, dist [k1, k2, p1, p2, k3]
    FISHEYE = "fisheye"  # OpenCV's fisheye (Kannala-Brandt), dist [k1, k2, k3, k4]

    @property
    def dist_size(self) -> int:
        """How many coefficients the model's `dist` has."""
        return FISHEYE_DIST_SIZE if self == LensModel.FISHEYE else DIST_SIZE


class StartKind(StrEnum):
    """How a solve started: the paper's solver, or a previous calibration (a warm start)."""

    COLD = "cold"
    WARM = "warm"  # every camera still fitted: only new tracks got the robust fit
    WARM_ROBUST = "warm, robust"  # some camera no longer fitted (it moved): the robust adjustment ran


@dataclass(frozen=True)
class Camera:
    """One calibrated camera: intrinsics, distortion (in `model`'s order) and pose in the world frame."""

    id: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(DIST_SIZE))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    model: LensModel = LensModel.PINHOLE

    def __post_init__(self) -> None:
        if self.model == LensModel.FISHEYE and len(self.dist) != FISHEYE_DIST_SIZE:
            if np.any(self.dist):
                raise ValueError(f"camera {self.id!r}: a fisheye's dist is [k1, k2, k3, k4], got {list(self.dist)}")
            object.__setattr__(self, "dist", np.zeros(FISHEYE_DIST_SIZE))  # the default: no distortion

    @property
    def centre(self) -> np.ndarray:
        """Camera centre in world coordinates (m)."""
        return -self.R.T @ self.t

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) of world points (n, 3); see camnet.geometry.projection.project."""
        return project(
            points_world, K=self.K, dist=self.dist, R=self.R, t=self.t, fisheye=self.model == LensModel.FISHEYE
        )

    def normalised(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (n, 2) of pixels (n, 2); see camnet.geometry.projection.normalised."""
        return normalised(uv, K=self.K, dist=self.dist, fisheye=self.model == LensModel.FISHEYE)


FIXABLE = ("K", "dist")  # what observations may hold as given (CameraInfo.fixed)


@dataclass(frozen=True)
class CameraInfo:
    """What observations say of one camera."""

    id: str
    width: int
    height: int
    K: np.ndarray | None = None  # 3x3, pixels, if known
    dist: np.ndarray | None = None  # in `model`'s order (pinhole [k1, k2, p1, p2, k3]), if known
    fixed: frozenset[str] = frozenset()  # subset of {"K", "dist"} to hold as given
    model: LensModel = LensModel.PINHOLE


@dataclass(frozen=True)
class Stereo:
    """The pair with the known baseline; its left camera's frame is the world frame.

    R, t (when known, a factory-calibrated head): the right camera's pose in
    the left's frame, ``x_right = R x_left + t``, t in metres, |t| = baseline_m.
    `parallel`: the pair is a near-parallel head (optical axes nearly parallel,
    the right camera to the left's right), so the matcher may search its
    matches along image rows; otherwise it is matched like any other pair.
    """

    left: str
    right: str
    baseline_m: float
    R: np.ndarray | None = None
    t: np.ndarray | None = None
    sigma_m: float = 0.0  # 1 sigma of baseline_m, metres (a tape measure); 0: exact
    parallel: bool = False
    # 1 sigma, degrees, of the pair's rotation where a solve holds it (the rig file's stereo.tolerance_deg):
    # None, the calibrator's default (calibrate.Options.pair_tolerance_deg; 0 for a given pose R, t).
    tolerance_deg: float | None = None


@dataclass(frozen=True)
class Baseline:
    """A further known distance between two camera centres: a second stereo head, or a taped distance.

    a, b: camera ids; baseline_m: the distance, metres; sigma_m: its 1 sigma,
    metres (0: exact).
    """

    a: str
    b: str
    baseline_m: float
    sigma_m: float = 0.0


@dataclass(frozen=True)
class Observations:
    """Multi-view correspondences in flat arrays, one row per observation.

    ``uv[k]`` is the pixel at which camera ``cameras[cam_index[k]]`` sees
    track ``track_ids[track_index[k]]``.
    """

    cameras: tuple[CameraInfo, ...]
    stereo: Stereo
    track_ids: np.ndarray  # (T,) int
    cam_index: np.ndarray  # (n,) int
    track_index: np.ndarray  # (n,) int
    uv: np.ndarray  # (n, 2) float pixels
    baselines: tuple[Baseline, ...] = ()  # known distances beyond the stereo pair's

    @property
    def camera_ids(self) -> list[str]:
        return [c.id for c in self.cameras]

    def index_of(self, camera_id: str) -> int:
        return self.camera_ids.index(camera_id)

    def fisheye(self, order: list[int]) -> np.ndarray:
        """(len(order),) bool: whether camera ``cameras[order[m]]`` has the fisheye lens model."""
        return np.array([self.cameras[i].model == LensModel.FISHEYE for i in order], dtype=bool)


# ---------------------------------------------------------------- the solve report


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

    intrinsics: per camera id, the names of camnet.geometry.projection.INTRINSIC_NAMES
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
    # the calibration a warm start began from: camnet.geometry.scale_cause.held_at_given_pose), not the parallel pair.
    pair_pose_given: bool = False


@dataclass(frozen=True)
class Calibration:
    """A solved network: cameras in the left stereo camera's frame, metric points.

    rms_reprojection_px is NaN when no observation went into it (a factory
    stereo head); report is None when no solve made it.
    """

    cameras: tuple[Camera, ...]
    point_ids: np.ndarray  # (N,) int, the track ids kept
    points: np.ndarray  # (N, 3) metres, world frame
    rms_reprojection_px: float
    world_frame: str
    report: SolveReport | None = None

    @property
    def uncertainty(self) -> Uncertainty | None:
        """The report's uncertainty; None without a report or without uncertainty in it."""
        return self.report.uncertainty if self.report is not None else None

    @property
    def warnings(self) -> tuple[str, ...]:
        """The report's warnings; none without a report."""
        return self.report.warnings if self.report is not None else ()
