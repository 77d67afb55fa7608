"""The matcher node on a real loopback network of simulated cameras, and its command."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import threading
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from camnet.services.matcher import NO_SET_WARNING_S, WARNING_PERIOD_S, HealthWatch, MatcherNode, MatcherNodeConfig
from camnet.services.matcher_config import rig_options

from camnet.bus import keys
from camnet.bus.frame import Frame, encode_frame
from camnet.bus.session import BusOptions, open_session
from camnet.bus.stats import NodeStats
from camnet.bus.sync import FrameSet
from camnet.io.formats import parse_observations
from camnet.io.rig import parse_rig
from camnet.matching.features import Detector, to_8bit, to_grey
from tests._groundtruth import epipolar_distance_px
from tests.conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent
FPS = 4.0
# The paper's rig (config/sim.yaml) at half resolution.
CAMERAS = {
    "left": {"f_px": 750, "centre_m": [0.0, 0.0, 0.0]},
    "right": {"f_px": 750, "centre_m": [0.125, 0.0, 0.0]},
    "mono_a": {"f_px": 650, "centre_m": [-0.30, 0.0, 0.05], "look_at_m": [0.0625, 0.0, 0.65]},
    "mono_b": {"f_px": 700, "centre_m": [0.425, 0.0, 0.05], "look_at_m": [0.0625, 0.0, 0.65]},
}


def rig_document(name: str, *, v4l2_camera: str | None = None) -> dict:
    cameras = []
    for camera_id, geometry in CAMERAS.items():
        if camera_id == v4l2_camera:
            cameras.append({"id": camera_id, "driver": "v4l2", "v4l2": {"source": "unused.mp4"}})
            continue
        sim = {"width": 640, "height": 512, "fps": FPS, "cx_px": 319.5, "cy_px": 255.5, **geometry}
        cameras.append({"id": camera_id, "driver": "sim", "sim": sim})
    return {"rig": name, "stereo": {"left": "left", "right": "right", "baseline_m": 0.125, "parallel": True},
            "scene": {"box_rotation_deg_per_s": 20.0}, "cameras": cameras}


class Network:
    """A matcher node, sim driver nodes and an observer, each on its own loopback session."""

    def __init__(self, rig, config: MatcherNodeConfig, *, start: bool = True) -> None:
        self.rig = rig
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.sessions = [open_session(BusOptions(listen=(endpoint,)))]
        self.matcher_session = self.sessions[0]
        self.drivers_session = open_session(BusOptions(connect=(endpoint,)))
        self.observer = open_session(BusOptions(connect=(endpoint,)))
        self.sessions += [self.drivers_session, self.observer]
        self.node = MatcherNode(self.matcher_session, rig, config=config)
        self.threads = [threading.Thread(target=self.node.run, daemon=True)]
        self.drivers = []
        self.lock = threading.Lock()
        self.documents: list[dict] = []
        self.stats: list[NodeStats] = []
        self.observer.declare_subscriber(keys.observations(rig.name), self._on_observations)
        self.observer.declare_subscriber(keys.node_stats(rig.name, "matcher", "matcher"),
                                         lambda s: self.stats.append(NodeStats.from_json(s.payload.to_bytes())))
        if start:
            self.start_matcher()

    def start_matcher(self) -> None:
        self.threads[0].start()

    def _on_observations(self, sample) -> None:
        with self.lock:
            self.documents.append(json.loads(sample.payload.to_bytes()))

    def start_driver(self, camera_id: str) -> None:
        from camnet.drivers.base import create_camera
        from camnet.drivers.node import DriverNode

        driver = DriverNode(self.drivers_session, self.rig, create_camera(self.rig.camera(camera_id), self.rig))
        thread = threading.Thread(target=driver.run, daemon=True)
        self.drivers.append(driver)
        self.threads.append(thread)
        thread.start()

    def count(self) -> int:
        with self.lock:
            return len(self.documents)

    def progress(self) -> tuple[int, int]:
        """What moves while the matcher works, however slowly (for `wait_for`): frame sets matched,
        observations published."""
        return self.node.engine.stats.frame_sets_matched, self.count()

    def latest(self) -> dict:
        with self.lock:
            return self.documents[-1]

    def close(self) -> None:
        self.node.stop.set()
        for driver in self.drivers:
            driver.stop.set()
        for thread in self.threads:
            if thread.ident is not None:  # started
                thread.join(timeout=30)
        for session in reversed(self.sessions):
            session.close()
        assert not any(t.is_alive() for t in self.threads), "a node thread did not stop"


@pytest.fixture
def network():
    made = []

    def make(rig, config: MatcherNodeConfig, *, start: bool = True) -> Network:
        made.append(Network(rig, config, start=start))
        return made[-1]

    try:
        yield make
    finally:
        for net in made:
            net.close()


def track_uv(doc: dict, camera_ids: list[str]) -> np.ndarray:
    """(T, C, 2) pixels of the document's tracks, NaN where unseen."""
    uv = np.full((len(doc["tracks"]), len(camera_ids), 2), np.nan)
    for k, track in enumerate(doc["tracks"]):
        for c, camera_id in enumerate(camera_ids):
            if camera_id in track["observations"]:
                uv[k, c] = track["observations"][camera_id]
    return uv


