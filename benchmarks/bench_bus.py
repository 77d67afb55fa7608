#!/usr/bin/env python3
"""Bus benchmark: simulated cameras through Zenoh on loopback, camnet vs bare Zenoh.

The camera processes (benchmarks/sim_publishers.py) run either the real
driver node ("camnet") or a bare Zenoh publisher of the same bytes ("bare"),
at the same rate; both copy each frame's pixels from the same pre-rendered
pool into a reused message, the one copy a camera makes, so the capture is
counted in both. "bare-ready" re-sends ready-made bytes without any capture
(a floor, 60-s table only). One subscriber process (this one) receives every frame:
camnet's through `camnet.bus.receiver.FrameReceiver` (copied out of Zenoh,
decoded, sequence checked), bare's copied out of Zenoh as bytes.

Latency is timed the same way for both, on the host's CLOCK_REALTIME, from
just before `put` in the publisher to the subscriber's callback (put->recv).
What each side adds is in its own column: capture->put is camnet's frame
encoding and driver loop (bare stamps its frames just before put: about zero), and
recv->ready is the subscriber's copy out of Zenoh plus, for camnet, decoding.

    python benchmarks/bench_bus.py --seconds 60          # the table
    python benchmarks/bench_bus.py --sweep               # highest rate x cameras without loss
    python benchmarks/bench_bus.py --alternate 12        # publisher CPU, camnet and bare taking turns
"""

from __future__ import annotations

import argparse
import struct
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sim_publishers import (  # noqa: E402
    SEQ_OFFSET,
    camera_id,
    render_pool,
    rig_name,
    run_publishers,
)

from camnet.testing.ports import free_port  # noqa: E402

_SEQ = struct.Struct("<Q")
# Frames of the first second are sent but not scored, in both modes: the first put of each
# new publisher waits for routes to settle (tens of ms), which says nothing about steady state.
WARMUP_S = 1.0


@dataclass
class PhaseResult:
    mode: str
    cameras: int
    fps: float
    seconds: float
    sent: int
    received: int
    lost: int  # sent but never received
    received_all: int  # warm-up included, for the throughput
    received_bytes: int  # warm-up included
    wall_s: float
    put_to_recv_ms: np.ndarray  # one value per received frame
    capture_to_put_ms: np.ndarray  # one value per sent frame
    in_put_ms: np.ndarray  # time inside Zenoh's put, one value per sent frame
    recv_to_ready_ms: np.ndarray  # one value per received frame
    publisher_cpu: float  # mean over cameras, 1.0 = one core; scored frames only (PutLog.steady_cpu)
    subscriber_cpu: float  # the whole subscriber process
    behind: bool  # a publisher could not keep the rate

    @property
    def frames_per_s(self) -> float:
        return self.received_all / self.wall_s

    @property
    def mb_per_s(self) -> float:
        return self.received_bytes / self.wall_s / 1e6


