"""The Aravis driver against Aravis's own GigE Vision camera emulator, and its Fake interface.

The emulator tests run the driver as a real `camnet driver aravis` process
and watch it through Zenoh, so that a crash in Aravis or GLib fails one test,
naming the signal and showing the driver's log, instead of killing pytest.
The emulator listens on the fixed GigE Vision control port of 127.0.0.1, so
one test run at a time may use it: a lock file serializes test runs, and
the tests skip when another process already holds the port.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import free_port, wait_for

EMULATOR = "arv-fake-gv-camera-0.8"
GVCP_PORT = 3956  # GigE Vision control, fixed by the standard
LOCK_FILE = Path(tempfile.gettempdir()) / "camnet-gige-emulator.lock"
ROOT = Path(__file__).resolve().parent.parent
RIG = "gvtest"


def _aravis_missing() -> str | None:
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis  # noqa: F401
    except (ImportError, ValueError) as exc:
        return f"Aravis typelib or PyGObject not installed ({exc})"
    return None


_MISSING = _aravis_missing()
pytestmark = pytest.mark.skipif(_MISSING is not None, reason=_MISSING or "")


def gvcp_port_taken() -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", GVCP_PORT))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return True
            raise
    return False


def start_emulator() -> subprocess.Popen:
    """The emulator on 127.0.0.1, once it holds the control port."""
    process = subprocess.Popen([EMULATOR, "-i", "127.0.0.1"], stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    if not wait_for(lambda: process.poll() is not None or gvcp_port_taken(), 60.0):
        stop(process)
        raise AssertionError(f"{EMULATOR} did not open UDP 127.0.0.1:{GVCP_PORT} within 60 s")
    if process.poll() is not None:
        raise AssertionError(f"{EMULATOR} exited with code {process.returncode} on start")
    return process


def stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.kill()
    process.wait(timeout=10)


@contextlib.contextmanager
def emulator_lock(timeout_s: float = 120.0):
    """Exclusive use of the emulator's port among camnet test runs on this host."""
    with open(LOCK_FILE, "a") as lock:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    pytest.skip(f"another test run held {LOCK_FILE} for {timeout_s:.0f} s")
                time.sleep(0.2)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.fixture
def emulator():
    if shutil.which(EMULATOR) is None:
        pytest.skip(f"{EMULATOR} not installed (Debian package aravis-tools)")
    with emulator_lock():
        if not wait_for(lambda: not gvcp_port_taken(), 10.0, 0.2):
            pytest.skip(f"UDP 127.0.0.1:{GVCP_PORT} (GigE Vision control) is held by another "
                        f"process, e.g. a leftover {EMULATOR}; the emulator tests need it")
        holder = {"process": start_emulator()}
        try:
            yield holder
        finally:
            # Always stopped, whatever the test did (it may have restarted it).
            stop(holder["process"])


def write_rig(directory: Path) -> Path:
    path = directory / "gv.yaml"
    path.write_text(f"rig: {RIG}\n"
                    "cameras:\n"
                    "  - id: gv\n"
                    "    driver: aravis\n"
                    "    aravis: {device_id: 127.0.0.1, pixel_format: Mono8, width: 320, "
                    "height: 240, fps: 50, packet_size: 1400, n_buffers: 8}\n")
    return path