def fraction_on_epipolar_lines(uv: np.ndarray, truth: dict, a: int, b: int, ids: list[str], tol_px: float):
    both = np.isfinite(uv[:, a, 0]) & np.isfinite(uv[:, b, 0])
    d = epipolar_distance_px(uv[both, a], uv[both, b], truth[ids[a]], truth[ids[b]])
    return int(both.sum()), float(np.mean(d <= tol_px)) if both.any() else 0.0


def test_live_network_tracks_match_the_ground_truth(network):
    rig = parse_rig(rig_document("mtest"))
    net = network(rig, MatcherNodeConfig(publish_period_s=0.5, max_wait_s=0.3, stats_period_s=0.5))
    # mono_b starts late: frame sets go without it, never stall.
    for camera_id in ("left", "right", "mono_a"):
        net.start_driver(camera_id)
    assert wait_for(lambda: net.count() >= 1, 60.0, progress=net.progress), "no observations from three cameras"
    first = net.latest()
    assert all("mono_b" not in t["observations"] for t in first["tracks"])
    net.start_driver("mono_b")
    assert wait_for(lambda: any("mono_b" in t["observations"] for t in net.latest()["tracks"]), 60.0,
                    progress=net.progress), \
        "mono_b never joined the tracks"
    # A malformed frame and a frame of an unknown camera: counted, and matching goes on.
    net.drivers_session.put(keys.frame(rig.name, "left"), b"CNFR\x01 not a frame")
    stranger = Frame("stranger", 0, 0, "mono8", np.zeros((8, 8), np.uint8))
    net.drivers_session.put(keys.frame(rig.name, "stranger"), encode_frame(stranger))
    # Both refused by the receiver, the stranger from its header before its pixels are decoded.
    assert wait_for(lambda: len(net.node.receiver.malformed.counts) == 2)
    assert net.node.receiver.malformed.counts.get("unknown-camera") == 1
    seen = net.count()
    assert wait_for(lambda: net.count() >= seen + 2, 60.0, progress=net.progress), \
        "observations stopped after a bad frame"

    doc = net.latest()
    obs = parse_observations(doc)  # the camnet.observations/1 contract
    assert [(c["id"], c["width"], c["height"]) for c in doc["cameras"]] == \
        [(c, 640, 512) for c in CAMERAS]
    assert all("K" not in c and "dist" not in c for c in doc["cameras"])  # no ground truth leaks
    assert obs.stereo.baseline_m == 0.125 and doc["rig"] == "mtest"
    assert doc["frame_sets"] >= 3
    assert doc["latest_capture_ns"] % round(1e9 / FPS) == 0  # on the cameras' common slot grid
    assert 0 < doc["published_ns"] - doc["latest_capture_ns"] < 60e9

    ids = list(CAMERAS)
    truth = {e.id: e.config.camera(e.id) for e in rig.cameras}
    uv = track_uv(doc, ids)
    n_stereo, stereo_ok = fraction_on_epipolar_lines(uv, truth, 0, 1, ids, 1.0)
    assert n_stereo >= 300 and stereo_ok > 0.95
    # Rectified pair: same row, positive disparity.
    both = np.isfinite(uv[:, 0, 0]) & np.isfinite(uv[:, 1, 0])
    assert np.mean(np.abs(uv[both, 0, 1] - uv[both, 1, 1]) <= 1.0) > 0.95
    assert np.mean(uv[both, 0, 0] > uv[both, 1, 0]) > 0.95
    # The converging cameras are a little less precise; their pair, seen only through
    # chained tracks, holds a few gross errors (a few percent of pooled tracks off by > 3 px).
    for a, b, min_ok, min_not_gross in ((0, 2, 0.95, 0.97), (1, 2, 0.95, 0.97), (0, 3, 0.95, 0.97),
                                        (1, 3, 0.95, 0.97), (2, 3, 0.90, 0.93)):
        n, ok = fraction_on_epipolar_lines(uv, truth, a, b, ids, 1.5)
        _, not_gross = fraction_on_epipolar_lines(uv, truth, a, b, ids, 3.0)
        assert n >= 50 and ok > min_ok and not_gross > min_not_gross, (ids[a], ids[b], n, ok, not_gross)

    # Statistics for `camnet status`, the liveliness token, and the latest document on query.
    assert wait_for(lambda: net.stats and net.stats[-1].frames >= 3)
    stats = net.stats[-1]
    assert (stats.kind, stats.node_id) == ("matcher", "matcher") and "tracks pooled" in stats.detail
    tokens = list(net.observer.liveliness().get(keys.node(rig.name, "matcher", "matcher"), timeout=30.0))
    assert any(r.ok is not None for r in tokens)
    replies = [r.ok for r in net.observer.get(keys.observations(rig.name), timeout=30.0) if r.ok is not None]
    assert replies and json.loads(replies[0].payload.to_bytes())["format"] == "camnet.observations/1"


