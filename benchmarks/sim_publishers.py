"""Simulated camera processes publishing frames on a loopback Zenoh bus (for the benchmarks).

Each camera is its own process. In "camnet" mode it runs the real driver
node (camnet.drivers.node.DriverNode: frame encoding, publish with congestion
control DROP, liveliness, statistics) on a camera that cycles through frames
pre-rendered by the sim renderer, so that rendering cost does not hide the
bus cost; the camera writes each frame into the node's reused message, the
one copy a capture costs. In "bare" mode a bare Zenoh publisher (also DROP)
does the same capture: each frame's pixels copied from the same pool into
one reused payload, the same encoded bytes, only the sequence number and
timestamp stamped into the header, then `put`. So both produce their pixels
the same way and the camera's copy is counted in both. "bare-ready" puts
ready-made bytes with no capture at all: a floor no camera publisher reaches.
"camnet-shm" is camnet with its frames put through Zenoh shared memory
(`DriverNode(shared_memory=True)`) instead of as bytes.

Every mode records, per frame, the host CLOCK_REALTIME just before `put`
(and, for camnet, the capture time from the frame header), and send them
back when done, so a subscriber can time publish-to-receipt the same way for
both without any change to the wire format.
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import struct
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from camnet.bus.frame import Frame, FrameBuffer  # noqa: E402

RIG_FILE = ROOT / "config" / "sim.yaml"
POOL_FRAMES = 4
# Offsets of seq and timestamp_ns in the frame header (docs/frame-format.md).
SEQ_AND_TIMESTAMP = struct.Struct("<QQ")
SEQ_OFFSET = 20


def camera_id(index: int) -> str:
    return f"cam{index}"


def render_pool(camera_index: int, width: int, height: int) -> list[np.ndarray]:
    """A few frames of the sim rig's camera (cycled through by the publisher)."""
    from camnet.io.rig import load_rig
    from camnet.sim.render import Renderer
    from camnet.sim.scene import Scene

    rig = load_rig(RIG_FILE)
    entry = rig.cameras[camera_index % len(rig.cameras)]
    cam = entry.config.camera(entry.id)
    if (width, height) != (cam.width, cam.height):
        cam = replace(cam, width=width, height=height)
    renderer = Renderer(cam)
    scene = Scene(rig.scene)
    rng = np.random.default_rng(camera_index)
    return [renderer.render(scene.quads(k / 30), noise_sigma_dn=2.0, rng=rng)
            for k in range(POOL_FRAMES)]


class PooledCamera:
    """A Camera (camnet.drivers.base protocol) replaying pre-rendered frames at `fps`."""

    def __init__(self, camera_id: str, pool: list[np.ndarray], fps: float) -> None:
        from camnet.drivers.base import DeviceInfo

        self.camera_id = camera_id
        self.groundtruth = None
        self.pool = pool
        self.fps = fps
        self.seq = 0
        self.t0_ns = 0
        h, w = pool[0].shape
        self.info = DeviceInfo(camera_id, "sim", w, h, "mono8", fps, "pooled sim frames")
        self.dropped = 0

    def __enter__(self):
        self.t0_ns = time.monotonic_ns()
        return self

    def __exit__(self, *exc):
        return None

    def read(self, *, timeout_s: float = 1.0) -> Frame:
        seq, timestamp_ns, encoding, image = self._next()
        return Frame(self.camera_id, seq, timestamp_ns, encoding, image.copy())

    def read_into(self, buffer: FrameBuffer, *, timeout_s: float = 1.0):
        # Into the node's reused message, as a camera would write it: the capture's one copy.
        return buffer.fill(*self._next())

    def _next(self) -> tuple[int, int, str, np.ndarray]:
        seq = self.seq
        sleep_until(self.t0_ns, seq, self.fps)
        self.seq = seq + 1
        return seq, time.time_ns(), "mono8", self.pool[seq % len(self.pool)]


def sleep_until(t0_ns: int, seq: int, fps: float) -> None:
    """Sleep until frame `seq` of a stream started at monotonic `t0_ns` is due."""
    wait_s = (t0_ns + int(seq * 1e9 / fps) - time.monotonic_ns()) / 1e9
    if wait_s > 0:
        time.sleep(wait_s)


