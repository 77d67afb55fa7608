"""Lockstep replay: a session through the real matcher and calibrator processes twice, the same result.

The session is written with mcap's writer from the sim driver's own renderer
(4 cameras, 640x512, 6 capture instants), with one camera's frames arriving
after the next instant's first frame, as they do on a loaded host.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from camnet.services.replayer import ReplayOptions, StepGrouper

from camnet.bus import keys
from camnet.bus.frame import Frame, encode_frame
from camnet.bus.launch import Launch
from camnet.bus.lockstep import Ack, Step, StepInbox
from camnet.bus.session import BusOptions, open_session
from camnet.io import session_file as sf
from camnet.io.rig import load_rig
from tests.conftest import free_port, wait_for
from tests.test_network import rig_file

ROOT = Path(__file__).resolve().parent.parent
SLOTS = range(20, 26)
# Wall-clock values, different on every run by nature: left out of the comparison.
WALL_CLOCK_KEYS = {
    "calibration": ("solved_ns", "timings_s", "latency_ns"),
    "observations": ("published_ns", "pool_id", "latency_ns"),  # pool_id: a fresh random id per matcher start
}


def write_session(path: Path, rig_path: str) -> int:
    """A session of the rig's sim cameras at `SLOTS`; the number of frames written."""
    from camnet.drivers.sim import create

    rig = load_rig(rig_path)
    cameras = [create(entry, rig) for entry in rig.cameras]
    frames = []
    for slot in SLOTS:
        for camera in cameras:
            timestamp_ns = camera.slot_timestamp_ns(slot)
            frame = Frame(camera.camera_id, slot, timestamp_ns, camera.config.encoding, camera.render(slot))
            frames.append((timestamp_ns, encode_frame(frame), camera.camera_id))
    # The last camera of each instant is late: it arrives after the next instant's first frame.
    n = len(cameras)
    order = []
    for k in range(len(SLOTS)):
        order += frames[k * n: k * n + n - 1]
        if k:
            order.append(frames[k * n - 1])
    order.append(frames[-1])
    write_frames(path, rig.name, order)
    return len(order)


def write_frames(path: Path, rig_name: str, frames: list[tuple[int, bytes, str]]) -> None:
    """A session file of (capture time ns, frame bytes, camera id), in this order, received 1-4 ms after capture."""
    from mcap.writer import Writer

    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile=sf.PROFILE, library="camnet tests")
        schema = writer.register_schema(sf.FRAME_SCHEMA, sf.FRAME_SCHEMA_ENCODING, sf.frame_schema())
        channels = {}
        for k, (timestamp_ns, data, camera_id) in enumerate(frames):
            if camera_id not in channels:
                channels[camera_id] = writer.register_channel(keys.frame(rig_name, camera_id), sf.FRAME_ENCODING,
                                                              schema)
            writer.add_message(channels[camera_id], log_time=timestamp_ns + 1_000_000 * (k % 4 + 1) + k,
                               data=data, publish_time=timestamp_ns)
        writer.finish()


def run_pipeline(tmp_path: Path, rig_path: str, session: Path, name: str) -> dict:
    """Matcher and calibrator processes in lockstep, fed by `camnet replay --lockstep`; what they published."""
    rig_name = load_rig(rig_path).name
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    got: dict[str, list[dict]] = {"observations": [], "calibration": []}
    lock = threading.Lock()

    def collect(kind):
        def on_sample(sample) -> None:
            with lock:
                got[kind].append(json.loads(sample.payload.to_bytes()))
        return on_sample

    run_dir = tmp_path / name
    run_dir.mkdir()
    with open_session(BusOptions(listen=(endpoint,))) as bus, Launch(run_dir) as launch:
        subscribers = [bus.declare_subscriber(keys.observations(rig_name), collect("observations")),
                       bus.declare_subscriber(keys.calibration(rig_name), collect("calibration"))]
        bus_flags = ["--connect", endpoint]
        launch.start("matcher", ["matcher", "--rig", rig_path, "--lockstep", "--publish-period-s", "0.9",
                                 *bus_flags])
        launch.start("calibrator", ["calibrator", "--rig", rig_path, "--no-state", "--lockstep", *bus_flags])
        replay = subprocess.run(
            [sys.executable, "-m", "camnet", "replay", str(session), "--lockstep", "--wait-s", "60",
             "--ack-timeout-s", "60", *bus_flags], cwd=ROOT, capture_output=True, text=True, timeout=150)
        logs = "\n".join(f"--- {c.name}\n{c.log_tail()}" for c in launch.children)
        assert replay.returncode == 0, replay.stdout + replay.stderr + logs
        counts = dict(part.split() for part in
                      next(line for line in replay.stdout.splitlines() if line.startswith("lockstep: "))
                      .removeprefix("lockstep: ").split(", "))
        with lock:
            published = len(got["calibration"])
        assert wait_for(lambda: len(got["calibration"]) >= int(counts.get("good", 0))), (published, counts)
        latest = [json.loads(r.ok.payload.to_bytes()) for r in bus.get(keys.calibration(rig_name), timeout=30)
                  if r.ok]
        for subscriber in subscribers:
            subscriber.undeclare()
    with lock:
        return {"counts": counts, "latest": latest, **{k: list(v) for k, v in got.items()}}


