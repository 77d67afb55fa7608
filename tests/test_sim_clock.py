"""Simulated cameras with clocks of their own: when they expose, what they stamp, what they show."""

from __future__ import annotations

import copy
import time
from fractions import Fraction

import numpy as np
import pytest
from camnet.drivers.sim import SimCamera, groundtruth_document

from camnet.errors import InputError
from camnet.io.rig import parse_rig
from camnet.sim.clock import SimClock, free_run_phase
from camnet.sim.scene import Scene

FPS = Fraction(30)
PERIOD_NS = 1e9 / 30
EPOCH_NS = 1_700_000_000 * 1_000_000_000
SLOT = 51_000_000_000  # about 1700 s after EPOCH_NS at 30 fps


def test_a_clock_stamps_its_reading_latency_after_the_exposure_and_the_true_offset_is_exposure_minus_stamp():
    clock = SimClock(offset_ms=3.0, drift_ppm=20.0, latency_ms=12.0)
    for slot in (SLOT, SLOT + 1, SLOT + 9000):
        exposure = clock.exposure_ns(slot, FPS, EPOCH_NS)
        assert exposure == slot * 1_000_000_000 // 30  # triggered: the rig's instant, whatever its clock
        stamp = clock.stamp_ns(exposure, EPOCH_NS)
        drift_ns = 20e-6 * (exposure + 12_000_000 - EPOCH_NS)
        assert stamp - exposure == pytest.approx(12_000_000 - 3_000_000 + drift_ns, abs=1)
        assert clock.true_offset_ms(exposure, EPOCH_NS) == pytest.approx((exposure - stamp) / 1e6, abs=1e-6)
    # Without drift the contract's offset is the clock's offset less the latency, at any time.
    still = SimClock(offset_ms=3.0, latency_ms=12.0)
    assert still.true_offset_ms(SLOT * 10**9 // 30, EPOCH_NS) == pytest.approx(-9.0)
    assert still.true_offset_ms(EPOCH_NS, EPOCH_NS) == pytest.approx(-9.0)
    # The default clock is the common trigger's: exposure and stamp k / fps, as without a clock.
    plain = SimClock()
    assert plain.stamp_ns(plain.exposure_ns(SLOT, FPS, 0), 0) == SLOT * 1_000_000_000 // 30


def test_a_free_running_clock_exposes_at_its_own_phase_with_a_drifting_period():
    clock = SimClock(offset_ms=3.0, drift_ppm=50.0, latency_ms=5.0, free_run=True, phase=0.25)
    exposures = np.array([clock.exposure_ns(SLOT + k, FPS, EPOCH_NS) for k in range(0, 3001, 100)])
    # Its own clock reads (k + phase) / fps at each exposure, and on the rig's clock the camera runs
    # 50 ppm fast: 100 of its periods are 100 / 30 s less 50 ppm.
    for k, exposure in zip(range(0, 3001, 100), exposures, strict=True):
        reading = clock.camera_time_ns(int(exposure), EPOCH_NS)
        assert reading == pytest.approx((SLOT + k + 0.25) * PERIOD_NS, abs=2)
    assert np.diff(exposures) == pytest.approx(100 * PERIOD_NS / (1 + 50e-6), abs=2)
    # Offset 3 ms: the rig clock reads 3 ms more than the camera's, so it exposes 3 ms + a quarter period
    # (less the drift since the epoch) after the rig's slot instant.
    ahead_ns = exposures[0] - SLOT * 1_000_000_000 // 30
    drift_ns = 50e-6 * (exposures[0] - EPOCH_NS)
    assert ahead_ns == pytest.approx(3_000_000 + 0.25 * PERIOD_NS - drift_ns, abs=5)
    for slot in (SLOT, SLOT + 1234):
        exposure = clock.exposure_ns(slot, FPS, EPOCH_NS)
        assert clock.slot_at(exposure, FPS, EPOCH_NS) == slot
        assert clock.slot_at(exposure - 1, FPS, EPOCH_NS) == slot - 1
        stamp = clock.stamp_ns(exposure, EPOCH_NS)
        assert clock.true_offset_ms(exposure, EPOCH_NS) == pytest.approx((exposure - stamp) / 1e6, abs=1e-6)
    phases = {free_run_phase(name) for name in ("left", "right", "mono_a", "mono_b")}
    assert len(phases) == 4 and all(0 <= p < 1 for p in phases)


def rig_doc(clock: dict | None = None) -> dict:
    sim = {"width": 160, "height": 120, "f_px": 200, "noise_sigma_dn": 0}
    cameras = [{"id": "a", "driver": "sim", "sim": dict(sim)}, {"id": "b", "driver": "sim", "sim": dict(sim)}]
    if clock is not None:
        cameras[0]["sim"]["clock"] = clock
    return {"rig": "r", "stereo": {"left": "a", "right": "b", "baseline_m": 0.1}, "cameras": cameras,
            "scene": {"box_rotation_deg_per_s": 180.0}}


def test_the_rig_file_gives_a_clock_and_its_bad_values_are_named():
    rig = parse_rig(rig_doc({"offset_ms": 3.0, "drift_ppm": 20, "latency_ms": 12, "free_run": True}))
    clock = rig.cameras[0].config.clock
    assert (clock.offset_ms, clock.drift_ppm, clock.latency_ms, clock.free_run) == (3.0, 20.0, 12.0, True)
    assert clock.phase == free_run_phase("a") and rig.cameras[1].config.clock is None
    assert parse_rig(rig_doc({"latency_ms": 4})).cameras[0].config.clock == SimClock(latency_ms=4.0)
    assert groundtruth_document(rig)["cameras"][0]["clock"]["latency_ms"] == 12.0
    assert "clock" not in groundtruth_document(rig)["cameras"][1]
    for clock, message in [
        ({"latency_ms": -1}, r"cameras\[0\]\.sim\.clock\.latency_ms: must be at least 0"),
        ({"drift_ppm": 5000}, r"cameras\[0\]\.sim\.clock\.drift_ppm: must be within \+-1000 ppm, got 5000"),
        ({"offset_ms": "soon"}, r"cameras\[0\]\.sim\.clock\.offset_ms: expected a finite number"),
        ({"drift_ppm": float("nan")}, r"cameras\[0\]\.sim\.clock\.drift_ppm: expected a finite number"),
        ({"free_run": "yes"}, r"cameras\[0\]\.sim\.clock\.free_run"),
        ({"latency": 3}, r"unknown key 'latency' in cameras\[0\]\.sim\.clock \(did you mean 'latency_ms'\?\)"),
    ]:
        with pytest.raises(InputError, match=message):
            parse_rig(rig_doc(clock))
    with pytest.raises(InputError, match=r"cameras\[0\]\.sim\.clock: expected a mapping"):
        parse_rig(rig_doc(3))


def test_a_free_running_camera_shows_the_scene_at_its_exposure_and_stamps_its_clock():
    doc = rig_doc({"offset_ms": 7.0, "drift_ppm": 30.0, "latency_ms": 12.0, "free_run": True})
    rig = parse_rig(doc)
    plain_doc = copy.deepcopy(doc)
    del plain_doc["cameras"][0]["sim"]["clock"]
    plain_rig = parse_rig(plain_doc)
    scene = Scene(rig.scene)
    epoch = time.time_ns()
    clocked = SimCamera("a", rig.cameras[0].config, scene, clock_epoch_ns=epoch)
    plain = SimCamera("a", plain_rig.cameras[0].config, scene)
    slot = clocked.slot_at(epoch) + 30
    exposure_s = clocked.exposure_ns(slot) / 1e9
    assert exposure_s != pytest.approx(slot / 30, abs=1e-3)  # its own instant, not the trigger's
    image = clocked.render(slot)
    assert np.array_equal(image, plain.render_at(exposure_s, noise_key=slot))
    assert not np.array_equal(image, plain.render(slot))  # the box turned between the two instants
    assert clocked.true_offset_ms(slot) == pytest.approx(
        (clocked.exposure_ns(slot) - clocked.slot_timestamp_ns(slot)) / 1e6, abs=1e-6)
    # Read as a driver: each frame comes once its latency has passed, with its clock's stamp.
    with clocked:
        for _ in range(3):
            frame = clocked.read(timeout_s=1.0)
            assert time.time_ns() >= clocked.exposure_ns(frame.seq) + 12_000_000
            assert frame.timestamp_ns == clocked.slot_timestamp_ns(frame.seq)
            assert np.array_equal(frame.image, clocked.render(frame.seq))
