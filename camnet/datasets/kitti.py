"""The KITTI raw "extract" (unrectified) layout: calibration and frames.

Reads ``calib_cam_to_cam.txt`` into `camnet.model.camera.Camera` objects in the
frame of camera 0 (``x_cam = R @ X + t``, X in cam-0 coordinates, metres;
KITTI's ``R_xx``/``T_xx`` already map cam-0 coordinates into camera xx), and
lists which cameras have an image for each frame in ``image_0X/data/``.

Camera ids are ``"0"`` ... ``"3"``: 0 = left grey, 1 = right grey,
2 = left colour, 3 = right colour. The grey pair (0, 1) is the stereo pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from camnet.errors import InputError
from camnet.model.calibration import Calibration
from camnet.model.camera import Camera, CameraInfo
from camnet.model.observations import Observations, Stereo

CALIB_FILE = "calib_cam_to_cam.txt"
STEREO_LEFT, STEREO_RIGHT = "0", "1"


def parse_calib_cam_to_cam(text: str, *, source: str = CALIB_FILE) -> dict[str, Camera]:
    """Cameras of a ``calib_cam_to_cam.txt`` (raw, unrectified model), keyed by id.

    Uses ``S_xx`` (width, height in pixels), ``K_xx``, ``D_xx`` (OpenCV
    order k1, k2, p1, p2, k3), ``R_xx`` and ``T_xx`` (metres).
    """
    values: dict[str, np.ndarray] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        key, sep, rest = line.partition(":")
        if not sep or key in ("calib_time",):
            continue
        try:
            values[key.strip()] = np.array([float(x) for x in rest.split()])
        except ValueError:
            raise InputError(f"{source}:{lineno}: {key.strip()}: expected numbers") from None
    cameras: dict[str, Camera] = {}
    for xx in sorted({k[2:] for k in values if k.startswith("K_")}):
        need = {name: f"{name}_{xx}" for name in ("S", "K", "D", "R", "T")}
        sizes = {"S": 2, "K": 9, "D": 5, "R": 9, "T": 3}
        for name, key in need.items():
            if key not in values:
                raise InputError(f"{source}: {key}: missing")
            if values[key].size != sizes[name]:
                raise InputError(f"{source}: {key}: expected {sizes[name]} numbers")
        width, height = (int(round(x)) for x in values[need["S"]])
        cam_id = str(int(xx))
        t = values[need["T"]].copy()
        if cam_id == "0":
            t[:] = 0.0  # stored as ~1e-16: the reference frame itself
        cameras[cam_id] = Camera(
            id=cam_id,
            width=width,
            height=height,
            K=values[need["K"]].reshape(3, 3),
            dist=values[need["D"]].copy(),
            R=values[need["R"]].reshape(3, 3),
            t=t,
        )
    if not cameras:
        raise InputError(f"{source}: no K_xx entries; is this a KITTI calib_cam_to_cam.txt?")
    return cameras


@dataclass(frozen=True)
class KittiFrame:
    """One trigger: its name (e.g. ``0000000001``) and the image path per camera id."""

    name: str
    images: dict[str, Path]

    @property
    def index(self) -> int:
        return int(self.name)

    @property
    def camera_ids(self) -> tuple[str, ...]:
        return tuple(sorted(self.images))


@dataclass(frozen=True)
class KittiExtract:
    """A KITTI raw extract folder: ``calib_cam_to_cam.txt`` and ``image_0X/data/*.png``."""

    root: Path
    cameras: dict[str, Camera]  # ground truth, cam-0 frame

    @classmethod
    def open(cls, root: str | Path) -> KittiExtract:
        root = Path(root)
        path = root / CALIB_FILE
        try:
            text = path.read_text()
        except OSError as exc:
            raise InputError(f"{path}: cannot read ({exc.strerror})") from None
        return cls(root, parse_calib_cam_to_cam(text, source=str(path)))

    @property
    def stereo(self) -> Stereo:
        """The grey pair, a parallel head, with its baseline |C_1 - C_0| in metres."""
        left, right = self.cameras[STEREO_LEFT], self.cameras[STEREO_RIGHT]
        return Stereo(STEREO_LEFT, STEREO_RIGHT, float(np.linalg.norm(right.centre - left.centre)), parallel=True)

    def frames(self) -> list[KittiFrame]:
        """Every frame with at least one image, sorted by name."""
        by_name: dict[str, dict[str, Path]] = {}
        for cam_id in self.cameras:
            folder = self.root / f"image_{int(cam_id):02d}" / "data"
            for png in sorted(folder.glob("*.png")):
                by_name.setdefault(png.stem, {})[cam_id] = png
        return [KittiFrame(name, images) for name, images in sorted(by_name.items())]

    def frame(self, name: str | int) -> KittiFrame:
        key = f"{int(name):010d}"
        for f in self.frames():
            if f.name == key:
                return f
        raise InputError(f"{self.root}: no frame {key}")


def read_image(path: str | Path) -> np.ndarray:
    """An image as uint8 grey (H, W) or BGR (H, W, 3), as stored."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: cannot read image")
    return image


def pooled_observations(kitti: KittiExtract, *, max_tracks: int = 3000) -> Observations:
    """The extract's frame sets matched and pooled into tracks as camnet's matcher does (SIFT), with
    the cameras' sizes and nothing else known of them."""
    from camnet.matching.engine import EngineConfig  # SIFT and the pool: only when asked
    from camnet.matching.pipeline import observations_from_frame_sets
    from camnet.matching.pool import PoolConfig

    infos = [CameraInfo(c.id, c.width, c.height) for c in kitti.cameras.values()]
    frame_sets = ({c: read_image(p) for c, p in f.images.items()} for f in kitti.frames())
    return observations_from_frame_sets(frame_sets, cameras=infos, stereo=kitti.stereo,
                                        config=EngineConfig(pool=PoolConfig(max_tracks=max_tracks)))


# What a user may know before calibrating, from nothing to everything but the poses.
# Each maps to observations (K, dist, fixed per camera) and an optional initial
# calibration holding the stereo pair's factory pose (`camnet calibrate --initial`).
SCENARIOS = {
    "scene": "nothing known: all intrinsics from the scene",
    "stereo-K": "stereo K+dist fixed; colour f from the scene, colour dist given",
    "stereo-head": "stereo K+dist and pose (R, t) fixed; colour f from the scene, colour dist given",
    "all-K": "every K+dist fixed, stereo pose fixed: colour poses from the scene",
}


def prepare_scenario(
    obs: Observations, published: dict[str, Camera], scenario: str
) -> tuple[Observations, Calibration | None]:
    """(observations carrying what `scenario` knows, initial calibration or None); see SCENARIOS."""
    from camnet.matching.pipeline import with_known_intrinsics

    if scenario not in SCENARIOS:
        raise InputError(f"scenario: unknown {scenario!r}; expected one of {sorted(SCENARIOS)}")
    if scenario == "scene":
        return obs, None
    stereo_ids = (STEREO_LEFT, STEREO_RIGHT)
    others = [c for c in obs.camera_ids if c not in stereo_ids]
    if scenario == "all-K":
        obs = with_known_intrinsics(obs, {c: published[c] for c in obs.camera_ids})
    else:
        obs = with_known_intrinsics(obs, {c: published[c] for c in stereo_ids})
        # The colour lenses' distortion as a starting point (held unless the data determine it):
        # f cannot be recovered with k1 ~ -0.37 left at zero.
        obs = with_known_intrinsics(obs, {c: published[c] for c in others}, given=("dist",), fixed=())
    if scenario == "stereo-K":
        return obs, None
    return obs, stereo_head(published)


def stereo_head(published: dict[str, Camera]) -> Calibration:
    """A calibration of the grey pair alone (K, dist, pose as published, no points): a factory stereo head.

    Offline it is `calibrate(..., initial=)`; live, the calibrator resumes
    from it as its state file and, with only the focal lengths free, holds
    the pair's pose.
    """
    return Calibration(
        cameras=tuple(published[c] for c in (STEREO_LEFT, STEREO_RIGHT)),
        point_ids=np.empty(0, dtype=np.int64),
        points=np.empty((0, 3)),
        rms_reprojection_px=float("nan"),
        world_frame=STEREO_LEFT,
    )
