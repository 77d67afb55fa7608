"""Frame sets from frames arriving per camera; simulated cameras on one common clock."""

from __future__ import annotations

import time

import numpy as np
import pytest

from camnet.bus.frame import Frame
from camnet.bus.sync import FrameSynchronizer
from camnet.io.rig import parse_rig

CAMERAS = ("left", "right", "mono_a", "mono_b")
PERIOD_NS = 100_000_000  # 10 fps


def frame(camera_id: str, timestamp_ns: int, seq: int = 0) -> Frame:
    return Frame(camera_id=camera_id, seq=seq, timestamp_ns=timestamp_ns, encoding="mono8",
                 image=np.zeros((2, 3), dtype=np.uint8))


def synchronizer(**options) -> FrameSynchronizer:
    options = {"tolerance_ns": 2_000_000, "max_wait_s": 0.5, "frames_per_camera": 4, **options}
    return FrameSynchronizer(CAMERAS, required=("left", "right"), **options)


def test_complete_set_takes_the_nearest_frame_within_tolerance():
    sync = synchronizer()
    t = 10 * PERIOD_NS
    for camera_id, dt in (("left", 0), ("right", 1_500_000), ("mono_a", -2_000_000)):
        sync.add(frame(camera_id, t + dt), now_s=0.0)
    sync.add(frame("mono_b", t + 2_500_000), now_s=0.0)  # outside the tolerance
    assert sync.pop(now_s=0.1) is None
    sync.add(frame("mono_b", t - 400_000), now_s=0.1)
    frame_set = sync.pop(now_s=0.1)
    assert frame_set is not None and frame_set.complete
    assert frame_set.timestamp_ns == t
    assert list(frame_set.frames) == list(CAMERAS)
    assert frame_set.frames["mono_b"].timestamp_ns == t - 400_000
    assert sync.pop(now_s=0.1) is None  # nothing is given out twice
    # mono_b's frame outside the tolerance is newer than the set: it stays for the next one.
    assert (sync.counts.complete_sets, sync.counts.dropped, sync.buffered) == (1, 0, 1)


def test_partial_set_only_after_max_wait_and_only_with_the_stereo_pair():
    sync = synchronizer()
    t = 5 * PERIOD_NS
    sync.add(frame("left", t), now_s=1.0)
    sync.add(frame("mono_a", t), now_s=1.0)
    # The right stereo camera is required: no set however long we wait.
    assert sync.pop(now_s=100.0) is None
    sync.add(frame("right", t), now_s=1.2)
    sync.add(frame("mono_b", t - PERIOD_NS), now_s=0.9)  # mono_b skipped instant t
    sync.add(frame("mono_b", t + PERIOD_NS), now_s=1.2)
    assert sync.pop(now_s=1.69) is None  # mono_b's t frame may still come: 0.49 s since the set's last frame
    frame_set = sync.pop(now_s=1.7)
    assert frame_set is not None and frame_set.missing == ("mono_b",)
    assert set(frame_set.frames) == {"left", "right", "mono_a"}
    counts = sync.counts
    assert (counts.partial_sets, counts.missing["mono_b"], counts.missing["left"]) == (1, 1, 0)
    # mono_b's frame of instant t, arriving now, can no longer be used.
    assert sync.add(frame("mono_b", t), now_s=1.8) is False


def test_newest_ready_set_wins_and_older_frames_are_dropped_once():
    sync = synchronizer(frames_per_camera=8)
    for k in range(3):
        for camera_id in CAMERAS:
            sync.add(frame(camera_id, k * PERIOD_NS, seq=k), now_s=0.0)
    frame_set = sync.pop(now_s=0.0)
    assert frame_set.timestamp_ns == 2 * PERIOD_NS
    assert {f.seq for f in frame_set.frames.values()} == {2}
    assert sync.counts.dropped == 8 and sync.buffered == 0
    # A newer instant whose mono_b is still missing waits; an older complete one is not there.
    for camera_id in CAMERAS[:3]:
        sync.add(frame(camera_id, 3 * PERIOD_NS), now_s=0.1)
    assert sync.pop(now_s=0.2) is None


def test_buffers_are_bounded_and_overflow_is_counted():
    sync = synchronizer(frames_per_camera=3, max_frames_per_camera=5)
    for k in range(10):  # a burst: all within the wait
        sync.add(frame("mono_a", k * PERIOD_NS), now_s=0.0)
    assert sync.buffered == 5
    assert sync.counts.received == 10 and sync.counts.dropped == 5
    sync.add(frame("mono_a", 10 * PERIOD_NS), now_s=10.0)  # long after: only frames_per_camera stay
    assert sync.buffered == 3 and sync.counts.dropped == 8


@pytest.mark.parametrize("fps", [1, 5, 10, 30, 60])
def test_a_dead_camera_at_any_frame_rate_leaves_every_frame_set_partial_not_stalled(fps):
    """A dead camera leaves the others' frame sets partial at any frame rate, none stalled: at 8 fps or more,
    buffers that hold less than the wait would form no partial set."""
    sync = synchronizer(max_wait_s=0.5)
    period_s, sets = 1.0 / fps, []
    frames = int(20 * fps)
    for k in range(frames):  # mono_b dies at once; 20 s of the others
        now_s = k * period_s
        for camera_id in CAMERAS[:3]:
            sync.add(frame(camera_id, round(k * period_s * 1e9)), now_s=now_s)
        while (frame_set := sync.pop(now_s=now_s)) is not None:
            sets.append(frame_set)
    assert all(s.missing == ("mono_b",) for s in sets)
    # Each set waits max_wait_s for mono_b, then the newest ready one goes: about one per wait or per frame.
    assert len(sets) >= min(frames, 20 / (0.5 + period_s)) * 0.9
    assert sync.buffered <= 3 * sync.max_frames_per_camera