def without(doc: dict, names) -> dict:
    return {k: v for k, v in doc.items() if k not in names}


def test_two_lockstep_replays_give_the_same_calibrations_to_the_last_digit(tmp_path):
    rig_path = rig_file(tmp_path, 4)
    doc = yaml.safe_load(Path(rig_path).read_text())
    fps = 2.0
    for camera in doc["cameras"]:
        camera["sim"]["fps"] = fps
    Path(rig_path).write_text(yaml.safe_dump(doc, sort_keys=False))
    session = tmp_path / "session.mcap"
    n_frames = write_session(session, rig_path)

    runs = [run_pipeline(tmp_path, rig_path, session, f"run{k}") for k in range(2)]
    first, second = runs
    # Every instant went through as one step, plus the final one; the 0.9 s publish period on the capture
    # clock (instants 0.5 s apart) publishes every other step, and the final step what is left.
    assert first["counts"]["steps"] == str(len(SLOTS) + 1), first["counts"]
    assert first["counts"]["observations"] == str(len(SLOTS) // 2 + 1), first["counts"]
    assert int(first["counts"].get("good", 0)) >= 2, first["counts"]
    assert n_frames == 4 * len(SLOTS)
    assert first["counts"] == second["counts"]

    observations = [[without(d, WALL_CLOCK_KEYS["observations"]) for d in run["observations"]] for run in runs]
    assert observations[0] == observations[1]
    assert [d["frame_sets"] for d in first["observations"]] == [1, 3, 5, 6]
    calibrations = [[without(d, WALL_CLOCK_KEYS["calibration"]) for d in run["calibration"]] for run in runs]
    assert len(calibrations[0]) == int(first["counts"]["good"])
    assert calibrations[0] == calibrations[1]  # parsed JSON: every number, to the last digit
    assert [without(d, WALL_CLOCK_KEYS["calibration"]) for d in first["latest"]] == calibrations[0][-1:]
    assert calibrations[0][-1]["latest_capture_ns"] == round(SLOTS[-1] * 1e9 / fps)


def _header(camera_id: str, timestamp_ns: int, seq: int):
    return sf.frame_header(encode_frame(Frame(camera_id, seq, timestamp_ns, "mono8", np.zeros((4, 4), np.uint8))))


def test_step_grouper_forms_one_step_per_instant_whatever_the_arrival_order():
    grouper = StepGrouper(3, tolerance_ns=5_000_000)
    arrivals = [("a", 100), ("b", 101), ("a", 200), ("c", 99), ("b", 200), ("c", 202), ("a", 300), ("b", 300)]
    steps = []
    for seq, (camera, t_ms) in enumerate(arrivals):
        steps += grouper.add(camera, b"", _header(camera, t_ms * 1_000_000, seq))
    assert [[t for t, _, _ in s.frames] for s in steps] == [["a", "b", "c"], ["a", "b", "c"]]
    assert [s.capture_ns for s in steps] == [100_000_000, 200_000_000]
    assert [[t for t, _, _ in s.frames] for s in grouper.flush()] == [["a", "b"]]
    # A camera that misses instants: steps leave once more than `window` are open.
    grouper = StepGrouper(2, tolerance_ns=0, window=2)
    done = [grouper.add("a", b"", _header("a", t, t)) for t in (1, 2, 3, 4)]
    assert [[g.capture_ns for g in d] for d in done] == [[], [], [1], [2]]


def test_lockstep_messages_and_inbox():
    step = Step(3, 42, {"left": 7, "right": 7})
    assert Step.parse(step.to_json()) == step
    assert Ack.parse(Ack(step=3, pool_id="p", frame_sets=2, status="matched").to_json()).frame_sets == 2
    with pytest.raises(Exception, match="lockstep-step"):
        Step.parse(b'{"format": "other"}')
    inbox = StepInbox(capacity=3)
    inbox.add_frame("right", 7, None)  # arrived, unusable
    frames, missing = inbox.take_frames(step, timeout_s=0.05)
    assert frames == {} and missing == ["left"]
    for seq in range(5):
        inbox.add_frame("left", seq, None)
    assert inbox.overflowed == 2


def test_lockstep_options_are_checked():
    with pytest.raises(Exception, match="lockstep"):
        ReplayOptions(rate=1.0, lockstep=True)
    with pytest.raises(Exception, match="include_results"):
        ReplayOptions(rate=0, lockstep=True, include_results=True)
    ReplayOptions(rate=0, lockstep=True)


def test_lockstep_replay_without_the_nodes_fails_in_one_line(tmp_path):
    session = tmp_path / "tiny.mcap"
    image = np.zeros((8, 8), np.uint8)
    write_frames(session, "tiny", [(t, encode_frame(Frame(c, t, t, "mono8", image)), c)
                                   for t in (1, 2) for c in ("left", "right")])
    result = subprocess.run([sys.executable, "-m", "camnet", "replay", str(session), "--lockstep", "--wait-s", "1",
                             "--listen", f"tcp/127.0.0.1:{free_port()}"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith("camnet replay: error: lockstep: no matcher and no calibrator in lockstep on rig tiny")