def run_phase(mode: str, *, cameras: int, fps: float, seconds: float, size=(1280, 1024),
              progress: bool = True) -> PhaseResult:
    """One phase: `cameras` publishers of `mode` at `fps` for `seconds`, one subscriber here."""
    from camnet.bus import keys
    from camnet.bus.receiver import FrameReceiver
    from camnet.bus.session import BusOptions, open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    receiver = FrameReceiver()
    lock = threading.Lock()
    # camera id -> [(seq, receipt ns, ready ns)]
    received: dict[str, list[tuple[int, int, int]]] = {}
    received_bytes = [0]

    def record(camera: str, seq: int, receipt_ns: int, size_bytes: int) -> None:
        ready_ns = time.time_ns()
        with lock:
            received.setdefault(camera, []).append((seq, receipt_ns, ready_ns))
            received_bytes[0] += size_bytes

    if mode.startswith("camnet"):
        def on_sample(sample):
            receipt_ns = time.time_ns()
            payload = sample.payload.to_bytes()
            frame = receiver.accept(payload)
            if frame is not None:
                record(frame.camera_id, frame.seq, receipt_ns, len(payload))
    else:
        def on_sample(sample):
            receipt_ns = time.time_ns()
            payload = sample.payload.to_bytes()
            seq, = _SEQ.unpack_from(payload, SEQ_OFFSET)
            record(str(sample.key_expr).split("/")[-2], seq, receipt_ns, len(payload))

    def report(elapsed_s: float) -> None:
        with lock:
            got = sum(len(v) for v in received.values())
        print(f"  [{mode} {cameras}x{fps:g} fps] {elapsed_s:5.1f}/{seconds:g} s, {got} frames "
              "received", file=sys.stderr, flush=True)

    with open_session(BusOptions(listen=(endpoint,))) as session:
        sub = session.declare_subscriber(keys.all_frames(rig_name(mode)), on_sample)
        wall0 = time.monotonic()
        results, sub_cpu = run_publishers(session, endpoint, mode=mode, cameras=cameras, fps=fps,
                                          seconds=seconds + WARMUP_S, size=size,
                                          progress=report if progress else None,
                                          steady_from=round(WARMUP_S * fps))
        wall_s = time.monotonic() - wall0
        sub.undeclare()
    latencies, encode, in_put, handling, sent, got = [], [], [], [], 0, 0
    first_scored = round(WARMUP_S * fps)
    for r in results.values():
        scored = r.puts[r.puts[:, 0] >= first_scored]
        puts = {int(seq): put_ns for seq, _, put_ns, _ in scored}
        seen = [row for row in received.get(camera_id(r.index), []) if row[0] >= first_scored]
        latencies += [(receipt - puts[seq]) / 1e6 for seq, receipt, _ in seen if seq in puts]
        handling += [(ready - receipt) / 1e6 for _, receipt, ready in seen]
        encode.append((scored[:, 2] - scored[:, 1]) / 1e6)
        in_put.append(scored[:, 3] / 1e6)
        sent += len(scored)
        got += len(seen)
    publish_wall_s = max(r.wall_s for r in results.values())
    behind = any(r.sent / r.wall_s < 0.98 * fps for r in results.values() if r.wall_s > 0)
    received_all = sum(len(rows) for rows in received.values())
    return PhaseResult(mode, cameras, fps, seconds, sent, got, sent - got, received_all,
                       received_bytes[0],
                       publish_wall_s if publish_wall_s > 0 else wall_s,
                       np.array(latencies or [np.nan]), np.concatenate(encode),
                       np.concatenate(in_put),
                       np.array(handling or [np.nan]),
                       float(np.nanmean([r.steady_cpu for r in results.values()])), sub_cpu,
                       behind)


def print_table(rows: list[PhaseResult]) -> None:
    print(f"{'':<10}{'sent':>7}{'recv':>7}{'lost':>6}{'frames/s':>10}{'MB/s':>8}"
          f"{'capture->put':>14}{'in put':>8}{'put->recv p50':>15}{'p99':>7}{'recv->ready':>13}"
          f"{'pub CPU/cam':>13}{'sub CPU/cam':>13}")
    for r in rows:
        print(f"{r.mode:<10}{r.sent:>7}{r.received:>7}{r.lost:>6}{r.frames_per_s:>10.1f}"
              f"{r.mb_per_s:>8.1f}{np.median(r.capture_to_put_ms):>14.2f}"
              f"{np.median(r.in_put_ms):>8.2f}"
              f"{np.nanmedian(r.put_to_recv_ms):>15.2f}"
              f"{np.nanpercentile(r.put_to_recv_ms, 99):>7.2f}"
              f"{np.nanmedian(r.recv_to_ready_ms):>13.2f}{r.publisher_cpu:>12.1%}"
              f"{r.subscriber_cpu / r.cameras:>12.1%}")
    print("(times in ms, medians unless p99; CPU: process CPU time over wall time, 100% = one "
          "core; sub CPU/cam: the subscriber process over the number of cameras)")