class PutLog:
    """Per frame: seq, capture timestamp_ns, put timestamp_ns, ns spent in put; preallocated.

    Also the process's CPU and wall time just after the put of frame `steady_from` and of the
    last frame: the publisher's CPU between them is the steady state, the same frames' work in
    every mode, without what each mode does to start (sessions, publishers, liveliness) and stop.
    """

    def __init__(self, n_frames: int, steady_from: int = 0) -> None:
        self.rows = np.zeros((n_frames, 4), dtype=np.int64)
        self.n = 0
        self.steady_from = min(steady_from, n_frames - 2)
        self.marks: list[tuple[float, float]] = []  # (process CPU s, monotonic s)

    def add(self, payload, put_ns: int, put_duration_ns: int) -> None:
        if self.n < len(self.rows):
            seq, capture_ns = SEQ_AND_TIMESTAMP.unpack_from(payload, SEQ_OFFSET)
            self.rows[self.n] = (seq, capture_ns, put_ns, put_duration_ns)
            self.n += 1
            if self.n - 1 == self.steady_from or self.n == len(self.rows):
                self.marks.append((time.process_time(), time.monotonic()))

    def steady_cpu(self) -> float:
        """CPU time over wall time between the marks (1.0 = one core); NaN without both."""
        if len(self.marks) < 2:
            return float("nan")
        (cpu0, wall0), (cpu1, wall1) = self.marks[0], self.marks[-1]
        return (cpu1 - cpu0) / (wall1 - wall0) if wall1 > wall0 else float("nan")


class TimedPublisher:
    """A Zenoh publisher that logs the time just before each put."""

    def __init__(self, publisher, log: PutLog) -> None:
        self._publisher = publisher
        self._log = log

    def put(self, payload, **kwargs) -> None:
        put_ns, t0_ns = time.time_ns(), time.perf_counter_ns()
        self._publisher.put(payload, **kwargs)
        self._log.add(payload, put_ns, time.perf_counter_ns() - t0_ns)

    def __getattr__(self, name):
        return getattr(self._publisher, name)


def time_frame_puts(log: PutLog, *, shared_memory: bool) -> None:
    """Make the driver node's frame publishers (this process's) log the time just before each put.

    Timed around `FramePublisher.put`, which copies the message into shared
    memory when it can: that copy is then inside "in put", as Zenoh's own copy is for bare.
    `shared_memory`: whether they put through Zenoh shared memory (the driver node's default: no).
    """
    from camnet.drivers import node as driver_node

    class TimedFramePublisher(driver_node.FramePublisher):
        def __init__(self, publisher, **_node_choice) -> None:  # the mode decides, not the node
            super().__init__(publisher, shared_memory=shared_memory)

        def put(self, message) -> None:
            put_ns, t0_ns = time.time_ns(), time.perf_counter_ns()
            super().put(message)
            log.add(message, put_ns, time.perf_counter_ns() - t0_ns)

    driver_node.FramePublisher = TimedFramePublisher


@dataclass
class PublisherResult:
    index: int
    sent: int
    cpu_s: float
    wall_s: float
    puts: np.ndarray  # (sent, 4): seq, capture timestamp_ns, put timestamp_ns, put duration ns
    steady_cpu: float  # CPU over wall time from the first scored frame's put to the last's (PutLog)


