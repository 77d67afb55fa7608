#!/usr/bin/env python3
"""Bus benchmark: simulated cameras through Zenoh on loopback, camnet vs bare Zenoh.

Each camera is its own process. In the camnet phase it is a real driver node
(drivers.node.DriverNode: frame encoding, publish with congestion control
DROP, liveliness, statistics) fed by a camera that cycles through frames
pre-rendered by the sim renderer, so that rendering cost does not hide the
bus cost. The bare phase publishes the same encoded bytes with session.put
from the same kind of process. One subscriber process (this one) decodes
every camnet frame (FrameReceiver) and measures capture-to-receipt latency
on the host's CLOCK_REALTIME, which all processes share.

    python benchmarks/bench_bus.py --seconds 60          # the table
    python benchmarks/bench_bus.py --sweep               # highest fps x cameras without loss
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import queue
import socket
import struct
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

RIG_FILE = Path(__file__).resolve().parent.parent / "config" / "sim.yaml"
POOL_FRAMES = 4
_BARE_HEADER = struct.Struct("<IQQ")  # camera index, seq, publish timestamp_ns


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def render_pool(camera_index: int, width: int, height: int) -> list[np.ndarray]:
    """A few frames of the sim rig's camera (cycled through by the publisher)."""
    from camnet.render import Renderer
    from camnet.rig import load_rig
    from camnet.scene import Scene

    rig = load_rig(RIG_FILE)
    entry = rig.cameras[camera_index % len(rig.cameras)]
    cam = entry.config.camera(entry.id)
    if (width, height) != (cam.width, cam.height):
        from dataclasses import replace

        cam = replace(cam, width=width, height=height)
    renderer = Renderer(cam)
    scene = Scene(rig.scene)
    rng = np.random.default_rng(camera_index)
    return [renderer.render(scene.quads(k / 30), noise_sigma_dn=2.0, rng=rng)
            for k in range(POOL_FRAMES)]


class PooledCamera:
    """A Camera (drivers.base protocol) replaying pre-rendered frames at `fps`."""

    def __init__(self, camera_id: str, pool: list[np.ndarray], fps: float) -> None:
        from drivers.base import CameraInfo

        self.camera_id = camera_id
        self.pool = pool
        self.fps = fps
        self.seq = 0
        self.t0_ns = 0
        h, w = pool[0].shape
        self.info = CameraInfo(camera_id, "sim", w, h, "mono8", fps, "pooled sim frames")
        self.dropped = 0

    def __enter__(self):
        self.t0_ns = time.monotonic_ns()
        return self

    def __exit__(self, *exc):
        return None

    def read(self, *, timeout_s: float = 1.0):
        from camnet.frame import Frame

        due_ns = self.t0_ns + int(self.seq * 1e9 / self.fps)
        wait_s = (due_ns - time.monotonic_ns()) / 1e9
        if wait_s > 0:
            time.sleep(wait_s)
        frame = Frame(self.camera_id, self.seq, time.time_ns(), "mono8",
                      self.pool[self.seq % len(self.pool)])
        self.seq += 1
        return frame


def publisher(mode: str, index: int, endpoint: str, fps: float, n_frames: int, size, start,
              results) -> None:
    from camnet.bus import BusOptions, open_session
    from camnet.frame import Frame, encode_frame
    from camnet.rig import load_rig

    pool = render_pool(index, *size)
    camera_id = f"cam{index}"
    with open_session(BusOptions(connect=(endpoint,))) as session:
        if mode == "camnet":
            from drivers.node import DriverNode

            node = DriverNode(session, load_rig(RIG_FILE), PooledCamera(camera_id, pool, fps))
            start.wait()
            cpu0, wall0 = time.process_time(), time.monotonic()
            node.run(max_frames=n_frames)
            sent = node.frames_sent
        else:
            import zenoh

            from camnet import keys

            payloads = [bytearray(encode_frame(Frame(camera_id, 0, 0, "mono8", img)))
                        for img in pool]
            pub = session.declare_publisher(keys.frame("bench", camera_id),
                                            congestion_control=zenoh.CongestionControl.DROP)
            start.wait()
            cpu0, wall0 = time.process_time(), time.monotonic()
            t0_ns = time.monotonic_ns()
            for seq in range(n_frames):
                due_ns = t0_ns + int(seq * 1e9 / fps)
                wait_s = (due_ns - time.monotonic_ns()) / 1e9
                if wait_s > 0:
                    time.sleep(wait_s)
                payload = payloads[seq % len(payloads)]
                _BARE_HEADER.pack_into(payload, 0, index, seq, time.time_ns())
                pub.put(bytes(payload))
            sent = n_frames
        cpu_s, wall_s = time.process_time() - cpu0, time.monotonic() - wall0
        time.sleep(0.5)  # let the last frames drain before the session closes
    results.put((index, sent, cpu_s, wall_s))


