"""`camnet driver sim` as a real process; a subscriber and `camnet status` see it."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from camnet.bus import keys
from camnet.bus.receiver import FrameReceiver
from camnet.bus.session import BusOptions, open_session
from tests.conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "config" / "sim.yaml"


def camnet(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "camnet", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


def stop(process: subprocess.Popen) -> str:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
    _, err = process.communicate(timeout=10)
    return err


def test_sim_driver_process_publishes_frames_groundtruth_and_status():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    driver = camnet("driver", "sim", "--rig", str(RIG), "--camera", "mono_a", "--listen",
                    endpoint, "--stats-period-s", "0.5")
    try:
        receiver = FrameReceiver()
        frames, arrivals_s = [], []

        def on_frame(sample) -> None:
            frames.append(receiver.accept(sample.payload.to_bytes()))
            arrivals_s.append(time.monotonic())

        with open_session(BusOptions(connect=(endpoint,))) as session:
            session.declare_subscriber(keys.frame("sim", "mono_a"), on_frame)
            assert wait_for(lambda: len(frames) >= 10, 30.0), stop(driver)
            frame = frames[-1]
            assert (frame.camera_id, frame.encoding, frame.image.shape) == \
                ("mono_a", "mono8", (1024, 1280))
            assert frame.image.std() > 20
            assert receiver.malformed.total == 0
            seqs = [f.seq for f in frames[:10]]
            assert seqs == sorted(seqs)
            replies = list(session.get(keys.groundtruth("sim"), timeout=5.0))
            truth = json.loads(replies[0].ok.payload.to_bytes())
            cams = {c["id"]: c for c in truth["cameras"]}
            assert truth["world_frame"] == "left" and len(cams) == 4
            assert np.allclose(cams["mono_a"]["K"][0][0], 1300)
            status = subprocess.run(
                [sys.executable, "-m", "camnet", "status", "--rig", "sim", "--connect", endpoint,
                 "--wait-s", "1.5"], cwd=ROOT, capture_output=True, text=True, timeout=30)
            assert status.returncode == 0, status.stderr
            line = next(row for row in status.stdout.splitlines() if "mono_a" in row)
            kind, node_id, fps, dropped = line.split()[:4]
            assert (kind, node_id) == ("driver", "mono_a")
            # The rate it reports is the rate that arrives here; on a loaded machine both fall together.
            now_s = time.monotonic()
            received_fps = sum(t > now_s - 2.0 for t in arrivals_s) / 2.0
            assert float(fps) > 0.5 * received_fps > 0 and int(dropped) >= 0
    finally:
        err = stop(driver)
    assert driver.returncode == 0, err
    # At the default log level, the driver says what it did (at least on leaving), in one line.
    status = [line for line in err.splitlines() if "camnet.status: driver mono_a: " in line]
    assert status and "frames sent" in status[-1] and "dropped by the camera" in status[-1], err


def test_driver_refuses_wrong_driver_for_camera():
    result = subprocess.run(
        [sys.executable, "-m", "camnet", "driver", "v4l2", "--rig", str(RIG), "--camera", "left"],
        cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert result.returncode == 2
    assert "camera 'left' uses driver 'sim', not 'v4l2'" in result.stderr


def test_router_relays_between_peers():
    port = free_port()
    router = camnet("router", "--listen", f"tcp/127.0.0.1:{port}")
    try:
        endpoint = f"tcp/127.0.0.1:{port}"
        got = []
        time.sleep(1.0)
        with open_session(BusOptions(connect=(endpoint,))) as a, \
                open_session(BusOptions(connect=(endpoint,))) as b:
            b.declare_subscriber(keys.observations("r"), lambda s: got.append(1))
            assert wait_for(lambda: (a.put(keys.observations("r"), b"x"), len(got) > 0)[1], 10.0)
    finally:
        stop(router)
    assert router.returncode == 0  # SIGTERM ends it cleanly
