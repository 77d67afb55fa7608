"""`camnet driver sim` as a real process, with one camera or several; a subscriber and `camnet status`
see it."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from camnet.bus import keys
from camnet.bus.features_wire import decode_features
from camnet.bus.receiver import FrameReceiver
from camnet.bus.session import BusOptions, open_session
from camnet.io.rig import load_rig
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
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
    _, err = process.communicate(timeout=60)
    return err


def test_sim_driver_process_publishes_frames_groundtruth_and_status():
    from camnet.drivers.node import RATE_WINDOW_S

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    driver = camnet("driver", "sim", "--rig", str(RIG), "--camera", "mono_a", "--listen",
                    endpoint, "--stats-period-s", "0.5")
    try:
        receiver = FrameReceiver()
        frames = []

        def on_frame(sample) -> None:
            frames.append(receiver.accept(sample.payload.to_bytes()))

        with open_session(BusOptions(connect=(endpoint,))) as session:
            session.declare_subscriber(keys.frame("sim", "mono_a"), on_frame)
            assert wait_for(lambda: len(frames) >= 10, 120.0, progress=lambda: len(frames)), stop(driver)
            frame = frames[-1]
            assert (frame.camera_id, frame.encoding, frame.image.shape) == \
                ("mono_a", "mono8", (1024, 1280))
            assert frame.image.std() > 20
            assert receiver.malformed.total == 0
            seqs = [f.seq for f in frames[:10]]
            assert seqs == sorted(seqs)
            replies = list(session.get(keys.groundtruth("sim"), timeout=30.0))
            truth = json.loads(replies[0].ok.payload.to_bytes())
            cams = {c["id"]: c for c in truth["cameras"]}
            assert truth["world_frame"] == "left" and len(cams) == 4
            assert np.allclose(cams["mono_a"]["K"][0][0], 1300)
            received_before_asking = len(frames)
            status = subprocess.run(
                [sys.executable, "-m", "camnet", "status", "--rig", "sim", "--connect", endpoint,
                 "--wait-s", "5"], cwd=ROOT, capture_output=True, text=True, timeout=120)
            assert status.returncode == 0, status.stderr
            line = next(row for row in status.stdout.splitlines() if "mono_a" in row)
            kind, node_id, fps, dropped, sent = line.split()[:5]
            assert (kind, node_id) == ("driver", "mono_a")
            # Bounds that hold however loaded the machine, not rates over two windows compared: the
            # driver reports after it puts a frame, and status hears only reports made after it was
            # asked, so they count every frame that had arrived here by then; and the rate is of
            # frames sent over its last RATE_WINDOW_S or more, at least that last frame, and never
            # above the camera's (a simulated camera skips the slots it is late for).
            assert int(sent) >= received_before_asking > 0, (line, received_before_asking)
            camera_fps = load_rig(RIG).camera("mono_a").config.fps
            assert 0 < float(fps) <= camera_fps + 1 / RATE_WINDOW_S and int(dropped) >= 0, line
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


def test_driver_refuses_a_files_start_for_a_driver_that_plays_no_files():
    result = subprocess.run(
        [sys.executable, "-m", "camnet", "driver", "sim", "--rig", str(RIG), "--camera", "left",
         "--files-start-ns", "1"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert "--files-start-ns: only the v4l2 driver plays files, not 'sim'" in result.stderr, result.stderr


def small_rig(path: Path, *, side_px: int = 320, fps: float = 5.0, name: str = "sim") -> Path:
    """config/sim.yaml at `side_px` wide and `fps`, named `name`, written to `path`."""
    rig = yaml.safe_load(RIG.read_text())
    rig["rig"] = name
    scale = side_px / 1280
    for camera in rig["cameras"]:
        sim = camera["sim"]
        sim.update(width=side_px, height=round(1024 * scale), fps=fps, f_px=sim["f_px"] * scale,
                   cx_px=(side_px - 1) / 2, cy_px=(round(1024 * scale) - 1) / 2)
    path.write_text(yaml.safe_dump(rig))
    return path


def test_one_driver_process_runs_several_cameras_with_their_feature_stages(tmp_path):
    """A camera host: three cameras of the rig in one process, each publishing frames and features."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cameras = ("left", "mono_a", "mono_b")
    rig = small_rig(tmp_path / "rig.yaml")
    driver = camnet("driver", "sim", "--rig", str(rig), *[a for c in cameras for a in ("--camera", c)],
                    "--features", "--features-period-s", "0.5", "--listen", endpoint, "--stats-period-s", "0.5")
    try:
        receiver = FrameReceiver()
        frames: dict[str, list[int]] = {c: [] for c in cameras}
        features: dict[str, list[int]] = {c: [] for c in cameras}

        def on_frame(sample) -> None:
            frame = receiver.accept(sample.payload.to_bytes())
            frames[frame.camera_id].append(frame.seq)

        def on_features(sample) -> None:
            message = decode_features(sample.payload.to_bytes())
            features[message.camera_id].append(len(message.uv))

        with open_session(BusOptions(connect=(endpoint,))) as session:
            session.declare_subscriber(keys.all_frames("sim"), on_frame)
            session.declare_subscriber(keys.all_features("sim"), on_features)
            # Progress, not a fixed delay: every camera's frames and features arrive, in order.
            assert wait_for(lambda: all(len(frames[c]) >= 5 and len(features[c]) >= 2 for c in cameras), 120.0,
                            progress=lambda: sum(map(len, frames.values())) + sum(map(len, features.values()))), \
                ({c: len(f) for c, f in frames.items()}, {c: len(f) for c, f in features.items()}, stop(driver))
            assert set(frames) == set(cameras) and receiver.malformed.total == 0
            assert all(seqs == sorted(seqs) for seqs in frames.values())
            assert all(min(n) > 20 for n in features.values()), features
            nodes = {str(reply.ok.key_expr) for reply in session.liveliness().get(keys.all_nodes("sim"), timeout=30.0)
                     if reply.ok is not None}
            assert nodes == {keys.node("sim", "driver", c) for c in cameras}, nodes
    finally:
        err = stop(driver)
    assert driver.returncode == 0, err  # SIGTERM stops every camera and the process cleanly


