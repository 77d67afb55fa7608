#!/usr/bin/env python3
"""Publishing-thread CPU per frame: camnet's driver node against bare Zenoh, in one process.

`bench_bus.py --alternate` compares whole publisher processes, most of whose
CPU is Zenoh's own threads; on a shared machine one pair of its phases moves
by tens of percent. This times only the thread that publishes: its CPU time
(`time.thread_time_ns`) from one `put` returning to the next, the sleep
until the frame is due not counted but what the thread does on waking is.
Two modes take turns in phases at the camera's rate, the order alternating:

- bare: bare Zenoh copying each frame's pixels from the pool into one reused
  payload, stamping seq and timestamp, and putting it (congestion control DROP);
- camnet: the driver node (`drivers.node.DriverNode`) on the pooled camera of
  `sim_publishers.py`, which writes each frame into the node's message.

A subscriber in another session of this process receives every frame over
loopback (its work runs on Zenoh's threads, not timed). Prints each pair's
medians and ratio, then the median ratio.

    python benchmarks/bench_driver_frame.py [--pairs 6] [--frames 240] [--fps 30]
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

from sim_publishers import (  # noqa: E402
    RIG_FILE,
    SEQ_AND_TIMESTAMP,
    SEQ_OFFSET,
    PooledCamera,
    render_pool,
    sleep_until,
)

from camnet.testing.ports import free_port  # noqa: E402

WARMUP_FRAMES = 30  # left out: the first puts wait for routes


def bare(session, pool: list[np.ndarray], frames: int, fps: float) -> np.ndarray:
    """Thread CPU ns from each put's return to the next's, bare Zenoh."""
    import zenoh

    from camnet.bus import keys
    from camnet.bus.frame import Frame, encode_frame

    payload = bytearray(encode_frame(Frame("cam0", 0, 0, "mono8", pool[0])))
    pixels = np.frombuffer(payload, np.uint8, offset=len(payload) - pool[0].size)
    publisher = session.declare_publisher(keys.frame("bench", "cam0"),
                                          congestion_control=zenoh.CongestionControl.DROP)
    marks = np.zeros(frames, np.int64)
    t0_ns = time.monotonic_ns()
    for seq in range(frames):
        sleep_until(t0_ns, seq, fps)
        np.copyto(pixels, pool[seq % len(pool)].reshape(-1))
        SEQ_AND_TIMESTAMP.pack_into(payload, SEQ_OFFSET, seq, time.time_ns())
        publisher.put(payload)
        marks[seq] = time.thread_time_ns()
    publisher.undeclare()
    return np.diff(marks[WARMUP_FRAMES:])


def camnet(session, pool: list[np.ndarray], frames: int, fps: float) -> np.ndarray:
    """Thread CPU ns from each put's return to the next's, the driver node."""
    from camnet.drivers import node as driver_node

    from camnet.io.rig import load_rig

    marks = np.zeros(frames, np.int64)
    sent = [0]

    class MarkedFramePublisher(driver_node.FramePublisher):
        def put(self, message) -> None:
            super().put(message)
            marks[sent[0]] = time.thread_time_ns()
            sent[0] += 1

    plain = driver_node.FramePublisher
    driver_node.FramePublisher = MarkedFramePublisher
    try:
        driver_node.DriverNode(session, load_rig(RIG_FILE), PooledCamera("cam0", pool, fps)).run(max_frames=frames)
    finally:
        driver_node.FramePublisher = plain
    return np.diff(marks[WARMUP_FRAMES:sent[0]])


def in_a_thread(mode, *args) -> np.ndarray:
    """`mode(*args)` run on a thread of its own, as a driver node runs."""
    result = {}
    thread = threading.Thread(target=lambda: result.update(ns=mode(*args)))
    thread.start()
    thread.join()
    return result["ns"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pairs", type=int, default=6)
    parser.add_argument("--frames", type=int, default=240, help="frames per phase")
    parser.add_argument("--fps", type=float, default=30.0)
    args = parser.parse_args()
    from camnet.bus.session import BusOptions, open_session

    pool = render_pool(0, 1280, 1024)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    received = [0]
    print(f"Publishing thread CPU per frame (us, median of a phase of {args.frames} frames at {args.fps:g} fps, "
          "1280x1024 mono8)")
    print(f"{'pair':>4}  {'first':<7}{'camnet':>8}{'bare':>8}{'ratio':>8}")
    ratios = []
    with open_session(BusOptions(listen=(endpoint,))) as listener, \
            open_session(BusOptions(connect=(endpoint,))) as session:
        subscriber = listener.declare_subscriber("camnet/**", lambda sample: received.__setitem__(0, received[0] + 1))
        time.sleep(1.0)  # the subscription reaches the publishing peer
        for pair in range(args.pairs):
            order = (camnet, bare) if pair % 2 == 0 else (bare, camnet)
            medians = {}
            for mode in order:
                per_frame_ns = in_a_thread(mode, session, pool, args.frames, args.fps)
                medians[mode.__name__] = float(np.median(per_frame_ns)) / 1e3
            ratios.append(medians["camnet"] / medians["bare"] - 1)
            print(f"{pair + 1:>4}  {order[0].__name__:<7}{medians['camnet']:>8.1f}{medians['bare']:>8.1f}"
                  f"{ratios[-1]:>+8.1%}", flush=True)
        subscriber.undeclare()
    q1, median, q3 = np.percentile(ratios, [25, 50, 75])
    print(f"camnet over bare: median {median:+.1%}, quartiles {q1:+.1%} to {q3:+.1%}, "
          f"range {min(ratios):+.1%} to {max(ratios):+.1%}; {received[0]} frames received")
    return 0


if __name__ == "__main__":
    sys.exit(main())
