"""What every stage of a solve reads of its observations: the problem's camera order, each track's
observation rows, the given intrinsics and the centred pixels.

Cameras are in problem order (left stereo camera, right stereo camera, then
the others in the order of the observations), points one per track row
(NaN where not yet known). Pixels handed to the solvers are *centred*:
relative to each camera's principal point, undistorted where the
distortion is known (camnet.solve.context.centred). Poses are ``x_cam = R (X - C)``, metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from camnet.model.camera import CameraInfo, LensModel
from camnet.model.observations import Observations
from camnet.model.projection import K_from_intrinsics, full_dist, intrinsics_from_K, normalised


@dataclass(frozen=True)
class SolveContext:
    """The observations as every stage of a solve reads them, computed once: the problem's camera order,
    each track's observation rows, the intrinsics the observations give, and the centred pixels.

    Its arrays are read-only; a stage that knows other intrinsics (a warm start's) makes a new context
    with `with_intrinsics`.
    """

    obs: Observations
    order: tuple[int, ...]  # problem camera m is observations camera order[m]: the stereo pair first
    intr: np.ndarray  # (M, 9) the given intrinsics; f NaN and the image centre where not given
    xy: np.ndarray  # (n, 2) centred pixels of every observation
    rows: np.ndarray  # (T, cameras) observation row of each track per observations camera, -1 where none or xy NaN

    def __post_init__(self) -> None:
        for array in (self.intr, self.xy, self.rows):
            array.setflags(write=False)

    @staticmethod
    def of(obs: Observations, intr: np.ndarray | None = None) -> SolveContext:
        """The context of `obs`, with intrinsics `intr` (M, 9) in problem order, or those its cameras give."""
        order = camera_order(obs)
        intr = initial_intrinsics(obs, order) if intr is None else np.array(intr, dtype=float)
        xy = centred(obs, order, intr)
        return SolveContext(obs, tuple(order), intr, xy, observation_rows(obs, xy))

    def with_intrinsics(self, intr: np.ndarray) -> SolveContext:
        """The same observations with intrinsics `intr` (M, 9): their pixels centred anew."""
        intr = np.array(intr, dtype=float)
        xy = centred(self.obs, list(self.order), intr)
        return SolveContext(self.obs, self.order, intr, xy, observation_rows(self.obs, xy))

    @property
    def n_cameras(self) -> int:
        return len(self.order)

    def camera(self, m: int) -> CameraInfo:
        """What the observations say of problem camera m."""
        return self.obs.cameras[self.order[m]]

    def camera_rows(self, m: int) -> np.ndarray:
        """(T,) problem camera m's observation row of each track, -1 where it does not see it."""
        return self.rows[:, self.order[m]]

    @cached_property
    def problem_rows(self) -> np.ndarray:
        """(T, M) each track's observation row per problem camera, -1 where none."""
        return self.rows[:, list(self.order)]

    @cached_property
    def held_K(self) -> np.ndarray:
        """(M,) bool: the observations give the camera's K and hold it."""
        return np.array([self.camera(m).K is not None and "K" in self.camera(m).fixed for m in range(self.n_cameras)])

    @cached_property
    def held_dist(self) -> np.ndarray:
        """(M,) bool: the observations give the camera's distortion and hold it."""
        return np.array([self.camera(m).dist is not None and "dist" in self.camera(m).fixed
                         for m in range(self.n_cameras)])

    @cached_property
    def guessed_K(self) -> np.ndarray:
        """(M,) bool: the observations give no K of the camera (its principal point is guessed)."""
        return np.array([self.camera(m).K is None for m in range(self.n_cameras)])

    @cached_property
    def threshold_px(self) -> float:
        """RANSAC's inlier threshold of the start (`threshold_px`)."""
        return threshold_px(self.obs, list(self.order))


def threshold_px(obs: Observations, order: list[int]) -> float:
    """RANSAC inlier threshold: 1% of the left image's diagonal (a start, not a fit)."""
    left = obs.cameras[order[0]]
    return 0.01 * float(np.hypot(left.width, left.height))


def camera_order(obs: Observations) -> list[int]:
    """Problem camera m is observations camera order[m]: the stereo pair first."""
    left, right = obs.index_of(obs.stereo.left), obs.index_of(obs.stereo.right)
    return [left, right] + [i for i in range(len(obs.cameras)) if i not in (left, right)]


def observation_rows(obs: Observations, xy: np.ndarray | None = None) -> np.ndarray:
    """(T, cameras) row of the observation of each track by each camera; -1 where none, or where its centred
    pixel `xy` (n, 2), if given, is not finite (a fisheye's pixel beyond the model's 90 degrees gives no ray to
    start from; the adjustment, which projects, still takes it)."""
    rows = np.full((len(obs.track_ids), len(obs.cameras)), -1)
    usable = np.ones(len(obs.uv), dtype=bool) if xy is None else np.all(np.isfinite(xy), axis=1)
    rows[obs.track_index[usable], obs.cam_index[usable]] = np.flatnonzero(usable)
    return rows


def initial_intrinsics(obs: Observations, order: list[int]) -> np.ndarray:
    """(M, 9) intrinsics given by the observations; f NaN and the image centre where not given."""
    intr = np.zeros((len(order), 9))
    for m, i in enumerate(order):
        cam = obs.cameras[i]
        dist = full_dist(cam.dist)  # a fisheye's four padded with a zero
        if cam.K is not None:
            intr[m] = intrinsics_from_K(cam.K, dist)
        else:
            intr[m] = [np.nan, 1.0, (cam.width - 1) / 2, (cam.height - 1) / 2, *dist]
    return intr


def centred(obs: Observations, order: list[int], intr: np.ndarray) -> np.ndarray:
    """Observed pixels relative to each camera's principal point, undistorted where known.

    A fisheye camera's pixels are made pinhole ones (of the same K), with a
    guessed focal length where none is known (`with_guessed_fisheye_focal`).
    """
    intr = with_guessed_fisheye_focal(obs, order, intr)
    m_of = np.empty(len(obs.cameras), dtype=int)
    m_of[order] = np.arange(len(order))
    m = m_of[obs.cam_index]
    xy = obs.uv - intr[m, 2:4]
    fisheye = np.array([obs.cameras[i].model == LensModel.FISHEYE for i in order])
    for mm in np.flatnonzero((np.any(intr[:, 4:] != 0, axis=1) | fisheye) & np.isfinite(intr[:, 0])):
        rows = m == mm
        K = K_from_intrinsics(intr[mm])
        dist = intr[mm, 4 : 4 + obs.cameras[order[mm]].model.dist_size]
        xy[rows] = normalised(obs.uv[rows], K=K, dist=dist, fisheye=fisheye[mm]) * np.diag(K)[:2]
    return xy


# A fisheye's guessed focal length puts its image's corner this far off the axis (rad): a pinhole
# image of the pixels then stays finite (tan 1.2 = 2.6) whatever the lens's true field of view.
FISHEYE_START_CORNER_RAD = 1.2


def with_guessed_fisheye_focal(obs: Observations, order: list[int], intr: np.ndarray) -> np.ndarray:
    """`intr` (M, 9) with a focal length guessed for each fisheye camera that has none, for `centred`.

    Raw fisheye pixels are no pinhole image: the paper's start on them can land
    the adjustment in a wrong valley that fits as well. Made pinhole by an
    equidistant lens of the guessed focal length (half the image diagonal over
    FISHEYE_START_CORNER_RAD), they start it in the right one, even with a guess
    a quarter off (docs/benchmarks.md, "Evidence behind the solver's
    thresholds"). The start estimates the focal lengths itself: the guess only
    undistorts (`centred` uses it).
    """
    guessed = intr.copy()
    for m, i in enumerate(order):
        cam = obs.cameras[i]
        if cam.model == LensModel.FISHEYE and not np.isfinite(intr[m, 0]):
            guessed[m, 0] = np.hypot(cam.width, cam.height) / 2 / FISHEYE_START_CORNER_RAD
    return guessed
