"""GigE Vision / USB3 Vision cameras through Aravis (GObject introspection).

Acquisition uses Aravis's stream buffer pool: `n_buffers` buffers are pushed
once, each `read()` pops one (with a timeout), copies the pixels out and pushes
the buffer straight back, so no allocation happens per frame.

When the camera disappears (GigE control lost, or no buffer for
`lost_after_s`), the driver drops it and reconnects by itself with
exponential back-off (0.5 s doubling to 4 s). Waiting for a reconnection
sleeps; it never spins. Timestamps are the camera's own (ns) when it gives
them, else the host's.

Threads: every Aravis call is made from the thread that calls `read()`,
except the release of a lost camera. Releasing a lost GigE device blocks for
several seconds in Aravis's finalizers (stream reset and control release are
retried until they time out), so it runs in a release thread, and nothing
else touches Aravis until it is done: the next connection waits for it, and
the old device never talks to the camera that came back. Control loss is
read from the device's controller flag (`is_controller()`, which Aravis's
heartbeat thread clears when it emits "control-lost"), not from a Python
handler of that signal: a handler makes the heartbeat thread hold a
reference to the device, and if it holds the last one, Aravis finalizes the
device in its own heartbeat thread, which then joins itself and GLib aborts
the process (g_error, SIGTRAP).
"""

from __future__ import annotations

import logging
import threading
import time

import gi
import numpy as np

gi.require_version("Aravis", "0.8")
from camnet.drivers.base import DeviceError, DeviceInfo, FoundCamera, ReadTimeout  # noqa: E402
from gi.repository import Aravis, GLib  # noqa: E402  (require_version must come first)

from camnet.bus.frame import Frame, FrameBuffer  # noqa: E402
from camnet.io.rig import AravisConfig, CameraEntry, Rig  # noqa: E402

log = logging.getLogger(__name__)

# GenICam PFNC codes -> camnet encodings.
PIXEL_FORMATS = {
    0x01080001: "mono8",
    0x01100007: "mono16",
    0x02180014: "rgb8",
    0x02180015: "bgr8",
    0x01080008: "bayer_grbg8",
    0x01080009: "bayer_rggb8",
    0x0108000A: "bayer_gbrg8",
    0x0108000B: "bayer_bggr8",
}
_CHANNELS = {"rgb8": 3, "bgr8": 3}
BACKOFF_START_S = 0.5
BACKOFF_MAX_S = 4.0
# How long closing waits for the release of a lost camera (Aravis needs ~8 s).
RELEASE_WAIT_S = 15.0
_FRAME_ID_MODULO = 1 << 16  # GigE Vision 1.x block ids are 16-bit


def create(entry: CameraEntry, rig: Rig) -> AravisCamera:
    return AravisCamera(entry.id, entry.config)


FAKE_INTERFACE = "Fake"  # Aravis's in-process Fake camera (device id Fake_1)


def discover(*, fake: bool = False) -> list[FoundCamera]:
    """The cameras Aravis finds (GigE Vision on every interface, USB3 Vision), each with its modes.

    `fake` also enables Aravis's in-process Fake camera. A camera that cannot
    be opened (held by another program, on another subnet) is listed with why.
    """
    if fake:
        Aravis.enable_interface(FAKE_INTERFACE)
    Aravis.update_device_list()
    found = []
    for i in range(Aravis.get_n_devices()):
        device_id = Aravis.get_device_id(i)
        address = Aravis.get_device_address(i)
        description = (f"{Aravis.get_device_vendor(i)} {Aravis.get_device_model(i)} "
                       f"(serial {Aravis.get_device_serial_nbr(i)}, {Aravis.get_device_protocol(i)}"
                       f"{', ' + address if address and address != '0.0.0.0' else ''})")
        is_fake = Aravis.get_device_protocol(i) == FAKE_INTERFACE
        try:
            modes, formats = _modes(Aravis.Camera.new(device_id))
        except GLib.Error as exc:
            found.append(FoundCamera("aravis", device_id, description, problem=f"cannot open: {exc.message}",
                                     fake=is_fake))
            continue
        found.append(FoundCamera("aravis", device_id, description, modes=modes, pixel_formats=formats, fake=is_fake))
    return found


