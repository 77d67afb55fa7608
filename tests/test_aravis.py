"""The Aravis driver against Aravis's own GigE Vision camera emulator, and its Fake interface."""

from __future__ import annotations

import shutil
import subprocess
import time

import pytest

EMULATOR = "arv-fake-gv-camera-0.8"


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


def start_emulator() -> subprocess.Popen:
    process = subprocess.Popen([EMULATOR, "-i", "127.0.0.1"], stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    time.sleep(0.3)  # lets it bind its GVCP port
    return process


def stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.kill()
    process.wait(timeout=10)


@pytest.fixture
def emulator():
    if shutil.which(EMULATOR) is None:
        pytest.skip(f"{EMULATOR} not installed (Debian package aravis-tools)")
    holder = {"process": start_emulator()}
    try:
        yield holder
    finally:
        # Always stopped, whatever the test did (it may have restarted it).
        stop(holder["process"])


def config(**overrides):
    from camnet.rig import AravisConfig

    values = dict(device_id="127.0.0.1", pixel_format="Mono8", width=None, height=None,
                  fps=50.0, exposure_us=None, gain_db=None, packet_size=1400, n_buffers=8,
                  enable_fake_interface=False)
    values.update(overrides)
    return AravisConfig(**values)


def read_until_frame(cam, within_s: float):
    from drivers.base import ReadTimeout

    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            return cam.read(timeout_s=0.5)
        except ReadTimeout:
            continue
    raise AssertionError(f"no frame within {within_s} s")


def test_streams_from_emulator(emulator):
    from drivers.aravis import AravisCamera

    with AravisCamera("gv", config(width=320, height=240)) as cam:
        frames = [cam.read(timeout_s=2.0) for _ in range(10)]
        assert cam.info.encoding == "mono8"
    assert all(f.image.shape == (240, 320) and f.encoding == "mono8" for f in frames)
    assert [f.seq for f in frames] == sorted(f.seq for f in frames)
    assert all(f.timestamp_ns > 0 for f in frames)
    assert frames[-1].timestamp_ns > frames[0].timestamp_ns
    # The emulator's test pattern is not blank.
    assert frames[-1].image.std() > 1


def test_survives_emulator_kill_and_restart(emulator):
    from drivers.aravis import AravisCamera
    from drivers.base import ReadTimeout

    with AravisCamera("gv", config(), lost_after_s=1.0) as cam:
        read_until_frame(cam, 5.0)
        stop(emulator["process"])
        cpu_start_s, wall_start_s = time.process_time(), time.monotonic()
        timeouts = 0
        while time.monotonic() - wall_start_s < 3.0:
            try:
                cam.read(timeout_s=0.3)
            except ReadTimeout:
                timeouts += 1
        cpu_fraction = (time.process_time() - cpu_start_s) / (time.monotonic() - wall_start_s)
        assert timeouts > 0 and not cam.connected
        assert cpu_fraction < 0.2, f"waiting for the camera used {cpu_fraction:.0%} CPU"
        emulator["process"] = start_emulator()
        frame = read_until_frame(cam, 20.0)
        assert cam.reconnects == 1 and cam.connected
        assert frame.image.shape == (cam.info.height, cam.info.width)


def test_unknown_device_error_names_camera_and_hint():
    from drivers.aravis import AravisCamera
    from drivers.base import DeviceError

    with pytest.raises(DeviceError, match="camera 'ghost'.*Nope-0000.*check"):
        AravisCamera("ghost", config(device_id="Nope-0000")).__enter__()


def test_in_process_fake_interface():
    from drivers.aravis import AravisCamera

    cfg = config(device_id="Fake_1", enable_fake_interface=True, packet_size=None, fps=None)
    with AravisCamera("fake", cfg) as cam:
        frames = [cam.read(timeout_s=2.0) for _ in range(3)]
    assert frames[0].encoding == "mono8" and frames[0].image.shape == (cam.info.height,
                                                                        cam.info.width)
    assert frames[2].seq > frames[0].seq