def publisher(mode: str, index: int, endpoint: str, fps: float, n_frames: int, size, start,
              results, steady_from: int = 0) -> None:
    """Process body: publish `n_frames` at `fps` once `start` is set; report a PublisherResult.

    Its steady CPU counts from the put of frame `steady_from` on.
    """
    import zenoh

    from camnet.bus import keys
    from camnet.bus.frame import encode_frame
    from camnet.bus.session import BusOptions, open_session
    from camnet.io.rig import load_rig

    pool = render_pool(index, *size)
    cam_id = camera_id(index)
    log = PutLog(n_frames, steady_from)
    with open_session(BusOptions(connect=(endpoint,))) as session:
        if mode in ("camnet", "camnet-shm"):
            from camnet.drivers.node import DriverNode

            time_frame_puts(log, shared_memory=mode == "camnet-shm")
            node = DriverNode(session, load_rig(RIG_FILE), PooledCamera(cam_id, pool, fps))
            start.wait()
            cpu0, wall0 = time.process_time(), time.monotonic()
            node.run(max_frames=n_frames)
            sent = node.frames_sent
        else:
            # The same bytes as camnet would send; only seq and timestamp change per frame. "bare" copies
            # each frame's pixels into one reused payload first, as a camera publisher must.
            payloads = [bytearray(encode_frame(Frame(cam_id, 0, 0, "mono8", img))) for img in pool]
            capture = mode == "bare"
            if capture:
                payloads = payloads[:1]
                pixels = np.frombuffer(payloads[0], np.uint8, offset=len(payloads[0]) - pool[0].size)
            pub = TimedPublisher(session.declare_publisher(
                keys.frame("bench", cam_id), congestion_control=zenoh.CongestionControl.DROP), log)
            start.wait()
            cpu0, wall0 = time.process_time(), time.monotonic()
            t0_ns = time.monotonic_ns()
            for seq in range(n_frames):
                sleep_until(t0_ns, seq, fps)
                payload = payloads[seq % len(payloads)]
                if capture:
                    np.copyto(pixels, pool[seq % len(pool)].reshape(-1))
                SEQ_AND_TIMESTAMP.pack_into(payload, SEQ_OFFSET, seq, time.time_ns())
                pub.put(payload)
            sent = n_frames
        cpu_s, wall_s = time.process_time() - cpu0, time.monotonic() - wall0
        time.sleep(0.5)  # let the last frames drain before the session closes
    results.put(PublisherResult(index, sent, cpu_s, wall_s, log.rows[:log.n].copy(), log.steady_cpu()))


def rig_name(mode: str) -> str:
    """The rig the frames of `mode` are published under (DriverNode uses the sim rig's)."""
    return "sim" if mode.startswith("camnet") else "bench"


def run_publishers(session, endpoint: str, *, mode: str, cameras: int, fps: float,
                   seconds: float, size=(1280, 1024), progress=None,
                   progress_period_s: float = 5.0,
                   steady_from: int = 0) -> tuple[dict[int, PublisherResult], float]:
    """Run `cameras` publisher processes connecting to `session` at `endpoint` until done.

    Returns their results by camera index and this process's CPU fraction
    (CPU time over wall time, 1.0 = one core) while they published.
    `progress(elapsed_s)` is called every `progress_period_s`; each publisher's steady CPU counts
    from frame `steady_from` on.
    """
    n_frames = int(round(fps * seconds))
    ctx = mp.get_context("spawn")
    start, results = ctx.Event(), ctx.Queue()
    procs = [ctx.Process(target=publisher, args=(mode, i, endpoint, fps, n_frames, size, start,
                                                 results, steady_from)) for i in range(cameras)]
    for p in procs:
        p.start()
    try:
        deadline = time.monotonic() + 60
        while len(list(session.info.peers_zid())) < cameras and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)  # subscriptions propagate to the new peers
        cpu0, wall0 = time.process_time(), time.monotonic()
        start.set()
        done: dict[int, PublisherResult] = {}
        next_report = wall0 + progress_period_s
        while len(done) < cameras:
            try:
                result = results.get(timeout=0.5)
                done[result.index] = result
            except queue.Empty:
                if any(p.exitcode not in (None, 0) for p in procs):
                    raise RuntimeError(f"a {mode} publisher process failed") from None
            if progress is not None and time.monotonic() >= next_report:
                progress(time.monotonic() - wall0)
                next_report += progress_period_s
            if time.monotonic() > wall0 + seconds + 120:
                raise RuntimeError(f"{mode} publishers did not finish")
        cpu = (time.process_time() - cpu0) / (time.monotonic() - wall0)
    finally:
        for p in procs:
            p.join(timeout=10)
            if p.is_alive():
                p.kill()
    return done, cpu