def test_cameras_not_triggered_together_form_frame_sets_when_the_rig_file_says_so(network):
    doc = rig_document("freerun")
    for camera in doc["cameras"]:
        camera["sim"]["clock"] = {"free_run": True}  # each on its own phase: 0.23 of a period between the pair
    doc["sync"] = {"free_run": True}
    rig = parse_rig(doc)
    net = network(rig, MatcherNodeConfig(**rig_options(rig), publish_period_s=0.5, max_wait_s=0.3))
    for camera_id in CAMERAS:
        net.start_driver(camera_id)
    assert wait_for(lambda: net.node.sync_counts().complete_sets >= 3, 60.0, progress=net.progress), \
        "no complete frame set of free-running cameras"
    assert wait_for(lambda: net.count() >= 1 and all(
        any(c in t["observations"] for t in net.latest()["tracks"]) for c in CAMERAS), 60.0, progress=net.progress)


def render_set(rig, timestamp_ns: int, camera_ids) -> FrameSet:
    from camnet.drivers.base import create_camera

    slot = timestamp_ns * int(FPS) // 1_000_000_000
    frames = {c: Frame(c, slot, timestamp_ns, "mono8", create_camera(rig.camera(c), rig).render(slot))
              for c in camera_ids}
    return FrameSet(timestamp_ns, frames, tuple(c for c in CAMERAS if c not in frames))


def test_a_camera_of_unknown_size_joins_the_pool_when_it_shows_up():
    sim_rig = parse_rig(rig_document("grow"))
    node_rig = parse_rig(rig_document("grow", v4l2_camera="mono_b"))  # no size in the rig file
    node = MatcherNode(None, node_rig, config=MatcherNodeConfig())  # process() needs no bus
    node.process(render_set(sim_rig, 1_000_000_000, ("left", "right", "mono_a")))
    assert [c.id for c in node.engine.pool.cameras] == ["left", "right", "mono_a"]
    pooled, first_pool_id = len(node.engine.pool), node.message().pool_id
    assert pooled > 100
    node.process(render_set(sim_rig, 3_000_000_000, tuple(CAMERAS)))
    assert [(c.id, c.width) for c in node.engine.pool.cameras] == [(c, 640) for c in CAMERAS]
    assert len(node.engine.pool) > pooled  # the earlier tracks were carried over
    message = node.message()
    assert message.pool_id != first_pool_id  # track ids started over
    assert "mono_b" in message.observations.camera_ids and np.any(
        message.observations.cam_index == message.observations.camera_ids.index("mono_b"))
    assert message.frame_sets == 2 and message.latest_capture_ns == 3_000_000_000