@dataclass
class CameraResult:
    sent: int
    received: int
    lost: int
    gaps: int
    latency_median_ms: float
    latency_p99_ms: float
    cpu_fraction: float


def run_phase(mode: str, *, cameras: int, fps: float, seconds: float, size=(1280, 1024),
              progress: bool = True) -> tuple[dict[int, CameraResult], float]:
    """Per-camera results and the subscriber's CPU fraction for one phase."""
    from camnet import keys
    from camnet.bus import BusOptions, open_session
    from camnet.receiver import FrameReceiver

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    n_frames = int(round(fps * seconds))
    lat: dict[int, list[float]] = {i: [] for i in range(cameras)}
    bare_seqs: dict[int, list[int]] = {i: [] for i in range(cameras)}
    receiver = FrameReceiver()
    ctx = mp.get_context("spawn")
    start = ctx.Event()
    results = ctx.Queue()
    rig_name = "sim" if mode == "camnet" else "bench"
    with open_session(BusOptions(listen=(endpoint,))) as session:
        if mode == "camnet":
            def on_sample(sample):
                frame = receiver.accept(sample.payload.to_bytes())
                now = time.time_ns()
                if frame is not None:
                    lat[int(frame.camera_id[3:])].append((now - frame.timestamp_ns) / 1e6)
        else:
            def on_sample(sample):
                payload = sample.payload.to_bytes()
                now = time.time_ns()
                index, seq, sent_ns = _BARE_HEADER.unpack_from(payload, 0)
                lat[index].append((now - sent_ns) / 1e6)
                bare_seqs[index].append(seq)
        sub = session.declare_subscriber(keys.all_frames(rig_name), on_sample)
        procs = [ctx.Process(target=publisher, args=(mode, i, endpoint, fps, n_frames, size,
                                                     start, results)) for i in range(cameras)]
        for p in procs:
            p.start()
        deadline = time.monotonic() + 60
        while len(list(session.info.peers_zid())) < cameras and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)  # subscriptions propagate to the new peers
        cpu0, wall0 = time.process_time(), time.monotonic()
        start.set()
        done = {}
        next_report = time.monotonic() + 5
        while len(done) < cameras:
            try:
                index, sent, cpu_s, wall_s = results.get(timeout=0.5)
                done[index] = (sent, cpu_s, wall_s)
            except queue.Empty:
                pass  # still running: report progress below
            if progress and time.monotonic() >= next_report:
                got = sum(len(v) for v in lat.values())
                print(f"  [{mode}] {time.monotonic() - wall0:5.1f}/{seconds:.0f} s, "
                      f"{got} frames received", file=sys.stderr, flush=True)
                next_report += 5
            if time.monotonic() > wall0 + seconds + 120:
                raise RuntimeError("publishers did not finish")
        sub_cpu = (time.process_time() - cpu0) / (time.monotonic() - wall0)
        sub.undeclare()
    for p in procs:
        p.join(timeout=10)
    out = {}
    for i in range(cameras):
        sent, cpu_s, wall_s = done[i]
        values = np.array(lat[i]) if lat[i] else np.array([np.nan])
        if mode == "camnet":
            counts = receiver.counts().get(f"cam{i}")
            gaps = counts.dropped if counts else 0
        else:
            seqs = bare_seqs[i]
            gaps = (seqs[-1] - seqs[0] + 1 - len(seqs)) if seqs else 0
        out[i] = CameraResult(sent, len(lat[i]), sent - len(lat[i]), gaps,
                              float(np.median(values)), float(np.percentile(values, 99)),
                              cpu_s / wall_s if wall_s > 0 else float("nan"))
    return out, sub_cpu


