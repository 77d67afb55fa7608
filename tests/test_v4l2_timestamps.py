"""Image sequences stamped from a recorded timestamps file (KITTI's format), and the rig-file keys for them."""

import time

import cv2
import numpy as np
import pytest
from camnet.drivers.base import DeviceError, EndOfStream
from camnet.drivers.v4l2 import V4l2Camera, create, frame_index, parse_timestamps, stamped_sequence
from camnet.services.matcher_config import MatcherNodeConfig

from camnet.errors import InputError
from camnet.io.rig import V4l2Config, parse_rig

# 2011-09-26 14:05:35 UTC
BASE_NS = 1317045935 * 1_000_000_000


def stamp_line(ns: int) -> str:
    seconds, fraction = divmod(ns - BASE_NS, 1_000_000_000)
    return f"2011-09-26 14:05:{35 + seconds:02d}.{fraction:09d}"


def recording(tmp_path, indices, *, period_ns=100_000_000, jitter_ns=(), lines=20):
    """Images named by frame index (a different grey level each) and a timestamps file of `lines` lines."""
    stamps = BASE_NS + period_ns * np.arange(lines)
    for i, dt in enumerate(jitter_ns):
        stamps[i] += dt
    for index in indices:
        cv2.imwrite(str(tmp_path / f"{index:010d}.png"), np.full((8, 12), 10 * index, np.uint8))
    path = tmp_path / "timestamps.txt"
    path.write_text("".join(stamp_line(int(t)) + "\n" for t in stamps) + "\n")
    return str(tmp_path / "*.png"), str(path), stamps


def config(source, timestamps, **overrides) -> V4l2Config:
    values = dict(source=source, width=None, height=None, fps=None, fourcc=None, encoding="mono8",
                  loop=False, timestamps=timestamps, speed=1.0, frame_range=None)
    values.update(overrides)
    return V4l2Config(**values)


def test_timestamps_are_read_to_the_nanosecond_as_utc():
    stamps = parse_timestamps("2011-09-26 14:05:35.500923136\n2011-09-26 14:05:36.5\n\n", source="t.txt")
    assert stamps.tolist() == [BASE_NS + 500_923_136, BASE_NS + 1_500_000_000]


@pytest.mark.parametrize("line", ["2011-09-26T14:05:35.5", "14:05:35.500", "2011-09-26 25:05:35.1", ""])
def test_a_bad_timestamp_line_is_named(line):
    with pytest.raises(ValueError, match=r"t\.txt:2: expected 'YYYY-MM-DD HH:MM:SS"):
        parse_timestamps(f"2011-09-26 14:05:35.1\n{line}\n2011-09-26 14:05:35.3\n", source="t.txt")


def test_frame_index_is_the_last_number_of_the_name():
    assert frame_index("/data/image_02/data/0000000013.png") == 13
    assert frame_index("cam3_frame_0042.png") == 42
    with pytest.raises(ValueError, match="no frame number"):
        frame_index("left.png")


def test_stamps_follow_the_frame_index_and_a_pass_is_the_range_plus_one_period(tmp_path):
    source, _, stamps = recording(tmp_path, [16, 1, 4, 13], jitter_ns=[0, 3_000_000])
    files = sorted(str(p) for p in tmp_path.glob("*.png"))
    seq = stamped_sequence(files, stamps, frame_range=None, source="t.txt")
    assert [frame_index(f) for f in seq.files] == [1, 4, 13, 16]
    assert list(seq.stamps_ns) == stamps[[1, 4, 13, 16]].tolist()
    assert seq.period_ns == 100_000_000  # the median interval, not spoiled by frame 1's jitter
    assert seq.origin_ns == stamps[1] and seq.pass_ns == 16 * 100_000_000
    # A wider frame range: the pace starts at its first frame and a pass is longer; frames outside are skipped.
    seq = stamped_sequence(files, stamps, frame_range=(0, 14), source="t.txt")
    assert [frame_index(f) for f in seq.files] == [1, 4, 13]
    assert seq.origin_ns == stamps[0] and seq.pass_ns == 15 * 100_000_000


@pytest.mark.parametrize(("frame_range", "lines", "message"), [
    ((17, 19), 20, "no image within frame_range"),
    (None, 10, "has 10 lines, no stamp for frame 16"),
    (None, 1, "at least 2 lines"),
])
def test_sequences_without_stamps_are_refused(tmp_path, frame_range, lines, message):
    source, _, stamps = recording(tmp_path, [1, 16], lines=lines)
    files = sorted(str(p) for p in tmp_path.glob("*.png"))
    with pytest.raises(ValueError, match=message):
        stamped_sequence(files, stamps, frame_range=frame_range, source="t.txt")