class DriverProcess:
    """`camnet driver aravis` in a child process, its frames received here through Zenoh."""

    def __init__(self, rig_path: Path, log_path: Path) -> None:
        from camnet.bus import keys
        from camnet.bus.receiver import FrameReceiver
        from camnet.bus.session import BusOptions, open_session

        endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.log_path = log_path
        with open(log_path, "w") as log:  # the child keeps its own descriptor
            self.process = subprocess.Popen(
                [sys.executable, "-X", "faulthandler", "-m", "camnet", "-v", "driver", "aravis",
                 "--rig", str(rig_path), "--camera", "gv", "--listen", endpoint,
                 "--stats-period-s", "0.5"],
                cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        self.receiver = FrameReceiver()
        self.frames = []
        self.session = open_session(BusOptions(connect=(endpoint,)))
        self.session.declare_subscriber(keys.frame(RIG, "gv"), self._on_frame)

    def _on_frame(self, sample) -> None:
        frame = self.receiver.accept(sample.payload.to_bytes())
        if frame is not None:
            self.frames.append(frame)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def check_alive(self) -> None:
        code = self.process.poll()
        if code is not None:
            how = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"
            raise AssertionError(f"the driver process died ({how}); its log ends:\n"
                                 f"{self.log()[-3000:]}")

    def wait_for_frames(self, count: int, within_s: float) -> None:
        def enough() -> bool:
            self.check_alive()
            return len(self.frames) >= count

        assert wait_for(enough, within_s, 0.05, progress=lambda: len(self.frames)), (
            f"{len(self.frames)} of {count} frames within {within_s} s; driver log:\n"
            f"{self.log()[-3000:]}")

    def cpu_s(self) -> float:
        """CPU time (user + system) the driver process has used so far."""
        fields = Path(f"/proc/{self.process.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> int:
        """Stop it as `docker stop` would (SIGTERM), killing it if it hangs; its exit code."""
        self.session.close()
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=10)
        return self.process.returncode


@pytest.fixture
def driver_process(tmp_path):
    """A factory of driver processes; every one is stopped at the end, even on failure."""
    started = []

    def start() -> DriverProcess:
        driver = DriverProcess(write_rig(tmp_path), tmp_path / f"driver{len(started)}.log")
        started.append(driver)
        return driver

    try:
        yield start
    finally:
        for driver in started:
            driver.stop()


def test_streams_from_emulator(emulator, driver_process):
    driver = driver_process()
    driver.wait_for_frames(10, 120.0)
    frames = list(driver.frames)
    assert all(f.image.shape == (240, 320) and f.encoding == "mono8" for f in frames)
    assert [f.seq for f in frames] == sorted(f.seq for f in frames)
    assert all(f.timestamp_ns > 0 for f in frames)
    assert frames[-1].timestamp_ns > frames[0].timestamp_ns
    # The emulator's test pattern is not blank.
    assert frames[-1].image.std() > 1
    assert driver.receiver.malformed.total == 0
    assert driver.stop() == 0, driver.log()


def test_survives_emulator_kill_and_restart(emulator, driver_process):
    driver = driver_process()
    driver.wait_for_frames(5, 120.0)
    stop(emulator["process"])
    cpu_start_s, wall_start_s = driver.cpu_s(), time.monotonic()
    # The driver notices the loss (no buffer for 2 s; later on a loaded machine) and waits to reconnect:
    # its CPU is measured over at least 4 s of that.
    assert wait_for(lambda: (driver.check_alive(), "camera gv: lost" in driver.log())[1], 120.0, 0.1), \
        driver.log()[-3000:]
    time.sleep(max(0.0, wall_start_s + 4.0 - time.monotonic()))
    driver.check_alive()
    cpu_fraction = (driver.cpu_s() - cpu_start_s) / (time.monotonic() - wall_start_s)
    assert cpu_fraction < 0.2, f"waiting for the camera used {cpu_fraction:.0%} CPU"
    assert "camera gv: lost" in driver.log()
    before = len(driver.frames)
    emulator["process"] = start_emulator()
    driver.wait_for_frames(before + 5, 120.0)
    log = driver.log()
    assert log.count("camera gv: reconnected") == 1, log
    counts = driver.receiver.counts()["gv"]
    assert counts.restarts == 0, "sequence numbers went back after reconnecting"
    assert driver.frames[-1].image.shape == (240, 320)
    assert driver.stop() == 0, driver.log()


def config(**overrides):
    from camnet.io.rig import AravisConfig

    values = dict(device_id="127.0.0.1", pixel_format="Mono8", width=None, height=None,
                  fps=50.0, exposure_us=None, gain_db=None, packet_size=1400, n_buffers=8,
                  enable_fake_interface=False)
    values.update(overrides)
    return AravisConfig(**values)


def test_unknown_device_error_names_camera_and_hint():
    from camnet.drivers.aravis import AravisCamera
    from camnet.drivers.base import DeviceError

    with pytest.raises(DeviceError, match="camera 'ghost'.*Nope-0000.*check"):
        AravisCamera("ghost", config(device_id="Nope-0000")).__enter__()


def test_in_process_fake_interface():
    from camnet.drivers.aravis import AravisCamera

    cfg = config(device_id="Fake_1", enable_fake_interface=True, packet_size=None, fps=None)
    with AravisCamera("fake", cfg) as cam:
        frames, copies = [], []
        for _ in range(3 * cfg.n_buffers):  # every buffer of the pool goes round more than once
            frames.append(cam.read(timeout_s=2.0))
            copies.append(frames[-1].image.copy())
    assert frames[0].encoding == "mono8" and frames[0].image.shape == (cam.info.height,
                                                                        cam.info.width)
    assert frames[2].seq > frames[0].seq
    # A frame's pixels are its own: the Aravis buffer they came from is reused.
    assert all(np.array_equal(f.image, c) for f, c in zip(frames, copies, strict=True))
    assert not np.array_equal(frames[0].image, frames[1].image)  # the fake pattern moves


def test_in_process_fake_camera_reads_into_the_node_buffer():
    """read_into: the pixels in the node's buffer and only (seq, timestamp) back; a buffer of another size
    gets the frame as a Frame of its own."""
    from camnet.drivers.aravis import AravisCamera

    from camnet.bus.frame import Frame, FrameBuffer, decode_frame

    cfg = config(device_id="Fake_1", enable_fake_interface=True, packet_size=None, fps=None)
    with AravisCamera("fake", cfg) as cam:
        first = cam.read(timeout_s=2.0)
        buffer = FrameBuffer.like(first)
        messages = []
        for _ in range(2 * cfg.n_buffers):  # every buffer of Aravis's pool goes round
            got = cam.read_into(buffer, timeout_s=2.0)
            assert isinstance(got, tuple), got
            messages.append(bytes(buffer.stamp(*got)))
        other = cam.read_into(FrameBuffer("fake", "mono8", (8, 8)), timeout_s=2.0)
    frames = [decode_frame(message) for message in messages]
    assert all(f.encoding == "mono8" and f.image.shape == first.image.shape for f in frames)
    seqs = [f.seq for f in frames]
    assert seqs[0] > first.seq and seqs == sorted(set(seqs))
    assert not np.array_equal(frames[0].image, frames[1].image)  # the fake pattern moves
    assert isinstance(other, Frame) and other.seq > seqs[-1] and other.image.shape == first.image.shape


def test_refused_configuration_names_camera_and_setting():
    from camnet.drivers.aravis import AravisCamera
    from camnet.drivers.base import DeviceError

    cfg = config(device_id="Fake_1", enable_fake_interface=True, packet_size=None, fps=None,
                 pixel_format="Mono9000")
    with pytest.raises(DeviceError, match="camera 'fake'.*refused its configuration.*Mono9000"
                                          ".*check pixel_format"):
        AravisCamera("fake", cfg).__enter__()
