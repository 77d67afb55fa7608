"""Observations: multi-view correspondences, the stereo pair with its known baseline, further known distances.

Pure values, no I/O (the JSON codec is camnet.io.formats). Pixels with ``u`` right, ``v`` down, origin at
the centre of the top-left pixel; lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from camnet.model.camera import CameraInfo, LensModel


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

    def only_cameras(self, keep: np.ndarray) -> Observations:
        """These observations of only the cameras where `keep` (bool, one per camera) is true: the others'
        observations and known distances go, every track stays (the stereo pair must be kept)."""
        keep = np.asarray(keep, dtype=bool)
        new_index = np.cumsum(keep) - 1
        rows = keep[self.cam_index]
        cameras = tuple(c for c, k in zip(self.cameras, keep, strict=True) if k)
        ids = {c.id for c in cameras}
        return replace(
            self, cameras=cameras, baselines=tuple(b for b in self.baselines if {b.a, b.b} <= ids),
            cam_index=new_index[self.cam_index[rows]], track_index=self.track_index[rows], uv=self.uv[rows],
        )
