"""The simulated camera: renders the rig file's scene from its ground-truth camera.

Frames come at the configured rate on the host's clock. Frame slot k is due at
``start + k / fps``; if rendering falls behind by a whole slot the slot is
skipped and counted as dropped, and its sequence number is skipped too, so
receivers see the gap. The scene's time is the slot's time, so a run is
reproducible frame by frame.
"""

from __future__ import annotations

import time
import zlib

import numpy as np

from camnet.frame import Frame
from camnet.render import Renderer
from camnet.rig import CameraEntry, Rig, SimConfig
from camnet.scene import Scene
from drivers.base import CameraInfo, ReadTimeout


def create(entry: CameraEntry, rig: Rig) -> SimCamera:
    return SimCamera(entry.id, entry.config, Scene(rig.scene))


def _convert(image: np.ndarray, encoding: str) -> np.ndarray:
    if encoding == "mono8":
        return image
    if encoding == "mono16":
        # Scale to the full 16-bit range, as a 16-bit sensor would fill it.
        return image.astype(np.uint16) * 257
    return np.repeat(image[:, :, None], 3, axis=2)


class SimCamera:
    def __init__(self, camera_id: str, config: SimConfig, scene: Scene, *, seed: int = 0) -> None:
        self.camera_id = camera_id
        self.config = config
        self.scene = scene
        self.ground_truth = config.camera(camera_id)
        self._renderer = Renderer(self.ground_truth)
        # Each camera its own noise, reproducible from the rig's seed and the camera id.
        self._rng = np.random.default_rng([seed, scene.config.seed,
                                           zlib.crc32(camera_id.encode())])
        self._info = CameraInfo(camera_id=camera_id, driver="sim", width=config.width,
                                height=config.height, encoding=config.encoding, fps=config.fps,
                                description="simulated camera (camnet.render)")
        self._dropped = 0
        self._slot = 0
        self._start_mono_ns = 0
        self._start_wall_ns = 0

    @property
    def info(self) -> CameraInfo:
        return self._info

    @property
    def dropped(self) -> int:
        return self._dropped

    def __enter__(self) -> SimCamera:
        self._start_mono_ns = time.monotonic_ns()
        self._start_wall_ns = time.time_ns()
        self._slot = 0
        return self

    def __exit__(self, *exc_info: object) -> None:
        return None

    def render(self, slot: int) -> np.ndarray:
        """The image of frame slot `slot` (scene time slot / fps), in the camera's encoding."""
        quads = self.scene.quads(slot / self.config.fps)
        image = self._renderer.render(quads, noise_sigma_dn=self.config.noise_sigma_dn,
                                      rng=self._rng)
        return _convert(image, self.config.encoding)

    def read(self, *, timeout_s: float = 1.0) -> Frame:
        period_ns = 1e9 / self.config.fps
        now = time.monotonic_ns()
        late_slots = int((now - self._start_mono_ns) // period_ns) - self._slot
        if late_slots > 0:
            self._dropped += late_slots
            self._slot += late_slots
        due_ns = self._start_mono_ns + int(self._slot * period_ns)
        wait_s = (due_ns - now) / 1e9
        if wait_s > timeout_s:
            time.sleep(timeout_s)
            raise ReadTimeout(f"next simulated frame due in {wait_s:.3f} s")
        if wait_s > 0:
            time.sleep(wait_s)
        slot = self._slot
        self._slot += 1
        image = self.render(slot)
        return Frame(camera_id=self._info.camera_id, seq=slot,
                     timestamp_ns=self._start_wall_ns + int(slot * period_ns),
                     encoding=self.config.encoding, image=image)


def groundtruth_document(rig: Rig) -> dict:
    """The rig's simulated cameras as a camnet.calibration/1-like document (world = left)."""
    cameras = []
    for entry in rig.cameras:
        if entry.driver != "sim":
            continue
        cam = entry.config.camera(entry.id)
        cameras.append({"id": cam.id, "width": cam.width, "height": cam.height,
                        "K": cam.K.tolist(), "dist": cam.dist.tolist(), "R": cam.R.tolist(),
                        "t": cam.t.tolist()})
    scene = rig.scene
    world = rig.stereo.left if rig.stereo is not None else cameras[0]["id"] if cameras else ""
    doc = {"format": "camnet.calibration/1", "world_frame": world, "units": "m",
           "rig": rig.name, "cameras": cameras, "points": [],
           "scene": {"box_centre_m": list(scene.box_centre_m),
                     "box_size_m": list(scene.box_size_m),
                     "box_rotation_deg_per_s": scene.box_rotation_deg_per_s,
                     "wall_z_m": scene.wall_z_m, "floor_y_m": scene.floor_y_m}}
    if rig.stereo is not None:
        doc["stereo"] = {"left": rig.stereo.left, "right": rig.stereo.right,
                         "baseline_m": rig.stereo.baseline_m}
    return doc
