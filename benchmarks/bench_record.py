#!/usr/bin/env python3
"""Recording benchmark: simulated cameras -> `camnet.services.recorder.Recorder` -> MCAP, then replay.

Each camera is its own process running the real driver node on frames
pre-rendered by the sim renderer (benchmarks/sim_publishers.py, as in
bench_bus.py). The recorder runs in this process with its own Zenoh session;
its CPU is this process's CPU time (Zenoh's receive threads included) over
wall time. Then the file is replayed
as fast as possible (`camnet.services.replayer.Replayer`, congestion control BLOCK)
to a subscriber in another session that counts the frames.

    python benchmarks/bench_record.py --seconds 20                # 4 x 1280x1024 @ 30 fps
    python benchmarks/bench_record.py --compression zstd lz4 none
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from sim_publishers import run_publishers  # noqa: E402  (the same camera processes)

from camnet.testing.ports import free_port  # noqa: E402


def record(compression: str, *, cameras: int, fps: float, seconds: float, size, directory: Path):
    from camnet.services.recorder import ChunkCompression, Recorder, RecorderConfig

    from camnet.bus.session import BusOptions, open_session

    path = directory / f"bench-{compression}.mcap"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(BusOptions(listen=(endpoint,))) as session:
        recorder = Recorder(session, RecorderConfig(rig="sim", path=path, compression=ChunkCompression(compression)))
        out = {}
        thread = threading.Thread(target=lambda: out.setdefault("summary", recorder.run()))
        thread.start()
        try:
            results, cpu = run_publishers(
                session, endpoint, mode="camnet", cameras=cameras, fps=fps, seconds=seconds,
                size=size, progress=lambda elapsed_s: print(
                    f"  [{compression}] {elapsed_s:5.1f}/{seconds:.0f} s", file=sys.stderr,
                    flush=True))
            time.sleep(0.5)
        finally:
            recorder.stop.set()
            thread.join()
    sent = {index: r.sent for index, r in results.items()}
    return path, out["summary"], sum(sent.values()), cpu


def replay_fast(path: Path) -> tuple[int, float]:
    """(frames received, seconds) replaying `path` as fast as possible to one subscriber."""
    from camnet.services.replayer import Replayer, ReplayOptions

    from camnet.bus import keys
    from camnet.bus.session import BusOptions, open_session
    from camnet.io.session_file import open_session_file

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    count = [0]
    with open_session(BusOptions(listen=(endpoint,))) as sub_bus, \
            open_session(BusOptions(connect=(endpoint,))) as pub_bus:
        sub = sub_bus.declare_subscriber(keys.all_frames("sim"),
                                         lambda s: count.__setitem__(0, count[0] + 1))
        replayer = Replayer(pub_bus, open_session_file(path), options=ReplayOptions(rate=0))
        t0 = time.monotonic()
        summary = replayer.run()
        while count[0] < sum(summary.frames.values()) and time.monotonic() < t0 + 600:
            time.sleep(0.01)
        elapsed = time.monotonic() - t0
        sub.undeclare()
    return count[0], elapsed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--cameras", type=int, default=4)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--compression", nargs="+", default=["zstd", "lz4", "none"])
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: a temp dir)")
    args = parser.parse_args()
    size = (1280, 1024)
    print(f"{args.cameras} cameras, {size[0]}x{size[1]} mono8, {args.fps:g} fps, {args.seconds:g} s")
    rows = []
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        for compression in args.compression:
            path, summary, sent, cpu = record(compression, cameras=args.cameras, fps=args.fps,
                                              seconds=args.seconds, size=size, directory=Path(tmp))
            frames = sum(t.frames for t in summary.cameras.values())
            missing = sum(t.missing for t in summary.cameras.values())
            payload = sum(t.payload_bytes for t in summary.cameras.values())
            received, replay_s = replay_fast(path)
            rows.append((compression, sent, frames, missing, summary.queue_overflows, cpu,
                         summary.file_bytes / 1e6, summary.file_bytes / payload,
                         received / replay_s, received * payload / frames / 1e6 / replay_s))
            path.unlink()
    print(f"\n{'compression':<12}{'sent':>7}{'recorded':>9}{'missing':>8}{'q.full':>7}{'CPU':>7}"
          f"{'file MB':>9}{'ratio':>7}{'replay fps':>11}{'replay MB/s':>12}")
    for c, sent, frames, missing, overflows, cpu, mb, ratio, rfps, rmbs in rows:
        print(f"{c:<12}{sent:>7}{frames:>9}{missing:>8}{overflows:>7}{cpu:>7.0%}{mb:>9.0f}"
              f"{ratio:>7.2f}{rfps:>11.0f}{rmbs:>12.0f}")
    print("(recorded frames include none from before the start; CPU: recorder process / wall, "
          "100% = one core; replay: as fast as possible to one subscriber)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