def _modes(camera) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(mode lines, GenICam pixel format names) of an open camera, which is released on return."""
    formats = tuple(camera.dup_available_pixel_formats_as_strings() or ())
    _, _, width, height = camera.get_region()
    widths, heights = camera.get_width_bounds(), camera.get_height_bounds()
    lines = [f"pixel formats: {', '.join(formats) or '?'}",
             f"size: {width}x{height} now, {widths.min}x{heights.min} to {widths.max}x{heights.max}"]
    if camera.is_frame_rate_available():
        rates = camera.get_frame_rate_bounds()
        lines.append(f"frame rate: {camera.get_frame_rate():g} fps now, {rates.min:g} to {rates.max:g} fps")
    return tuple(lines), formats


def _release_in_order(held: list) -> None:
    """Drop the last references to [stream, camera, device], in that order.

    The stream goes first: its finalizer stops its receiving thread and still
    talks to the device. The caller must keep no other reference.
    """
    while held:
        del held[0]


class AravisCamera:
    groundtruth = None  # a real camera
    def __init__(self, camera_id: str, config: AravisConfig, *, lost_after_s: float = 2.0) -> None:
        self.camera_id = camera_id
        self.config = config
        self.lost_after_s = lost_after_s
        self._camera = None
        self._stream = None
        self._gv_device = None  # the GigE device, whose controller flag tells control loss
        self._release: threading.Thread | None = None
        self._info: DeviceInfo | None = None
        self._seq = 0
        self._dropped = 0
        self._reconnects = 0
        self._last_frame_id: int | None = None
        self._last_buffer_mono = 0.0
        self._backoff_s = BACKOFF_START_S
        self._next_attempt_mono = 0.0

    @property
    def info(self) -> DeviceInfo:
        if self._info is None:
            raise DeviceError(f"camera {self.camera_id!r}: not open")
        return self._info

    @property
    def dropped(self) -> int:
        return self._dropped

    @property
    def reconnects(self) -> int:
        """How many times the camera was lost and found again."""
        return self._reconnects

    @property
    def connected(self) -> bool:
        return self._camera is not None

    def __enter__(self) -> AravisCamera:
        if self.config.enable_fake_interface:
            Aravis.enable_interface("Fake")
        self._connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._disconnect(reachable=True)
        if not self._wait_for_release(RELEASE_WAIT_S):
            log.warning("camera %s: Aravis is still releasing the lost camera after %.0f s",
                        self.camera_id, RELEASE_WAIT_S)

    def _connect(self) -> None:
        device = self.config.device_id
        try:
            camera = Aravis.Camera.new(device)
        except GLib.Error as exc:
            raise DeviceError(
                f"camera {self.camera_id!r}: cannot open Aravis device "
                f"{device or '(first found)'!r}: {exc.message}; check that it is powered and "
                "reachable (arv-tool-0.8 lists cameras), that its id matches, and for GigE that "
                "it is on this host's subnet") from exc
        stream, failure = None, None
        try:
            self._configure(camera)
            stream = camera.create_stream(None, None)
            payload = camera.get_payload()
            for _ in range(self.config.n_buffers):
                stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            camera.start_acquisition()
        except GLib.Error as exc:
            # Only the message is kept: the traceback would hold the camera in its frames.
            failure = exc.message
        if failure is not None:
            # The camera may have gone mid-way: release what was made like a lost camera.
            self._release_later([stream, camera])
            del camera, stream
            raise DeviceError(f"camera {self.camera_id!r}: Aravis device "
                              f"{device or '(first found)'!r} refused its configuration: "
                              f"{failure}; check pixel_format, size and fps in the rig file")
        gv_device = camera.get_device()
        self._camera, self._stream = camera, stream
        self._gv_device = gv_device if isinstance(gv_device, Aravis.GvDevice) else None
        self._last_frame_id = None
        self._last_buffer_mono = time.monotonic()
        self._backoff_s = BACKOFF_START_S
        _, _, width, height = camera.get_region()
        encoding = PIXEL_FORMATS.get(camera.get_pixel_format(), "unsupported")
        fps = camera.get_frame_rate() if camera.is_frame_rate_available() else 0.0
        self._info = DeviceInfo(
            camera_id=self.camera_id, driver="aravis", width=width, height=height,
            encoding=encoding, fps=fps,
            description=f"{camera.get_vendor_name()} {camera.get_model_name()} "
                        f"({camera.get_device_id()})")
        log.info("camera %s: opened %s", self.camera_id, self._info.description)

    def _configure(self, camera) -> None:
        cfg = self.config
        camera.set_pixel_format_from_string(cfg.pixel_format)
        if cfg.width or cfg.height:
            _, _, width, height = camera.get_region()
            camera.set_region(0, 0, cfg.width or width, cfg.height or height)
        if cfg.fps and camera.is_frame_rate_available():
            camera.set_frame_rate(cfg.fps)
        if cfg.exposure_us and camera.is_exposure_time_available():
            camera.set_exposure_time(cfg.exposure_us)
        if cfg.gain_db is not None and camera.is_gain_available():
            camera.set_gain(cfg.gain_db)
        if cfg.packet_size and camera.is_gv_device():
            camera.gv_set_packet_size(cfg.packet_size)

    def _disconnect(self, *, reachable: bool) -> None:
        held = [self._stream, self._camera, self._gv_device]
        self._camera, self._stream, self._gv_device = None, None, None
        if held[1] is None:
            return
        if reachable:
            try:
                held[1].stop_acquisition()
            except GLib.Error as exc:
                log.debug("camera %s: stop_acquisition failed: %s", self.camera_id, exc.message)
            _release_in_order(held)
        else:
            self._release_later(held)

    def _release_later(self, held: list) -> None:
        """Release [stream, camera, ...] in a thread; `held` must hold the last references."""
        self._release = threading.Thread(target=_release_in_order, args=(held,),
                                         name=f"aravis-release-{self.camera_id}", daemon=True)
        self._release.start()

    def _wait_for_release(self, timeout_s: float) -> bool:
        """Wait up to `timeout_s` for a pending release; True when none is left."""
        if self._release is not None:
            self._release.join(max(0.0, timeout_s))
            if self._release.is_alive():
                return False
            self._release = None
        return True

    def _lose(self, why: str) -> None:
        log.warning("camera %s: lost (%s); reconnecting with back-off", self.camera_id, why)
        self._disconnect(reachable=False)
        self._next_attempt_mono = time.monotonic() + self._backoff_s

    def _try_reconnect(self, deadline: float) -> None:
        if not self._wait_for_release(deadline - time.monotonic()):
            raise ReadTimeout(f"camera {self.camera_id!r} is gone; still releasing it")
        now = time.monotonic()
        if now < self._next_attempt_mono:
            time.sleep(max(0.0, min(self._next_attempt_mono, deadline) - now))
            if time.monotonic() < self._next_attempt_mono:
                raise ReadTimeout(f"camera {self.camera_id!r} is gone; next attempt soon")
        try:
            self._connect()
        except DeviceError as exc:
            self._backoff_s = min(self._backoff_s * 2, BACKOFF_MAX_S)
            self._next_attempt_mono = time.monotonic() + self._backoff_s
            log.info("camera %s: reconnection failed (%s); next try in %.1f s", self.camera_id,
                     exc, self._backoff_s)
            raise ReadTimeout(f"camera {self.camera_id!r} is gone") from exc
        self._reconnects += 1
        log.warning("camera %s: reconnected", self.camera_id)

    def read(self, *, timeout_s: float = 1.0) -> Frame:
        seq, timestamp_ns, encoding, image = self._next(timeout_s)
        return Frame(self.camera_id, seq, timestamp_ns, encoding, image)

    def read_into(self, buffer: FrameBuffer, *, timeout_s: float = 1.0) -> tuple[int, int] | Frame:
        return buffer.fill(*self._next(timeout_s))

    def _next(self, timeout_s: float) -> tuple[int, int, str, np.ndarray]:
        """(seq, timestamp_ns, encoding, image) of the next complete frame, reconnecting as needed."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self._camera is None:
                self._try_reconnect(deadline)
            if self._gv_device is not None and not self._gv_device.is_controller():
                self._lose("control lost")
                continue
            remaining_s = deadline - time.monotonic()
            if remaining_s <= 0:
                raise ReadTimeout(f"camera {self.camera_id!r}: no frame in {timeout_s} s")
            buffer = self._stream.timeout_pop_buffer(max(1, int(remaining_s * 1e6)))
            if buffer is None:
                if time.monotonic() - self._last_buffer_mono > self.lost_after_s:
                    self._lose(f"no buffer for {self.lost_after_s} s")
                raise ReadTimeout(f"camera {self.camera_id!r}: no frame in {timeout_s} s")
            self._last_buffer_mono = time.monotonic()
            try:
                captured = self._captured(buffer)
            finally:
                self._stream.push_buffer(buffer)
            if captured is not None:
                return captured

    def _captured(self, buffer) -> tuple[int, int, str, np.ndarray] | None:
        """(seq, timestamp_ns, encoding, image) of the frame in `buffer`, or None (counted as dropped) if
        incomplete."""
        frame_id = buffer.get_frame_id()
        if self._last_frame_id is not None:
            gap = (frame_id - self._last_frame_id - 1) % _FRAME_ID_MODULO
            if 0 < gap < _FRAME_ID_MODULO // 2:
                self._dropped += gap
                self._seq += gap
        self._last_frame_id = frame_id
        if buffer.get_status() != Aravis.BufferStatus.SUCCESS:
            self._dropped += 1
            self._seq += 1
            return None
        encoding = PIXEL_FORMATS.get(buffer.get_image_pixel_format())
        if encoding is None:
            raise DeviceError(f"camera {self.camera_id!r}: pixel format "
                              f"0x{buffer.get_image_pixel_format():08x} is not supported; set "
                              f"pixel_format to one of Mono8, Mono16, RGB8, BGR8, Bayer*8")
        width, height = buffer.get_image_width(), buffer.get_image_height()
        dtype = np.dtype("<u2") if encoding == "mono16" else np.dtype(np.uint8)
        channels = _CHANNELS.get(encoding, 1)
        shape = (height, width, channels) if channels > 1 else (height, width)
        data = buffer.get_data()
        needed = width * height * channels * dtype.itemsize
        if len(data) < needed:
            self._dropped += 1
            self._seq += 1
            return None
        # get_data() already copied the pixels out of the buffer (PyGObject turns the C array
        # into bytes), so the buffer can go back to the pool and the image is a view of them.
        image = np.frombuffer(data, dtype=dtype, count=needed // dtype.itemsize).reshape(shape)
        timestamp_ns = buffer.get_timestamp() or buffer.get_system_timestamp() or time.time_ns()
        seq, self._seq = self._seq, self._seq + 1
        return seq, int(timestamp_ns), encoding, image
