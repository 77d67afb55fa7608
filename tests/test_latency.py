"""Capture-to-calibration latency: the stage times the nodes stamp, and the cheaper parts on its way."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from camnet.drivers.sim import SimCamera
from camnet.services.calibrator import CalibratorNode
from camnet.services.matcher import MatcherNode, MatcherNodeConfig

from camnet.bus import latency
from camnet.bus.frame import Frame
from camnet.bus.sync import FrameSet
from camnet.errors import InputError
from camnet.io import formats
from camnet.io.formats import observations_to_doc, parse_observations
from camnet.io.messages import decode_calibration_message, encode_observations_message
from camnet.io.rig import load_rig, parse_rig
from camnet.sim.render import Quad, Renderer, render_ideal
from camnet.sim.scene import Scene
from camnet.sim.simulate import make_rig, observe
from tests.test_matcher_node import rig_document

ROOT = Path(__file__).resolve().parent.parent


def test_stage_durations_follow_the_stamps_and_skip_the_stages_not_stamped():
    stamps = latency.StageStamps(taken_ns=2_000, detected_ns=3_500, matched_ns=4_000, received_ns=6_000)
    durations = latency.stage_durations_s(stamps, capture_ns=1_000, solved_ns=9_000)
    assert durations == {"taken": 1e-6, "detected": 1.5e-6, "matched": 0.5e-6}
    assert latency.stage_durations_s(latency.StageStamps(), capture_ns=5, solved_ns=None) == {}
    assert latency.StageStamps.from_stages({"pooled": 7, "capture": 1}).by_stage() == {"pooled": 7}


class Recorder:
    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def put(self, payload: bytes, *, attachment: bytes | None = None) -> None:
        self.payloads.append(payload)


def test_every_stage_from_capture_to_calibration_is_stamped_in_order():
    rig = parse_rig(rig_document("stamps"))
    matcher = MatcherNode(None, rig, config=MatcherNodeConfig())  # process() needs no bus
    slot = 40
    cameras = [SimCamera(e.id, e.config, Scene(rig.scene)) for e in rig.cameras]
    frames = {c.camera_id: Frame(c.camera_id, slot, c.slot_timestamp_ns(slot), "mono8", c.render(slot))
              for c in cameras}
    matcher.process(FrameSet(cameras[0].slot_timestamp_ns(slot), frames))
    observations = matcher.message()
    found = {"capture": observations.latest_capture_ns, **observations.latency_ns.by_stage(),
             "published": observations.published_ns}
    assert list(found) == ["capture", *latency.MATCHER_STAGES[1:], "published"]
    assert list(found.values()) == sorted(found.values())

    # The calibrator adds its own to the matcher's; the simulated rig's tracks are replaced by a
    # synthetic rig's, which solves in a moment.
    synthetic = replace(observations, observations=observe(make_rig(n_points=150, seed=3), seed=3).observations)
    calibrator, publisher = CalibratorNode(None, "stamps"), Recorder()
    received_ns = latency.now_ns()
    outcome = calibrator.handle(encode_observations_message(synthetic), publisher, received_ns=received_ns)
    assert outcome is not None and outcome.status == "good"
    published = decode_calibration_message(publisher.payloads[-1])
    stamped = {"capture": published.latest_capture_ns, **published.latency_ns.by_stage(),
               "solved": published.solved_ns}
    assert sorted(stamped, key=latency.STAGES.index) == list(latency.STAGES)
    assert stamped["received"] == received_ns and stamped["published"] == observations.published_ns
    assert [stamped[stage] for stage in latency.STAGES] == sorted(stamped.values())
    durations = latency.stage_durations_s(published.latency_ns, capture_ns=published.latest_capture_ns,
                                          solved_ns=published.solved_ns)
    assert list(durations) == list(latency.STAGES[1:])
    assert sum(durations.values()) == pytest.approx((published.solved_ns - published.latest_capture_ns) / 1e9)


def test_the_kept_background_gives_the_image_drawn_whole():
    rig = load_rig(ROOT / "config" / "sim.yaml")
    scene = Scene(rig.scene)
    camera = rig.camera("mono_a").config.camera("mono_a")
    renderer = Renderer(camera)
    for time_s in (0.0, 2.5, 7.0):
        quads = scene.quads(time_s)
        whole = render_ideal(quads, K=camera.K, R=camera.R, t=camera.t, size=(camera.width, camera.height))
        assert np.array_equal(renderer.render(quads), whole), time_s
    # Another background (new quad objects) is drawn anew, not taken from the one kept.
    wall = scene.background[0]
    darker = Quad(wall.p0, wall.u, wall.v, wall.texture // 2, layer=wall.layer)
    quads = [darker, *scene.quads(7.0)[1:]]
    whole = render_ideal(quads, K=camera.K, R=camera.R, t=camera.t, size=(camera.width, camera.height))
    assert np.array_equal(renderer.render(quads), whole)


def test_simulated_sensor_noise_has_its_sigma_changes_every_frame_and_repeats_for_a_slot():
    rig = load_rig(ROOT / "config" / "sim.yaml")
    entry = rig.camera("left")
    camera = SimCamera(entry.id, entry.config, Scene(rig.scene))
    clean = Renderer(entry.config.camera(entry.id)).render(Scene(rig.scene).quads(10 / entry.config.fps))
    first, again, other = camera.render(10), camera.render(10), camera.render(11)
    assert np.array_equal(first, again)
    inside = (clean > 20) & (clean < 235)  # away from saturation, which clips the noise
    noise = first.astype(float)[inside] - clean[inside]
    assert noise.std() == pytest.approx(entry.config.noise_sigma_dn, rel=0.05) and abs(noise.mean()) < 0.05
    # The next slot's noise is not this one's: the box moved, but the background's pixels differ too.
    assert np.mean(first[:150, :300] != other[:150, :300]) > 0.5


def observations_doc() -> dict:
    return observations_to_doc(observe(make_rig(n_points=60, seed=5), seed=5).observations)


def test_observations_parse_at_once_as_they_do_value_by_value():
    doc = observations_doc()
    cameras = tuple(formats._parse_camera(c, "") for c in doc["cameras"])
    index = {c.id: i for i, c in enumerate(cameras)}
    fast = formats._track_arrays(doc["tracks"], cameras, index)
    checked = formats._checked_track_arrays(doc["tracks"], cameras, index)
    assert fast is not None
    for a, b in zip(fast, checked, strict=True):
        assert a.dtype == b.dtype and np.array_equal(a, b)


@pytest.mark.parametrize("spoil, message", [
    (lambda t: t[3].update(id=True), "tracks[3].id: expected an integer"),
    (lambda t: t[4].update(id=t[2]["id"]), "tracks[4].id: duplicate track id"),
    (lambda t: t[1]["observations"].update(nobody=[1.0, 2.0]), "unknown camera id 'nobody'"),
    (lambda t: t[2]["observations"].update(left=[float("nan"), 2.0]), "expected a finite number"),
    (lambda t: t[2]["observations"].update(left=[1e6, 2.0]), "is outside the camera's"),
    (lambda t: t[2]["observations"].update(left=[1.0, "2"]), "expected a finite number"),
    (lambda t: t[5].update(observations=[]), "expected an object of camera id"),
    (lambda t: t[5].pop("observations"), "tracks[5].observations: missing"),
])
def test_a_bad_track_is_named_as_before(spoil, message):
    doc = observations_doc()
    spoil(doc["tracks"])
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("(", r"\(")):
        parse_observations(doc)
