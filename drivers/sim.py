"""The simulated camera: renders the rig file's scene from its ground-truth camera.

Simulated cameras behave like hardware-triggered cameras on one common clock:
frame slot k is due at ``k / fps`` seconds of the host's wall clock (Unix
epoch), and its frame has ``seq = k``, ``timestamp_ns = k * 1e9 / fps``
(exact integer) and shows the scene at time ``k / fps``. So every simulated
camera of a rig with the same fps stamps the same instants and sees the same
scene at each, whichever process runs it and whenever it started; the matcher
can form frame sets from equal timestamps.

A camera that falls behind by a whole slot skips slots, counts them as
dropped, and its sequence numbers skip too, so receivers see the gap. It
resumes on a multiple of the smallest power of two above the number of slots
it was late by: cameras that fall behind alike (same rendering cost, same
machine) then land on the same slots instead of on interleaved ones, and the
coarser grids of the worse-off cameras nest in the finer ones.

A camera with a `clock` in the rig file (camnet.sim.clock) departs from this:
it exposes slot k at its clock's exposure instant (its own phase and drift
when free-running), shows the scene at that instant of the rig clock, and
stamps the frame with its own clock's reading `latency_ms` later, when the
frame is delivered. Its clock is set (drift counts from) when the camera is made.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import asdict
from fractions import Fraction

import numpy as np
from camnet.drivers.base import DeviceInfo, ReadTimeout

from camnet.bus.frame import Frame, FrameBuffer
from camnet.io.rig import CameraEntry, Rig
from camnet.sim.clock import SimClock
from camnet.sim.config import SimConfig
from camnet.sim.render import Renderer
from camnet.sim.scene import Scene


def create(entry: CameraEntry, rig: Rig) -> SimCamera:
    return SimCamera(entry.id, entry.config, Scene(rig.scene), groundtruth=groundtruth_document(rig))


def _convert(image: np.ndarray, encoding: str) -> np.ndarray:
    if encoding == "mono8":
        return image
    if encoding == "mono16":
        # Scale to the full 16-bit range, as a 16-bit sensor would fill it.
        return image.astype(np.uint16) * 257
    return np.repeat(image[:, :, None], 3, axis=2)


class SimCamera:
    def __init__(self, camera_id: str, config: SimConfig, scene: Scene, *, seed: int = 0,
                 groundtruth: dict | None = None, clock_epoch_ns: int | None = None) -> None:
        self.camera_id = camera_id
        self.config = config
        self.scene = scene
        self.groundtruth = groundtruth  # the whole rig's, for the node to publish
        # Each camera its own noise, reproducible from the rig's seed and the camera id.
        self._noise_seed = (seed, scene.config.seed, zlib.crc32(camera_id.encode()))
        self._renderer = Renderer(config.camera(camera_id), noise_seed=self._noise_seed)
        self._info = DeviceInfo(camera_id=camera_id, driver="sim", width=config.width,
                                height=config.height, encoding=config.encoding, fps=config.fps,
                                description="simulated camera (camnet.sim.render)")
        # fps as an exact fraction, so that every camera computes the same integer timestamps.
        self._fps = Fraction(config.fps)
        self._clock = config.clock or SimClock()  # the default clock is the common trigger's
        # When the camera's clock was set, on the rig clock (ns): its drift counts from then.
        self.clock_epoch_ns = time.time_ns() if clock_epoch_ns is None else clock_epoch_ns
        self._dropped = 0
        self._next_slot = 0

    @property
    def info(self) -> DeviceInfo:
        return self._info

    @property
    def dropped(self) -> int:
        return self._dropped

    def __enter__(self) -> SimCamera:
        self._next_slot = self.slot_at(time.time_ns()) + 1
        return self

    def __exit__(self, *exc_info: object) -> None:
        return None

    def exposure_ns(self, slot: int) -> int:
        """Rig-clock time of frame slot `slot`'s exposure (Unix epoch, ns): ``slot * 1e9 / fps`` rounded down
        unless a free-running clock says otherwise."""
        return self._clock.exposure_ns(slot, self._fps, self.clock_epoch_ns)

    def slot_timestamp_ns(self, slot: int) -> int:
        """The stamp of frame slot `slot` (ns): its exposure instant, or what the camera's clock reads when
        its frame is delivered."""
        return self._clock.stamp_ns(self.exposure_ns(slot), self.clock_epoch_ns)

    def due_ns(self, slot: int) -> int:
        """When the frame of slot `slot` is delivered (Unix epoch, ns): its exposure plus the clock's latency."""
        return self.exposure_ns(slot) + self._clock.latency_ns

    def slot_at(self, time_ns: int) -> int:
        """The last slot due (delivered) at or before `time_ns` (Unix epoch, ns)."""
        return self._clock.slot_at(time_ns - self._clock.latency_ns, self._fps, self.clock_epoch_ns)

    def true_offset_ms(self, slot: int) -> float:
        """The formats contract's `offset_ms` of this camera at frame slot `slot`: its capture instant on the
        rig's clock minus its stamp, in ms (camnet.sim.clock)."""
        return self._clock.true_offset_ms(self.exposure_ns(slot), self.clock_epoch_ns)

    def render(self, slot: int) -> np.ndarray:
        """The image of frame slot `slot`, in the camera's encoding: the scene at its exposure instant.

        Deterministic: the sensor noise is seeded by the slot too.
        """
        time_s = slot / self.config.fps if not self._clock.free_run else self.exposure_ns(slot) / 1e9
        return self.render_at(time_s, noise_key=slot)

    def render_at(self, time_s: float, *, noise_key: int) -> np.ndarray:
        """The image of the scene at rig time `time_s` (Unix epoch, s), its sensor noise seeded by `noise_key`."""
        quads = self.scene.quads(time_s)
        rng = np.random.default_rng([*self._noise_seed, noise_key])
        image = self._renderer.render(quads, noise_sigma_dn=self.config.noise_sigma_dn, rng=rng)
        return _convert(image, self.config.encoding)

    def read(self, *, timeout_s: float = 1.0) -> Frame:
        slot, timestamp_ns = self._wait_for_slot(timeout_s)
        return Frame(self.camera_id, slot, timestamp_ns, self.config.encoding, self.render(slot))

    def read_into(self, buffer: FrameBuffer, *, timeout_s: float = 1.0) -> tuple[int, int] | Frame:
        slot, timestamp_ns = self._wait_for_slot(timeout_s)
        return buffer.fill(slot, timestamp_ns, self.config.encoding, self.render(slot))

    def _wait_for_slot(self, timeout_s: float) -> tuple[int, int]:
        """(slot, timestamp_ns) of the next frame, once it is due; ReadTimeout if not within `timeout_s`."""
        now_ns = time.time_ns()
        slot = self._next_slot
        late_slots = self.slot_at(now_ns) - slot
        if late_slots > 0:
            # The smallest power of two > late_slots, but at most about a second of slots: a camera
            # that was stopped for a while (SIGSTOP, a suspended host) resumes within a second, not
            # within as long again as it was away.
            max_stride = 1 << max(0, int(self.config.fps).bit_length() - 1)
            stride = min(1 << late_slots.bit_length(), max_stride)
            resume = -(-self.slot_at(now_ns) // stride) * stride
            self._dropped += resume - slot
            slot = self._next_slot = resume
        wait_s = (self.due_ns(slot) - now_ns) / 1e9
        if wait_s > timeout_s:
            time.sleep(timeout_s)
            raise ReadTimeout(f"next simulated frame due in {wait_s:.3f} s")
        if wait_s > 0:
            time.sleep(wait_s)
        self._next_slot = slot + 1
        return slot, self.slot_timestamp_ns(slot)


def groundtruth_document(rig: Rig) -> dict:
    """The rig's simulated cameras as a camnet.calibration/1-like document (world = left).

    A camera with a clock has its parameters under "clock" (camnet.sim.clock.SimClock's fields); its
    true `offset_ms` also depends on when its driver set its clock (`SimCamera.true_offset_ms`).
    """
    cameras = []
    for entry in rig.cameras:
        if entry.driver != "sim":
            continue
        cam = entry.config.camera(entry.id)
        cameras.append({"id": cam.id, "width": cam.width, "height": cam.height,
                        "K": cam.K.tolist(), "dist": cam.dist.tolist(), "R": cam.R.tolist(),
                        "t": cam.t.tolist()})
        if entry.config.clock is not None:  # its offset follows from these and its clock's epoch
            cameras[-1]["clock"] = asdict(entry.config.clock)
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
