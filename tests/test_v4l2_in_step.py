"""Video files and image sequences of one rig, recorded together, play in step from a shared start instant
(`files_start_ns`), whenever their drivers open: the v4l2 driver on files written here."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest
from camnet.drivers.base import EndOfStream
from camnet.drivers.v4l2 import V4l2Camera

from camnet.io.rig import V4l2Config

FPS = 10.0
PERIOD_NS = int(1e9 / FPS)
FRAMES = 30
LATE_S = 0.3  # the second driver opens this long after the first
TOLERANCE_NS = 5_000_000  # the matcher's default sync tolerance
MAX_WAIT_NS = 500_000_000  # how long the matcher waits for a set's frames (sync.max_wait_s)


def config(source: str, **overrides) -> V4l2Config:
    values = dict(source=source, width=None, height=None, fps=None, fourcc=None, encoding="mono8", loop=False)
    values.update(overrides)
    return V4l2Config(**values)


def level(i: int) -> int:
    """The grey level of frame i of the files written here: 8 apart, so that lossy coding keeps them apart."""
    return (8 * i) % 256


def video(path, n: int = FRAMES) -> str:
    """An mp4 of `n` 64x48 frames at FPS, frame i of grey `level(i)`, as a webcam capture tool writes them."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (64, 48))
    assert writer.isOpened()
    for i in range(n):
        writer.write(np.full((48, 64, 3), level(i), np.uint8))
    writer.release()
    return str(path)


def frame_number(image: np.ndarray) -> int:
    """Which frame of `video` an image is, from its grey level."""
    return round(float(image.mean()) / 8)


def due(start_ns: int, wall_ns: int) -> int:
    """The frame of files started at `start_ns` that is due at wall time `wall_ns`."""
    return (wall_ns - start_ns) // PERIOD_NS


def play(camera: V4l2Camera, opens_at_s: float, got: list, opened: list | None = None) -> None:
    """Open `camera` at monotonic `opens_at_s` and read it to its end: (seq, timestamp_ns, frame number,
    monotonic ns when read) per frame, into `got`; the wall times (ns) just before and after it opened, into
    `opened`."""
    time.sleep(max(0.0, opens_at_s - time.monotonic()))
    before_ns = time.time_ns()
    with camera:
        if opened is not None:
            opened += [before_ns, time.time_ns()]
        while True:
            try:
                frame = camera.read(timeout_s=5.0)
            except EndOfStream:
                return
            got.append((frame.seq, frame.timestamp_ns, frame_number(frame.image), time.monotonic_ns()))


def two_drivers(tmp_path, files_start_ns: int | None, opened: list | None = None) -> tuple[list, list]:
    """Frames of two cameras' files read by two drivers, the second opening LATE_S after the first (the wall
    times just before and after it opened, into `opened`)."""
    a, b = [], []
    first_s = time.monotonic() + 0.1
    threads = [threading.Thread(target=play, args=(V4l2Camera(name, config(video(tmp_path / f"{name}.mp4")),
                                                              files_start_ns=files_start_ns), opens_s, got, where))
               for name, opens_s, got, where in (("a", first_s, a, None), ("b", first_s + LATE_S, b, opened))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    return a, b


def test_files_of_one_rig_play_in_step_from_a_shared_start(tmp_path):
    start_ns = time.time_ns() + 100_000_000  # as camnet up: picked as the drivers are started
    opened: list[int] = []
    a, b = two_drivers(tmp_path, start_ns, opened)
    by_seq_a = {seq: rest for seq, *rest in a}
    common = [(seq, by_seq_a[seq], rest) for seq, *rest in b if seq in by_seq_a]
    # The late driver began at the frame due when it opened, skipping those before, and played to the end.
    assert due(start_ns, opened[0]) >= 1 and due(start_ns, opened[0]) <= b[0][0] <= due(start_ns, opened[1]) + 1, \
        (b[0], opened)
    assert [seq for seq, *_ in b] == list(range(b[0][0], FRAMES))
    assert len(common) == len(b)
    for seq, (stamp_a, number_a, read_a), (stamp_b, number_b, read_b) in common:
        assert stamp_a == stamp_b == start_ns + seq * PERIOD_NS
        assert number_a == number_b == seq  # the stamp is that of the frame it carries
        # Published at its due time by both, not at each driver's own pace: within the matcher's wait for a set.
        assert abs(read_a - read_b) < MAX_WAIT_NS, f"frame {seq} read {abs(read_a - read_b) / 1e6:.0f} ms apart"


def test_without_a_shared_start_each_driver_starts_the_files_at_its_own_start(tmp_path):
    a, b = two_drivers(tmp_path, None)
    assert [seq for seq, *_ in a] == [seq for seq, *_ in b] == list(range(FRAMES))
    apart_ns = [stamp_b - stamp_a for (_, stamp_a, *_), (_, stamp_b, *_) in zip(a, b, strict=True)]
    assert min(apart_ns) > 0.5 * LATE_S * 1e9 > TOLERANCE_NS  # never in one frame set


@pytest.mark.parametrize("loop", [True, False])
def test_a_driver_opening_long_after_the_start_goes_on_at_the_frame_due(tmp_path, loop):
    """As a driver that camnet up starts again after it died: not frame 0 stamped now, nor a burst of every
    frame since the start, but the frame due now, at once, on the rig's clock; past its end, a file that does
    not loop has ended."""
    path = video(tmp_path / "a.mp4", 20)
    start_ns = time.time_ns() - int(2.55e9)  # frame 25 due 50 ms ago: frame 5 of the second pass
    before_ns = time.time_ns()
    with V4l2Camera("a", config(path, loop=loop), files_start_ns=start_ns) as camera:
        after_ns = time.time_ns()
        if not loop:
            with pytest.raises(EndOfStream):
                camera.read()
            return
        first = camera.read()
        second = camera.read()
    # The frame due when it opened (25, or a later one where opening took long), its stamp on the rig's clock.
    assert due(start_ns, before_ns) <= first.seq <= due(start_ns, after_ns), (first.seq, before_ns, after_ns)
    for frame, seq in ((first, first.seq), (second, first.seq + 1)):
        assert (frame.seq, frame.timestamp_ns, frame_number(frame.image)) == (seq, start_ns + seq * PERIOD_NS, seq % 20)


def test_an_image_sequence_without_timestamps_shares_the_start_and_one_with_them_keeps_its_own(tmp_path):
    for i in range(4):
        cv2.imwrite(str(tmp_path / f"img_{i}.png"), np.full((48, 64), level(i), np.uint8))
    (tmp_path / "times.txt").write_text("".join(f"2011-09-26 13:02:25.{i:09d}\n" for i in range(0, 400, 100)))
    start_ns = time.time_ns() - int(0.25e9)  # frame 2 due 50 ms ago
    pattern = str(tmp_path / "img_*.png")
    with V4l2Camera("plain", config(pattern, fps=FPS), files_start_ns=start_ns) as camera:
        plain = [camera.read() for _ in range(2)]
    stamps_path = str(tmp_path / "times.txt")
    with V4l2Camera("stamped", config(pattern, timestamps=stamps_path, fps=100.0),
                    files_start_ns=start_ns) as camera:
        stamped = camera.read()
    assert [(f.seq, f.timestamp_ns, frame_number(f.image)) for f in plain] == \
        [(i, start_ns + i * PERIOD_NS, i) for i in (2, 3)]
    recorded_ns = int(np.datetime64("2011-09-26T13:02:25", "ns").astype(np.int64))
    assert (stamped.seq, stamped.timestamp_ns) == (0, recorded_ns)