def print_table(title: str, results: dict[int, CameraResult], sub_cpu: float) -> None:
    print(f"\n{title}")
    print(f"{'camera':<8}{'sent':>7}{'recv':>7}{'lost':>6}{'gaps':>6}{'lat p50 ms':>12}"
          f"{'lat p99 ms':>12}{'CPU/cam':>9}")
    for i, r in sorted(results.items()):
        print(f"cam{i:<5}{r.sent:>7}{r.received:>7}{r.lost:>6}{r.gaps:>6}"
              f"{r.latency_median_ms:>12.2f}"
              f"{r.latency_p99_ms:>12.2f}{r.cpu_fraction:>8.1%}")
    print(f"subscriber CPU: {sub_cpu:.1%}   (gaps: lost inside the stream, the rest of "
          "'lost' at its start or end)")


def summary(results: dict[int, CameraResult]) -> tuple[float, float, float, int]:
    lat50 = float(np.median([r.latency_median_ms for r in results.values()]))
    lat99 = float(np.max([r.latency_p99_ms for r in results.values()]))
    cpu = float(np.mean([r.cpu_fraction for r in results.values()]))
    lost = sum(r.lost for r in results.values())
    return lat50, lat99, cpu, lost


def sweep(seconds: float) -> None:
    print(f"\nSweep ({seconds:.0f} s per point, 1280x1024 mono8, camnet driver nodes)")
    print(f"{'cameras':>8}{'fps':>6}{'frames/s':>10}{'lost':>6}{'lat p99 ms':>12}{'CPU/cam':>9}")
    best = None
    for cameras, fps_list in ((4, (30, 60, 90, 120, 180)), (8, (30, 60)), (12, (30,))):
        for fps in fps_list:
            results, _ = run_phase("camnet", cameras=cameras, fps=fps, seconds=seconds,
                                   progress=False)
            _, lat99, cpu, lost = summary(results)
            keeps_up = all(r.sent == int(round(fps * seconds)) for r in results.values())
            print(f"{cameras:>8}{fps:>6}{cameras * fps:>10}{lost:>6}{lat99:>12.1f}{cpu:>8.1%}",
                  flush=True)
            if lost == 0 and keeps_up and (best is None or cameras * fps > best[0] * best[1]):
                best = (cameras, fps)
            if lost:
                break
    if best:
        print(f"highest without loss: {best[0]} cameras x {best[1]} fps = "
              f"{best[0] * best[1]} frames/s ({best[0] * best[1] * 1.31:.0f} MB/s)")
    else:
        print("no configuration ran without loss")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="duration per phase")
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--sweep", action="store_true", help="also run the sweep")
    parser.add_argument("--sweep-only", action="store_true", help="only run the sweep")
    parser.add_argument("--sweep-seconds", type=float, default=5.0)
    args = parser.parse_args()
    if not args.sweep_only:
        print(f"{args.cameras} cameras, 1280x1024 mono8, {args.fps:g} fps, {args.seconds:g} s "
              "per phase", flush=True)
        camnet_res, camnet_sub = run_phase("camnet", cameras=args.cameras, fps=args.fps,
                                           seconds=args.seconds)
        bare_res, bare_sub = run_phase("bare", cameras=args.cameras, fps=args.fps,
                                       seconds=args.seconds)
        print_table("camnet (driver node -> FrameReceiver)", camnet_res, camnet_sub)
        print_table("bare Zenoh (put/subscribe of the same bytes)", bare_res, bare_sub)
        c50, c99, ccpu, _ = summary(camnet_res)
        b50, b99, bcpu, _ = summary(bare_res)
        print(f"\ncamnet overhead: latency p50 {c50:.2f} vs {b50:.2f} ms "
              f"({(c50 / b50 - 1):+.0%}), p99 {c99:.2f} vs {b99:.2f} ms; "
              f"publisher CPU {ccpu:.1%} vs {bcpu:.1%} ({(ccpu / bcpu - 1):+.0%})")
    if args.sweep or args.sweep_only:
        sweep(args.sweep_seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
