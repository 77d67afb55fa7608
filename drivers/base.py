"""The Camera protocol every driver implements, and the lazy driver registry.

A camera is a context manager: entering opens it, leaving closes it. Inside,
`read()` returns the next `camnet.bus.frame.Frame` (blocking at most `timeout_s`)
and `dropped` counts frames the camera produced but the driver lost.
`read_into(buffer)` is the driver node's way, frame after frame: it writes
the next frame's pixels into the node's reused message
(`camnet.bus.frame.FrameBuffer.fill`) and returns only its
``(seq, timestamp_ns)``; no `Frame` is built. A frame the buffer cannot
carry (another size or encoding: the first after a reconnection, say)
comes back as a `Frame` of its own instead, so callers check which they
got. A simulated camera also knows the rig's ground truth (`groundtruth`),
which its node publishes; real cameras have None. Driver modules are
imported only when chosen, so a missing SDK (Aravis, say) breaks only that
driver.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from camnet.bus.frame import Frame, FrameBuffer
from camnet.errors import CamnetError
from camnet.io.rig import DRIVERS, CameraEntry, Rig

# The driver registry: driver name (one per config section of a rig file) -> module implementing
# `create(entry, rig) -> Camera`, imported only when the driver is chosen.
DRIVER_MODULES = {name: f"camnet.drivers.{name}" for name in DRIVERS}

# What to install when a driver's module cannot be imported.
INSTALL_HINTS = {
    "aravis": "install the Aravis typelib (Debian: gir1.2-aravis-0.8) and PyGObject<3.51 "
              "(pip install 'camnet[aravis]')",
}


class DeviceError(CamnetError):
    """A camera cannot be opened or used; the message names it and what to check."""


class ReadTimeout(Exception):
    """No frame arrived within the timeout (camera slow, absent, or reconnecting)."""


class EndOfStream(Exception):
    """A finite source (video file, image sequence) has no more frames."""


@dataclass(frozen=True)
class DeviceInfo:
    """What an opened device reports of itself; `fps` is nominal (0 if unknown)."""

    camera_id: str
    driver: str
    width: int
    height: int
    encoding: str
    fps: float
    description: str = ""


@dataclass(frozen=True)
class FoundCamera:
    """A camera found on this host (`camnet cameras`), with what its driver reports of its modes.

    `device` is what a rig file names it by (a v4l2 `source`, an Aravis
    `device_id`); `modes` are lines such as ``MJPG 1920x1080 at 30, 15 fps``;
    `pixel_formats` are the camera's own names (GenICam, V4L2 fourcc); `problem`
    says why the camera could not be asked (then `modes` may be empty).
    """

    driver: str
    device: str
    description: str
    modes: tuple[str, ...] = ()
    pixel_formats: tuple[str, ...] = ()
    problem: str | None = None
    fake: bool = False  # Aravis's in-process Fake camera

    @property
    def suggested_id(self) -> str:
        """A camera id for a rig file: the device's name without what ids may not hold."""
        name = self.device.removeprefix("/dev/")
        return "".join("_" if ch in "/*$?# " else ch for ch in name)


@runtime_checkable
class Camera(Protocol):
    camera_id: str
    groundtruth: dict | None  # the rig's simulated cameras, camnet.calibration/1-like (world = left)

    @property
    def info(self) -> DeviceInfo: ...

    @property
    def dropped(self) -> int: ...

    def __enter__(self) -> Camera: ...

    def __exit__(self, *exc_info: object) -> None: ...

    def read(self, *, timeout_s: float = 1.0) -> Frame: ...

    def read_into(self, buffer: FrameBuffer, *, timeout_s: float = 1.0) -> tuple[int, int] | Frame: ...


def create_camera(entry: CameraEntry, rig: Rig, **options: object) -> Camera:
    """An unopened camera for `entry`, importing its driver module now; `options`: the driver's own keywords
    (v4l2: `files_start_ns`)."""
    module_name = DRIVER_MODULES.get(entry.driver)
    if module_name is None:
        raise DeviceError(f"camera {entry.id!r}: unknown driver {entry.driver!r} "
                          f"(expected {', '.join(DRIVERS)})")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        hint = INSTALL_HINTS.get(entry.driver, "check the installation")
        raise DeviceError(f"camera {entry.id!r}: the {entry.driver} driver is unavailable "
                          f"({exc}); {hint}") from exc
    return module.create(entry, rig, **options)
