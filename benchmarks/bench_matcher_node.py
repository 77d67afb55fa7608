"""The matcher node on a live simulated rig: matching time, frame sets, drops, latency.

Runs the rig's sim drivers as `camnet driver sim` processes and the matcher
node in this process, joined on loopback Zenoh (an explicit free port, no
scouting), for a while, and prints one row per detector:

- ms/set: median time to match and pool one frame set (the node's own timing);
- sets/s: frame sets matched per second; partial: sets without a late camera;
- dropped: frames the node did not match (it keeps only the latest ones);
- latency: publication time minus capture time of the newest pooled set, median.

    python benchmarks/bench_matcher_node.py [--rig config/sim.yaml] [--seconds 20]
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from camnet.services.matcher import MatcherNode, MatcherNodeConfig

from camnet.bus import keys
from camnet.bus.session import BusOptions, open_session
from camnet.io.messages import ObservationsMessage, decode_observations_message
from camnet.io.rig import load_rig
from camnet.matching.features import Detector

ROOT = Path(__file__).resolve().parents[1]


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def run_once(rig_path: str, rig, config: MatcherNodeConfig, seconds: float) -> dict:
    endpoint = free_endpoint()
    with open_session(BusOptions(listen=(endpoint,))) as session:
        node = MatcherNode(session, rig, config=config)
        latencies_ms, match_ms = [], []
        session.declare_subscriber(
            keys.observations(rig.name),
            lambda s: latencies_ms.append(_latency_ms(decode_observations_message(s.payload.to_bytes()))))
        worker = threading.Thread(target=node.run)
        worker.start()
        drivers = [subprocess.Popen([sys.executable, "-m", "camnet", "driver", "sim", "--rig", rig_path,
                                     "--camera", entry.id, "--connect", endpoint], cwd=ROOT)
                   for entry in rig.cameras]
        try:
            end = time.monotonic() + seconds
            seen = 0
            while time.monotonic() < end:
                time.sleep(0.05)
                stats = node.engine.stats
                if stats.frame_sets_matched > seen:
                    seen = stats.frame_sets_matched
                    match_ms.append(1e3 * stats.last_match_s)
                    print(f"\r  {config.detector}: {seen} frame sets, pool {stats.tracks_pooled}", end="", flush=True)
        finally:
            for driver in drivers:
                driver.terminate()
            for driver in drivers:
                driver.wait(timeout=10)
            node.stop.set()
            worker.join()
        print("\r", end="")
        sync, stats = node.sync_counts(), node.engine.stats
        return {"ms_per_set": float(np.median(match_ms)) if match_ms else float("nan"),
                "sets_per_s": stats.frame_sets_matched / seconds, "partial": sync.partial_sets,
                "dropped": sync.dropped, "frames": sync.received,
                "latency_ms": float(np.median(latencies_ms)) if latencies_ms else float("nan"),
                "tracks": stats.tracks_pooled}


def _latency_ms(message: ObservationsMessage) -> float:
    return (message.published_ns - message.latest_capture_ns) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rig", default=str(ROOT / "config" / "sim.yaml"))
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    rig = load_rig(args.rig)
    sizes = {f"{e.config.width}x{e.config.height}@{e.config.fps:g}" for e in rig.cameras}
    print(f"rig {rig.name}: {len(rig.cameras)} cameras {', '.join(sorted(sizes))}; {args.seconds:g} s per row")
    print(f"{'detector':8} {'ms/set':>7} {'sets/s':>7} {'partial':>8} {'dropped':>8} {'frames':>7} "
          f"{'latency ms':>11} {'tracks':>7}")
    for detector in Detector:
        r = run_once(args.rig, rig, MatcherNodeConfig(detector=detector), args.seconds)
        print(f"{detector:8} {r['ms_per_set']:7.0f} {r['sets_per_s']:7.2f} {r['partial']:8d} {r['dropped']:8d} "
              f"{r['frames']:7d} {r['latency_ms']:11.0f} {r['tracks']:7d}")


if __name__ == "__main__":
    main()