def os_thread_names(pid: int) -> set[str]:
    names = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):  # the thread ended
            names.add((task / "comm").read_text().strip())
    return names


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="thread names are read from /proc")
def test_a_camera_hosts_feature_stages_slow_to_the_matchers_pace(tmp_path):
    """A matcher that reports no frame set matched for two windows: the host's stages then detect only on
    every 8th point of their 0.5 s grid (capture times on multiples of 4 s). Its threads carry their names
    in the operating system, where a benchmark reads each one's CPU time."""
    from camnet.services.features import MAX_PACE_LEVEL, PACE_WINDOW_S

    from camnet.bus.stats import NodeStats
    from tests.conftest import matched_publisher

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cameras = ("left", "mono_a")
    driver = camnet("driver", "sim", "--rig", str(small_rig(tmp_path / "rig.yaml")),
                    *[a for c in cameras for a in ("--camera", c)], "--features", "--features-period-s", "0.5",
                    "--listen", endpoint)
    try:
        stamps: dict[str, list[int]] = {c: [] for c in cameras}

        def on_features(sample) -> None:
            message = decode_features(sample.payload.to_bytes())
            stamps[message.camera_id].append(message.timestamp_ns)

        with open_session(BusOptions(connect=(endpoint,))) as session:
            session.declare_subscriber(keys.all_features("sim"), on_features)
            assert wait_for(lambda: all(len(stamps[c]) >= 2 for c in cameras), 120.0), (stamps, stop(driver))
            reports = matched_publisher(session, keys.node_stats("sim", "matcher", "matcher"), timeout_s=30.0)
            # Reports of their own stamps: the pace goes by them, not by when they arrive.
            for t_s in range(round(3 * PACE_WINDOW_S) + 1):
                reports.put(NodeStats(rig="sim", kind="matcher", node_id="matcher", fps=0.0, frames=0, dropped=0,
                                      timestamp_ns=t_s * 1_000_000_000).to_json())
            # One stage may have a detection under way when the pace changes: three more each, the last two paced.
            seen = {c: len(stamps[c]) for c in cameras}
            assert wait_for(lambda: all(len(stamps[c]) >= seen[c] + 3 for c in cameras), 120.0), (stamps, stop(driver))
            period_ns = 500_000_000 << MAX_PACE_LEVEL
            assert all(t % period_ns == 0 for c in cameras for t in stamps[c][-2:]), stamps
            names = os_thread_names(driver.pid)
            assert {f"{prefix}-{c}"[:15] for prefix in ("driver", "features") for c in cameras} <= names, names
    finally:
        err = stop(driver)
    assert driver.returncode == 0, err


@pytest.mark.parametrize(("cameras", "message"), [
    (("left", "mono_a", "left"), "--camera: a camera given twice"),
    (("left", "nope"), "nope"),
])
def test_driver_refuses_a_bad_list_of_cameras(tmp_path, cameras, message):
    result = subprocess.run([sys.executable, "-m", "camnet", "driver", "sim", "--rig", str(RIG),
                             *[a for c in cameras for a in ("--camera", c)]],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and message in result.stderr, result.stderr


class FailingCamera:
    """A driver node whose camera fails after `fail_after_s` (None: runs until stopped)."""

    def __init__(self, camera_id: str, fail_after_s: float | None) -> None:
        import threading

        self.camera_id, self.fail_after_s = camera_id, fail_after_s
        self.stop = threading.Event()
        self.stopped = False

    def run(self, *, max_frames: int = 0) -> int:
        if self.stop.wait(self.fail_after_s if self.fail_after_s is not None else 60.0):
            self.stopped = True
            return 0
        raise OSError(f"camera {self.camera_id} unplugged")


def test_a_failing_camera_stops_the_other_cameras_of_its_process():
    from camnet.drivers.node import run_together

    nodes = [FailingCamera("a", None), FailingCamera("b", 0.3), FailingCamera("c", None)]
    with pytest.raises(OSError, match="camera b unplugged"):
        run_together(nodes)
    # Stopped, not failed by themselves 60 s on: no clock needed to tell the two apart.
    assert nodes[0].stopped and nodes[2].stopped


def test_router_relays_between_peers():
    port = free_port()
    router = camnet("router", "--listen", f"tcp/127.0.0.1:{port}")
    try:
        endpoint = f"tcp/127.0.0.1:{port}"
        got = []
        # The peers keep trying to connect until the router listens: wait for both to reach it.
        with open_session(BusOptions(connect=(endpoint,))) as a, \
                open_session(BusOptions(connect=(endpoint,))) as b:
            assert wait_for(lambda: list(a.info.routers_zid()) and list(b.info.routers_zid()), 120.0), \
                "the peers never reached the router"
            b.declare_subscriber(keys.observations("r"), lambda s: got.append(1))
            assert wait_for(lambda: (a.put(keys.observations("r"), b"x"), len(got) > 0)[1], 60.0, 0.1)
    finally:
        stop(router)
    assert router.returncode == 0  # SIGTERM ends it cleanly
