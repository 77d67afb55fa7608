"""The pinhole camera with OpenCV distortion.

Pose ``x_cam = R @ X_world + t`` (the camera centre is ``C = -R.T @ t``),
lengths in metres, K in pixels; the conventions and the projection itself
are `camnet.geometry.projection`'s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from camnet.geometry.projection import DIST_SIZE, project


@dataclass(frozen=True)
class Camera:
    """One calibrated camera: intrinsics, distortion and pose in the world frame."""

    id: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(DIST_SIZE))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def centre(self) -> np.ndarray:
        """Camera centre in world coordinates (m)."""
        return -self.R.T @ self.t

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) of world points (n, 3); see `camnet.geometry.projection.project`."""
        return project(points_world, K=self.K, dist=self.dist, R=self.R, t=self.t)
