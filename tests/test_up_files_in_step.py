"""`camnet up` on a rig of video files recorded together: its v4l2 drivers, started one after the other,
stamp frame i of every file alike, and one it restarts after it died rejoins on the same clock."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from camnet.bus import keys
from camnet.bus.receiver import FrameReceiver
from camnet.bus.session import BusOptions
from tests.conftest import free_port, open_patient_session, stop_process, wait_for

FPS = 10.0
PERIOD_NS = int(1e9 / FPS)
RIG = "files"


def write_rig(tmp_path: Path) -> Path:
    """A stereo pair of looping mp4 files of textured frames, as a webcam capture tool writes them."""
    rng = np.random.default_rng(0)
    cameras = []
    for camera_id in ("left", "right"):
        writer = cv2.VideoWriter(str(tmp_path / f"{camera_id}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (96, 64))
        assert writer.isOpened()
        for _ in range(20):
            writer.write(rng.integers(0, 256, size=(64, 96, 3), dtype=np.uint8))
        writer.release()
        cameras.append({"id": camera_id, "driver": "v4l2",
                        "v4l2": {"source": f"{camera_id}.mp4", "loop": True, "encoding": "mono8"}})
    rig = {"rig": RIG, "stereo": {"left": "left", "right": "right", "baseline_m": 0.1}, "cameras": cameras}
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(rig))
    return path


def child_pid(parent: int, camera_id: str) -> int | None:
    """The pid of the driver of `camera_id` among the processes `parent` started."""
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            ppid = int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
            argv = (proc / "cmdline").read_bytes().split(b"\0")
        except (OSError, IndexError, ValueError):
            continue
        if ppid == parent and b"driver" in argv and argv[argv.index(b"--camera") + 1] == camera_id.encode():
            return int(proc.name)
    return None


def gone(pid: int) -> bool:
    try:
        return (Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]) == "Z"
    except OSError:
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the driver's process is found in /proc")
def test_up_plays_the_files_of_a_rig_in_step_and_a_restarted_driver_rejoins(tmp_path):
    rig_path = write_rig(tmp_path)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = subprocess.Popen([sys.executable, "-m", "camnet.cli", "up", str(rig_path), "--forever", "--run-dir",
                           str(tmp_path / "run"), "--listen", endpoint], stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL)
    receiver = FrameReceiver()
    frames: dict[str, list[tuple[int, int]]] = {"left": [], "right": []}  # (seq, timestamp_ns) as received
    lock = threading.Lock()

    def on_frame(sample) -> None:
        frame = receiver.accept(sample.payload.to_bytes())
        if frame is not None:
            with lock:
                frames[frame.camera_id].append((frame.seq, frame.timestamp_ns))

    def count() -> int:
        with lock:
            return sum(map(len, frames.values()))

    def starts(camera_ids=("left", "right")) -> set[int]:
        """Frame 0's instant, from each frame received: one for the whole rig when its files are in step."""
        with lock:
            return {stamp - int(seq * 1e9 / FPS) for c in camera_ids for seq, stamp in frames[c]}

    def logs() -> str:
        return "\n".join(p.read_text()[-1500:] for p in (tmp_path / "run" / "logs").glob("*.log"))

    try:
        with open_patient_session(BusOptions(connect=(endpoint,))) as session:
            session.declare_subscriber(keys.all_frames(RIG), on_frame)
            assert wait_for(lambda: min(len(f) for f in frames.values()) >= 10, 60.0, progress=count), \
                (count(), logs())
            assert len(starts()) == 1, "the drivers' files are not on one clock"

            # A driver that dies is started again by camnet up, on the same clock, at the frame due.
            pid = child_pid(up.pid, "right")
            assert pid is not None
            with lock:
                last_seq = frames["right"][-1][0]
            os.kill(pid, signal.SIGKILL)
            assert wait_for(lambda: gone(pid), 30.0)
            with lock:
                frames["right"].clear()
            assert wait_for(lambda: len(frames["right"]) >= 5, 60.0, progress=count), (count(), logs())
            assert len(starts()) == 1, "the restarted driver left the rig's clock"
            with lock:
                first_seq = frames["right"][0][0]
            assert first_seq > last_seq + FPS * 1.0, (last_seq, first_seq)  # not from frame 0; 1 s back-off
            assert child_pid(up.pid, "right") not in (None, pid)
    finally:
        stop_process(up)