def print_overhead(camnet: PhaseResult, bare: PhaseResult) -> None:
    def ratio(a: float, b: float) -> str:
        return f"{a / b - 1:+.0%}" if b > 0 else "n/a"

    c50, b50 = np.nanmedian(camnet.put_to_recv_ms), np.nanmedian(bare.put_to_recv_ms)
    c99, b99 = np.nanpercentile(camnet.put_to_recv_ms, 99), np.nanpercentile(bare.put_to_recv_ms, 99)
    print(f"camnet vs {bare.mode}: throughput {ratio(camnet.frames_per_s, bare.frames_per_s)}, "
          f"put->recv p50 {ratio(c50, b50)}, p99 {ratio(c99, b99)}, publisher CPU "
          f"{ratio(camnet.publisher_cpu, bare.publisher_cpu)}, subscriber CPU "
          f"{ratio(camnet.subscriber_cpu, bare.subscriber_cpu)}")
    end_to_end = (np.median(camnet.capture_to_put_ms) + c50 + np.nanmedian(camnet.recv_to_ready_ms),
                  np.median(bare.capture_to_put_ms) + b50 + np.nanmedian(bare.recv_to_ready_ms))
    print(f"capture->ready p50 (sum of the medians): camnet {end_to_end[0]:.2f} ms, {bare.mode} "
          f"{end_to_end[1]:.2f} ms ({ratio(*end_to_end)})")


def frame_costs(size=(1280, 1024), repeats: int = 200) -> dict[str, float]:
    """Median ms per call of camnet's per-frame work, measured in this process alone."""
    import zenoh

    from camnet.bus.frame import Frame, decode_frame, encode_frame

    frame = Frame("cam0", 0, time.time_ns(), "mono8", render_pool(0, *size)[0])
    data = encode_frame(frame)
    zbytes = zenoh.ZBytes(data)

    def median_ms(fn) -> float:
        fn()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter_ns()
            fn()
            times.append(time.perf_counter_ns() - t0)
        return float(np.median(times)) / 1e6

    return {"encode_frame": median_ms(lambda: encode_frame(frame)),
            "Zenoh payload to bytes": median_ms(zbytes.to_bytes),
            "decode_frame": median_ms(lambda: decode_frame(data))}


def alternate(pairs: int, *, cameras: int, fps: float, seconds: float) -> list[float]:
    """Publisher CPU of camnet over bare Zenoh, `pairs` times, the two taking turns in short phases.

    The order alternates (camnet first, then bare first, ...), so that a load
    rising or falling through the run favours neither; each pair's ratio is
    printed, then their median and spread. A shared machine's load moves a
    single long phase by tens of percent; the median of many short pairs does not.
    Returns the ratios (camnet / bare - 1).
    """
    print(f"\nAlternating ({pairs} pairs of {seconds:g}-s phases, {cameras} x {fps:g} fps, 1280x1024 mono8)")
    print(f"{'pair':>4}  {'first':<7}{'camnet CPU/cam':>15}{'bare CPU/cam':>14}{'ratio':>8}{'lost c/b':>10}",
          flush=True)
    ratios = []
    for pair in range(pairs):
        order = ("camnet", "bare") if pair % 2 == 0 else ("bare", "camnet")
        runs = {mode: run_phase(mode, cameras=cameras, fps=fps, seconds=seconds, progress=False) for mode in order}
        camnet, bare = runs["camnet"], runs["bare"]
        ratios.append(camnet.publisher_cpu / bare.publisher_cpu - 1)
        print(f"{pair + 1:>4}  {order[0]:<7}{camnet.publisher_cpu:>14.2%}{bare.publisher_cpu:>13.2%}"
              f"{ratios[-1]:>+8.1%}{f'{camnet.lost}/{bare.lost}':>10}", flush=True)
    q1, median, q3 = np.percentile(ratios, [25, 50, 75])
    within = sum(r <= 0.10 for r in ratios)
    print(f"publisher CPU, camnet over bare: median {median:+.1%}, quartiles {q1:+.1%} to {q3:+.1%}, "
          f"range {min(ratios):+.1%} to {max(ratios):+.1%}; {within} of {pairs} pairs at most +10%")
    return ratios