def test_stamps_that_go_back_are_refused(tmp_path):
    _, _, stamps = recording(tmp_path, [1, 2], jitter_ns=[0, 0, -150_000_000])
    files = sorted(str(p) for p in tmp_path.glob("*.png"))
    with pytest.raises(ValueError, match="do not increase"):
        stamped_sequence(files, stamps, frame_range=None, source="t.txt")


def test_a_looping_sequence_carries_recorded_stamps_that_keep_increasing(tmp_path):
    source, timestamps, stamps = recording(tmp_path, [2, 3, 5])
    with V4l2Camera("c", config(source, timestamps, loop=True, speed=20.0)) as cam:
        assert cam.info.fps == pytest.approx(200.0)
        frames = [cam.read(timeout_s=1.0) for _ in range(7)]
    pass_ns = 4 * 100_000_000  # frames 2-5: span 3 periods, plus one
    expected = [stamps[i] + k * pass_ns for k in range(3) for i in (2, 3, 5)][:7]
    assert [f.timestamp_ns for f in frames] == expected
    assert [int(f.image[0, 0]) // 10 for f in frames] == [2, 3, 5, 2, 3, 5, 2]
    assert [f.seq for f in frames] == list(range(7))


def test_recorded_pace_is_scaled_and_a_fixed_rate_overrides_it(tmp_path):
    source, timestamps, stamps = recording(tmp_path, [0, 4])
    # Recorded: frame 4 is 0.4 s after frame 0; at speed 2 it is due 0.2 s after the start.
    with V4l2Camera("c", config(source, timestamps, speed=2.0)) as cam:
        t0 = time.monotonic()
        cam.read(timeout_s=1.0)
        frame = cam.read(timeout_s=1.0)
        assert time.monotonic() - t0 >= 0.19 and frame.timestamp_ns == stamps[4]
        with pytest.raises(EndOfStream):
            cam.read(timeout_s=1.0)
    # A fixed rate publishes one image per period whatever the stamps say; the stamps stay recorded. Told
    # apart from the recorded pace by half of it (a gap of 8 s; 2 ms at 500 fps), not by a tight clock.
    (tmp_path / "far").mkdir()
    source, timestamps, stamps = recording(tmp_path / "far", [0, 4], period_ns=2_000_000_000, lines=8)
    with V4l2Camera("c", config(source, timestamps, fps=500.0)) as cam:
        t0 = time.monotonic()
        frames = [cam.read(timeout_s=1.0) for _ in range(2)]
        assert time.monotonic() - t0 < 4.0
    assert [f.timestamp_ns for f in frames] == stamps[[0, 4]].tolist()


def test_cameras_with_different_frames_of_one_recording_stay_in_step(tmp_path):
    """Like KITTI's colour cameras: one has frames 1 and 4, the other 13 and 16, both within frames 1-16."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    source_a, timestamps, stamps = recording(tmp_path / "a", [1, 4])
    source_b, _, _ = recording(tmp_path / "b", [13, 16])
    frames = {}
    for name, source in (("a", source_a), ("b", source_b)):
        with V4l2Camera(name, config(source, timestamps, loop=True, frame_range=[1, 16], fps=1000.0)) as cam:
            frames[name] = [cam.read(timeout_s=1.0).timestamp_ns for _ in range(4)]
    pass_ns = 16 * 100_000_000
    assert frames["a"] == [stamps[1], stamps[4], stamps[1] + pass_ns, stamps[4] + pass_ns]
    assert frames["b"] == [stamps[13], stamps[16], stamps[13] + pass_ns, stamps[16] + pass_ns]


def test_unreadable_timestamps_name_the_camera_and_the_file(tmp_path):
    source, timestamps, _ = recording(tmp_path, [1])
    with pytest.raises(DeviceError, match="camera 'c': cannot read timestamps .*missing.txt"):
        V4l2Camera("c", config(source, str(tmp_path / "missing.txt"))).__enter__()
    (tmp_path / "bad.txt").write_text("2011-09-26 14:05:35.1\nyesterday\n")
    with pytest.raises(DeviceError, match=r"camera 'c': .*bad\.txt:2: expected"):
        V4l2Camera("c", config(source, str(tmp_path / "bad.txt"))).__enter__()


def test_cameras_looping_together_keep_one_pass_length_though_their_median_intervals_differ(tmp_path):
    """Two recordings of one rig whose timestamps files' median intervals differ by 0.2 ms: each pass of
    frames 1-16 on its own would be 3.2 ms longer for one camera than for the other."""
    cameras = []
    for name, period_ns in (("a", 100_000_000), ("b", 100_200_000)):
        (tmp_path / name).mkdir()
        recording(tmp_path / name, [1, 16], period_ns=period_ns)
        cameras.append({"id": name, "driver": "v4l2", "v4l2": {
            "source": f"{name}/*.png", "timestamps": f"{name}/timestamps.txt", "loop": True,
            "frame_range": [1, 16], "fps": 1000.0}})
    rig = parse_rig({"rig": "r", "cameras": cameras}, base_dir=tmp_path)
    stamps = {}
    for entry in rig.cameras:
        with create(entry, rig) as cam:
            stamps[entry.id] = np.array([cam.read(timeout_s=1.0).timestamp_ns for _ in range(12)])
    apart_ms = np.abs(stamps["a"] - stamps["b"]) / 1e6
    # Six passes, every frame still within the matcher's tolerance of its partner (3.2 ms at frame 16).
    assert apart_ms.max() <= MatcherNodeConfig().sync_tolerance_ms, apart_ms
    assert np.all(np.diff(stamps["a"]) > 0) and np.all(np.diff(stamps["b"]) > 0)


# ---------------------------------------------------------------- the rig file


def rig(v4l2: dict, **camera) -> dict:
    return {"rig": "r", "cameras": [{"id": "a", "driver": "v4l2", "v4l2": v4l2, **camera}]}


def test_rig_file_keys_for_stamped_sequences_intrinsics_and_sync():
    doc = rig({"source": "img/*.png", "timestamps": "t.txt", "speed": 0.5, "frame_range": [1, 16], "loop": True},
              intrinsics={"K": [[900, 0, 640], [0, 900, 360], [0, 0, 1]], "dist": [-0.3, 0.1], "fixed": ["K"]})
    doc["sync"] = {"tolerance_ms": 10, "max_wait_s": 2}
    parsed = parse_rig(doc)
    entry = parsed.cameras[0]
    assert (entry.config.timestamps, entry.config.speed, entry.config.frame_range) == ("t.txt", 0.5, (1, 16))
    assert entry.intrinsics.K[0, 0] == 900 and entry.intrinsics.dist.tolist() == [-0.3, 0.1, 0, 0, 0]
    assert entry.intrinsics.fixed == frozenset({"K"})
    assert (parsed.sync.tolerance_ms, parsed.sync.max_wait_s) == (10.0, 2.0)
    plain = parse_rig(rig({"source": "img/*.png"}))
    assert plain.sync is None and plain.cameras[0].intrinsics is None and plain.cameras[0].config.timestamps is None
    assert parse_rig(rig({"source": "x/*.png"}, intrinsics={"dist": [0.1]})).cameras[0].intrinsics.fixed == \
        frozenset({"dist"})


@pytest.mark.parametrize(("v4l2", "extra", "message"), [
    ({"source": "img/*.png", "speed": 2}, {}, r"cameras\[0\]\.v4l2\.speed: only for an image sequence with"),
    ({"source": "clip.avi", "timestamps": "t.txt"}, {}, r"v4l2\.timestamps: only for an image sequence"),
    ({"source": "img/*.png", "timestamps": "t.txt", "fps": 5, "speed": 2}, {}, r"v4l2\.speed: scales the recorded"),
    ({"source": "img/*.png", "timestamps": "t.txt", "frame_range": [5, 1]}, {}, r"v4l2\.frame_range: expected"),
    ({"source": "img/*.png", "timestamps": "t.txt", "speed": 0}, {}, r"v4l2\.speed: must be positive"),
    ({"source": "x/*.png"}, {"intrinsics": {"K": [[1, 0], [0, 1]]}}, r"cameras\[0\]\.intrinsics\.K: expected a 3x3"),
    ({"source": "x/*.png"}, {"intrinsics": {"K": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}}, r"intrinsics\.K: expected"),
    ({"source": "x/*.png"}, {"intrinsics": {"dist": [0.1], "fixed": ["K"]}}, r"intrinsics\.fixed: expected a list"),
    ({"source": "x/*.png"}, {"intrinsics": {"fixed": []}}, r"cameras\[0\]\.intrinsics: give K, dist or both"),
    ({"source": "x/*.png"}, {"intrinsics": {"dist": [0.1], "k1": 2}},
     r"unknown key 'k1' in cameras\[0\]\.intrinsics \(known: K, dist, fixed\)"),
])
def test_bad_rig_keys_are_named(v4l2, extra, message):
    with pytest.raises(InputError, match=message):
        parse_rig(rig(v4l2, **extra))


def test_bad_sync_settings_are_named():
    doc = rig({"source": "x/*.png"})
    doc["sync"] = {"tolerance_ms": -1}
    with pytest.raises(InputError, match="sync.tolerance_ms: must be at least 0"):
        parse_rig(doc)
    doc["sync"] = {"tolerance": 5}
    with pytest.raises(InputError, match=r"unknown key 'tolerance' in sync \(did you mean 'tolerance_ms'\?\)"):
        parse_rig(doc)
