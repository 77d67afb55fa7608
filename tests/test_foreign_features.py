"""Features of a camera from another publisher than its stage: counted, named in `camnet status`, ignored.

On loopback Zenoh: mono_a's stage runs beside its driver as `camnet driver --features` runs it (declared,
stating its session as the source), the other cameras send frames; a stranger on its own session publishes
well-formed features for mono_a (stating its own source) and for mono_b (which has no stage, stating none).
"""

from __future__ import annotations

import threading

import numpy as np
from camnet.services.features import FeatureStageConfig, FeatureWorker
from camnet.services.matcher import MatcherNodeConfig

from camnet.bus import keys
from camnet.bus.features_wire import FeaturesMessage, encode_features
from camnet.bus.source import SourcedPublisher, declare_stage
from camnet.commands.status import suspicious
from camnet.io.rig import parse_rig
from tests.conftest import wait_for
from tests.test_matcher_node import CAMERAS, network, rig_document  # noqa: F401 (the fixture)

FORGED_PERIOD_S = 0.5


def forged(camera_id: str, n: int) -> bytes:
    """Well-formed features of `camera_id`, stamped long ago: never in a set of the real cameras."""
    rng = np.random.default_rng(n)
    return encode_features(FeaturesMessage(camera_id, n, (n + 1) * 200_000_000, 640, 512, "sift", 0, 0,
                                           rng.random((50, 2)) * 500, rng.integers(0, 256, (50, 128), np.uint8)))


class Stranger:
    """Puts forged features of each camera of `publishers` every `FORGED_PERIOD_S` on a thread, until closed."""

    def __init__(self, publishers: dict) -> None:
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(publishers,), daemon=True)
        self._thread.start()

    def _run(self, publishers: dict) -> None:
        while not self._stop.wait(FORGED_PERIOD_S):
            for camera_id, publisher in publishers.items():
                publisher.put(forged(camera_id, self.sent))
            self.sent += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=30)


def test_a_strangers_features_neither_feed_the_matcher_nor_silence_a_camera(network):  # noqa: F811 (the fixture)
    from camnet.drivers.base import create_camera
    from camnet.drivers.node import DriverNode

    rig = parse_rig(rig_document("forged"))
    net = network(rig, MatcherNodeConfig(publish_period_s=0.5, max_wait_s=0.3, stats_period_s=0.5))
    sets: list[tuple[str, ...]] = []  # the cameras of each frame set the engine matched
    process = net.node.engine.process
    net.node.engine.process = lambda items: (sets.append(tuple(i.camera_id for i in items)), process(items))[1]
    stage = declare_stage(net.drivers_session, rig.name, "mono_a")
    worker = FeatureWorker(SourcedPublisher(net.drivers_session.declare_publisher(keys.features(rig.name, "mono_a"))),
                           "mono_a", FeatureStageConfig(period_s=0.5)).__enter__()
    for camera_id in CAMERAS:
        driver = DriverNode(net.drivers_session, rig, create_camera(rig.camera(camera_id), rig),
                            on_frame=worker.offer if camera_id == "mono_a" else None)
        net.drivers.append(driver)
        net.threads.append(threading.Thread(target=driver.run, daemon=True))
        net.threads[-1].start()
    stranger = None
    try:
        assert wait_for(lambda: net.node.frames.feature_cameras == {"mono_a"}, 120.0, progress=net.progress), \
            "mono_a's stage never fed the matcher"
        stranger = Stranger({"mono_a": SourcedPublisher(net.observer.declare_publisher(keys.features(rig.name,
                                                                                                      "mono_a"))),
                             "mono_b": net.observer.declare_publisher(keys.features(rig.name, "mono_b"))})
        assert wait_for(lambda: stranger.sent >= 4, 60.0)
        before = len(sets)
        # Sets formed while the stranger publishes: mono_a's features and mono_b's frames are in them.
        assert wait_for(lambda: sum("mono_a" in s for s in sets[before:]) >= 3
                        and sum("mono_b" in s for s in sets[before:]) >= 3, 120.0, progress=net.progress,
                        limit_s=300.0), \
            sets[before:]
        foreign = net.node.foreign.counts
        assert foreign.get("foreign features: mono_a", 0) > 0 and foreign.get("foreign features: mono_b", 0) > 0, \
            foreign
        # mono_a's features are still its stage's; mono_b still sends frames, not features.
        assert net.node.frames.feature_cameras == {"mono_a"}
        assert net.node.frames.stage_source("mono_a") == str(net.drivers_session.info.zid())
        # The counts go out in the matcher's statistics, and `camnet status` names the cameras.
        assert wait_for(lambda: net.stats and "foreign features: mono_b" in net.stats[-1].faults, 60.0)
        lines = suspicious([("matcher", "matcher")], {("matcher", "matcher"): net.stats[-1]})
        assert any(line.startswith("camera mono_a: ") and "another publisher" in line for line in lines), lines
        assert any(line.startswith("camera mono_b: ") and "another publisher" in line for line in lines), lines
    finally:
        if stranger is not None:
            stranger.close()
        for driver in net.drivers:
            driver.stop.set()
        worker.__exit__(None, None, None)
        stage.undeclare()


def test_a_stage_that_leaves_lets_the_next_one_in(network):  # noqa: F811 (the fixture)
    """A restarted stage is a new session: once the old one's token is gone, its features are taken."""
    rig = parse_rig(rig_document("restage"))
    net = network(rig, MatcherNodeConfig(stats_period_s=0.5))
    frames = net.node.frames
    old, new = net.drivers_session, net.observer
    stage = declare_stage(old, rig.name, "mono_b")
    assert wait_for(lambda: "mono_b" in frames.declared_cameras, 60.0)
    publishers = {s: SourcedPublisher(s.declare_publisher(keys.features(rig.name, "mono_b"))) for s in (old, new)}
    publishers[old].put(forged("mono_b", 0))
    assert wait_for(lambda: frames.stage_source("mono_b") == str(old.info.zid()), 60.0)
    publishers[new].put(forged("mono_b", 1))
    assert wait_for(lambda: net.node.foreign.counts.get("foreign features: mono_b") == 1, 60.0)
    stage.undeclare()  # the old stage leaves; the new one declares itself
    assert wait_for(lambda: "mono_b" not in frames.declared_cameras and frames.feature_cameras == frozenset(), 60.0)
    restarted = declare_stage(new, rig.name, "mono_b")  # kept: a token dropped is undeclared
    assert wait_for(lambda: "mono_b" in frames.declared_cameras, 60.0)
    publishers[new].put(forged("mono_b", 2))
    assert wait_for(lambda: frames.stage_source("mono_b") == str(new.info.zid()), 60.0)
    assert net.node.foreign.counts == {"foreign features: mono_b": 1}
    restarted.undeclare()