def test_grey_from_every_frame_encoding():
    rng = np.random.default_rng(0)
    small = rng.random((17, 23, 3))
    bgr = (40 + 170 * cv2.resize(small, (92, 68), interpolation=cv2.INTER_CUBIC).clip(0, 1)).astype(np.uint8)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    assert np.array_equal(to_grey(bgr[:, :, ::-1], encoding="rgb8"), grey)
    # A Bayer mosaic keeps one colour per pixel; ROS names the 2x2 pattern from the top-left.
    channel = {"r": 2, "g": 1, "b": 0}
    for pattern in ("rggb", "bggr", "gbrg", "grbg"):
        mosaic = np.empty(bgr.shape[:2], np.uint8)
        for k, colour in enumerate(pattern):
            dy, dx = divmod(k, 2)
            mosaic[dy::2, dx::2] = bgr[dy::2, dx::2, channel[colour]]
        demosaiced = to_grey(mosaic, encoding=f"bayer_{pattern}8").astype(int)
        assert np.abs(demosaiced - grey)[4:-4, 4:-4].mean() < 3, pattern
    grey16 = grey.astype(np.uint16) << 4  # 12-bit data in 16-bit words
    assert np.array_equal(to_grey(grey16, encoding="mono16"), grey16)  # detection decides how 16 bits become 8
    assert np.array_equal(to_8bit(to_grey(grey16, encoding="mono16")), grey)


def camnet(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)


def test_command_help_defaults_and_bad_rigs(tmp_path):
    from dataclasses import fields

    from camnet.cli import build_parser
    from camnet.commands.matcher import node_config_from_args

    result = camnet("matcher", "--help")
    assert result.returncode == 0
    help_text = " ".join(result.stdout.split())
    for field in fields(MatcherNodeConfig):
        flag = "--" + field.name.replace("_", "-")
        assert flag in help_text
        after = help_text.split(flag, 2)[-1].removeprefix(f", --no-{flag[2:]}")  # a boolean flag's negation
        assert f"(default: {field.default}" in after.split(" --")[0], flag
    args = build_parser().parse_args(["matcher", "--rig", "r.yaml", "--detector", "orb", "--max-tracks", "300"])
    assert node_config_from_args(args) == MatcherNodeConfig(detector=Detector.ORB, max_tracks=300)

    bad = tmp_path / "bad.yaml"
    bad.write_text("rig: x\ncameras: []\n")
    result = camnet("matcher", "--rig", str(bad))
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "cameras: expected a non-empty list" in result.stderr
    mono = tmp_path / "mono.yaml"
    doc = rig_document("nostereo")
    del doc["stereo"]
    mono.write_text(json.dumps(doc))
    result = camnet("matcher", "--rig", str(mono))
    assert result.returncode == 2 and "has no stereo pair" in result.stderr
    result = camnet("matcher", "--rig", str(ROOT / "config" / "sim.yaml"), "--max-tracks", "0")
    assert result.returncode == 2 and "max_tracks: must be at least 1" in result.stderr


def test_a_camera_with_too_few_features_is_warned_about_once_then_counted(caplog):
    rig = parse_rig(rig_document("dim"))
    node = MatcherNode(None, rig, config=MatcherNodeConfig(normalise_contrast=False))
    for k in (1, 2):
        frame_set = render_set(rig, k * 1_000_000_000, tuple(CAMERAS))
        dim = frame_set.frames["mono_a"]
        frames = {**frame_set.frames, "mono_a": replace(dim, image=(dim.image // 12).astype(np.uint8))}
        with caplog.at_level(logging.WARNING, logger="camnet.services.matcher"):
            node.process(replace(frame_set, frames=frames))
    warnings = [r.getMessage() for r in caplog.records if "features" in r.getMessage()]
    assert len(warnings) == 1 and "camera 'mono_a'" in warnings[0] and "dark (median grey" in warnings[0]
    assert node.few_features.counts == {"few features: mono_a": 2}


def test_the_worker_warns_of_dropped_frames_once_a_period_and_of_no_frame_set_once_a_stretch():
    watch = HealthWatch(100.0)
    assert watch.dropped_since_warning(0, 100.0) == 0
    assert watch.dropped_since_warning(5, 101.0) == 5
    assert watch.dropped_since_warning(9, 102.0) == 0  # within the period: only counted
    assert watch.dropped_since_warning(12, 101.0 + WARNING_PERIOD_S) == 7  # those since the last warning
    assert watch.silent_s(100.0 + NO_SET_WARNING_S - 1.0) is None
    assert watch.silent_s(100.0 + NO_SET_WARNING_S) == NO_SET_WARNING_S
    assert watch.silent_s(200.0) is None  # said once for this stretch without sets
    watch.frame_set_done(200.0)
    assert watch.silent_s(200.0 + NO_SET_WARNING_S) == NO_SET_WARNING_S