def test_a_camera_that_stops_never_stalls_the_rest_and_may_come_back():
    sync = synchronizer(max_wait_s=0.2)
    sets = []
    for k in range(12):
        now_s = k * 0.1
        silent = 3 <= k < 8
        for camera_id in CAMERAS:
            if not (silent and camera_id == "mono_a"):
                sync.add(frame(camera_id, k * PERIOD_NS), now_s=now_s)
        while (frame_set := sync.pop(now_s=now_s)) is not None:
            sets.append(frame_set)
    assert [s.complete for s in sets[:3]] == [True] * 3
    partial = [s for s in sets if not s.complete]
    assert partial and all(s.missing == ("mono_a",) for s in partial)
    assert sets[-1].complete and sets[-1].timestamp_ns == 11 * PERIOD_NS


def test_frames_stamped_in_the_future_are_dropped_and_never_stall_the_sets():
    sync = synchronizer()
    day_ns = 86_400 * 10**9
    sets = []
    for k in range(30):
        now_s = k * 0.1
        for camera_id in CAMERAS:
            sync.add(frame(camera_id, k * PERIOD_NS), now_s=now_s)
        if k == 10:  # a forged pair one day ahead
            assert sync.add(frame("left", k * PERIOD_NS + day_ns), now_s=now_s) is False
            assert sync.add(frame("right", k * PERIOD_NS + day_ns), now_s=now_s) is False
        while (frame_set := sync.pop(now_s=now_s)) is not None:
            sets.append(frame_set)
    assert sync.counts.future == 2
    assert [s.timestamp_ns for s in sets] == [k * PERIOD_NS for k in range(30)]
    # A camera's first frame is judged by the others' clocks; a silent camera's return is not the future.
    late = FrameSynchronizer(("a", "b"), required=("a",), tolerance_ns=0, max_wait_s=0.5)
    assert late.add(frame("a", 10**9), now_s=1.0)
    assert not late.add(frame("b", 10**9 + day_ns), now_s=1.0)
    assert late.add(frame("a", 10**9 + 3600 * 10**9), now_s=3601.0)


def test_random_arrivals_keep_every_invariant():
    rng = np.random.default_rng(4)
    tolerance_ns = 3_000_000
    sync = synchronizer(tolerance_ns=tolerance_ns, max_wait_s=0.15, frames_per_camera=3)
    events = []
    for k in range(300):
        for camera_id in CAMERAS:
            if rng.random() < 0.15:
                continue  # lost on the way
            jitter_ns = int(rng.integers(-tolerance_ns // 2, tolerance_ns // 2 + 1))
            delay_s = rng.exponential(0.05)
            events.append((k * 0.1 + delay_s, frame(camera_id, k * PERIOD_NS + jitter_ns, seq=k)))
    events.sort(key=lambda e: e[0])
    sets, seen, added = [], set(), 0
    for now_s, f in events:
        added += 1
        sync.add(f, now_s=now_s)
        while (frame_set := sync.pop(now_s=now_s)) is not None:
            sets.append(frame_set)
    times = [s.timestamp_ns for s in sets]
    assert times == sorted(set(times))  # forward in time, one set per instant
    for frame_set in sets:
        assert {"left", "right"} <= set(frame_set.frames)
        for f in frame_set.frames.values():
            assert abs(f.timestamp_ns - frame_set.timestamp_ns) <= tolerance_ns
            assert id(f) not in seen
            seen.add(id(f))
    counts = sync.counts
    assert counts.received == added
    assert len(seen) + counts.dropped + sync.buffered == added
    assert counts.complete_sets > 100 and counts.partial_sets > 10


def test_bad_setup_is_refused():
    with pytest.raises(ValueError, match="required"):
        FrameSynchronizer(("a", "b"), required=("c",), tolerance_ns=0, max_wait_s=0.1)
    with pytest.raises(ValueError, match="not one of"):
        synchronizer().add(frame("nobody", 0), now_s=0.0)


# ---------------------------------------------------------------- simulated cameras, one clock

SMALL_RIG = {
    "rig": "clock",
    "cameras": [{"id": cam_id, "driver": "sim",
                 "sim": {"width": 160, "height": 128, "f_px": 200, "fps": 20,
                         "centre_m": [0.05 * i, 0.0, 0.0]}}
                for i, cam_id in enumerate(("a", "b"))],
    "scene": {"box_rotation_deg_per_s": 30.0},
}


def test_sim_cameras_started_apart_share_instants_and_scene():
    from camnet.drivers.base import create_camera

    rig = parse_rig(SMALL_RIG)
    first = create_camera(rig.camera("a"), rig)
    with first:
        frames_a = [first.read(timeout_s=1.0) for _ in range(2)]
    time.sleep(0.13)  # not a whole number of periods
    later_a = create_camera(rig.camera("a"), rig)
    b = create_camera(rig.camera("b"), rig)
    with later_a, b:
        frame_b = b.read(timeout_s=1.0)
        assert abs(time.time_ns() - frame_b.timestamp_ns) < 200_000_000
    for f in (*frames_a, frame_b):
        assert f.timestamp_ns == f.seq * 1_000_000_000 // 20  # slot k at k / fps, exactly
    assert frame_b.seq > frames_a[-1].seq
    # The same slot is the same image whichever instance renders it and when.
    assert np.array_equal(later_a.render(frames_a[0].seq), frames_a[0].image)
    assert not np.array_equal(later_a.render(frames_a[0].seq + 1), frames_a[0].image)
