"""A camera: its lens model, a calibrated camera, and what observations say of one.

Pure values, no I/O (the JSON codec is camnet.io.formats). Conventions are those of
camnet.model.projection: ``x_cam = R @ X_world + t``, lengths in metres, pixels with ``u`` right,
``v`` down, origin at the centre of the top-left pixel, ``K`` in pixels and ``dist`` in OpenCV's
order: ``[k1, k2, p1, p2, k3]`` for the pinhole lens model, ``[k1, k2, k3, k4]`` for the fisheye.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np

from camnet.model.projection import DIST_SIZE, FISHEYE_DIST_SIZE, normalised, project


class LensModel(StrEnum):
    """A camera's lens model (camnet.model.projection): its `dist` is in that model's order."""

    PINHOLE = "pinhole"  # OpenCV's radial-tangential distortion, dist [k1, k2, p1, p2, k3]
    FISHEYE = "fisheye"  # OpenCV's fisheye (Kannala-Brandt), dist [k1, k2, k3, k4]

    @property
    def dist_size(self) -> int:
        """How many coefficients the model's `dist` has."""
        return FISHEYE_DIST_SIZE if self == LensModel.FISHEYE else DIST_SIZE


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
                raise ValueError(f"camera {self.id!r}: a fisheye's dist is [k1, k2, k3, k4], got "
                                 f"{', '.join(f'{d:g}' for d in self.dist)}")
            object.__setattr__(self, "dist", np.zeros(FISHEYE_DIST_SIZE))  # the default: no distortion

    @property
    def centre(self) -> np.ndarray:
        """Camera centre in world coordinates (m)."""
        return -self.R.T @ self.t

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) of world points (n, 3); see camnet.model.projection.project."""
        return project(
            points_world, K=self.K, dist=self.dist, R=self.R, t=self.t, fisheye=self.model == LensModel.FISHEYE
        )

    def normalised(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (n, 2) of pixels (n, 2); see camnet.model.projection.normalised."""
        return normalised(uv, K=self.K, dist=self.dist, fisheye=self.model == LensModel.FISHEYE)


def in_frame(camera: Camera, R: np.ndarray, t: np.ndarray) -> Camera:
    """The camera with its pose in the frame ``X_new = R @ X + t`` of its world (R a rotation, t metres)."""
    R_new = camera.R @ np.asarray(R, dtype=float).T
    return replace(camera, R=R_new, t=camera.t - R_new @ np.asarray(t, dtype=float))


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