SWEEP = ((4, (30, 60, 90, 120, 150, 180, 240, 300, 360, 480)), (8, (30, 60)), (12, (30,)))


def sweep(seconds: float) -> None:
    """Step the rate up until frames are lost, camnet and bare Zenoh back to back at each step.

    Each mode stops at its first loss; running the two modes at the same step
    one after the other keeps a shared machine's drifting load from favouring either.
    """
    print(f"\nSweep ({seconds:g} s per point, 1280x1024 mono8)")
    print(f"{'mode':<8}{'cameras':>8}{'fps':>6}{'frames/s':>10}{'lost':>6}{'behind':>8}"
          f"{'p99 ms':>8}{'pub CPU/cam':>13}")
    best: dict[str, tuple[int, float]] = {}
    for cameras, fps_list in SWEEP:
        going = ["camnet", "bare"]
        for fps in fps_list:
            for mode in list(going):
                r = run_phase(mode, cameras=cameras, fps=fps, seconds=seconds, progress=False)
                print(f"{mode:<8}{cameras:>8}{fps:>6}{r.frames_per_s:>10.0f}{r.lost:>6}"
                      f"{'yes' if r.behind else 'no':>8}"
                      f"{np.nanpercentile(r.put_to_recv_ms, 99):>8.1f}{r.publisher_cpu:>12.1%}",
                      flush=True)
                if r.lost or r.behind:
                    going.remove(mode)
                elif cameras * fps > np.prod(best.get(mode, (0, 0))):
                    best[mode] = (cameras, fps)
    for mode in ("camnet", "bare"):
        if mode in best:
            cameras, fps = best[mode]
            print(f"highest without loss, {mode}: {cameras} cameras x {fps} fps = "
                  f"{cameras * fps} frames/s ({cameras * fps * 1280 * 1024 / 1e6:.0f} MB/s)")
        else:
            print(f"highest without loss, {mode}: none")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="duration per phase")
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--sweep", action="store_true", help="also run the sweep")
    parser.add_argument("--sweep-only", action="store_true", help="only run the sweep")
    parser.add_argument("--sweep-seconds", type=float, default=5.0)
    parser.add_argument("--alternate", type=int, default=0, metavar="PAIRS",
                        help="only compare publisher CPU: camnet and bare taking turns, PAIRS times")
    parser.add_argument("--alternate-seconds", type=float, default=5.0, help="duration per phase when alternating")
    args = parser.parse_args()
    if args.alternate:
        alternate(args.alternate, cameras=args.cameras, fps=args.fps, seconds=args.alternate_seconds)
        return 0
    if not args.sweep_only:
        print(f"{args.cameras} cameras, 1280x1024 mono8, {args.fps:g} fps, {args.seconds:g} s "
              "per phase; latency from just before put to receipt", flush=True)
        camnet = run_phase("camnet", cameras=args.cameras, fps=args.fps, seconds=args.seconds)
        bare = run_phase("bare", cameras=args.cameras, fps=args.fps, seconds=args.seconds)
        ready = run_phase("bare-ready", cameras=args.cameras, fps=args.fps, seconds=args.seconds)
        print()
        print_table([camnet, bare, ready])
        print_overhead(camnet, bare)
        print_overhead(camnet, ready)
        costs = frame_costs()
        print("camnet's own work per frame, alone in one process: " +
              ", ".join(f"{name} {ms:.3f} ms" for name, ms in costs.items()))
    if args.sweep or args.sweep_only:
        sweep(args.sweep_seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
