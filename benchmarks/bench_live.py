#!/usr/bin/env python3
"""The live network on a simulated rig: accuracy against elapsed time, and capture-to-calibration latency.

Runs `camnet up RIG` (drivers, matcher, calibrator as processes on loopback
Zenoh, simulated time on the wall clock) and tabulates every calibration it
publishes: when it came, how long after the newest frame set it includes
was captured, and its errors against the simulation's ground truth.

    python benchmarks/bench_live.py [--rig config/sim.yaml] [--seconds 120] [--detector sift]
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from camnet.matching.features import Detector

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rig", default=str(ROOT / "config" / "sim.yaml"))
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--detector", type=Detector, choices=list(Detector), default=Detector.SIFT)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="camnet-bench-live-") as tmp:
        progress = Path(tmp) / "progress.jsonl"
        command = [sys.executable, "-m", "camnet.cli", "up", args.rig, "--duration-s", str(args.seconds),
                   "--detector", str(args.detector), "--run-dir", str(Path(tmp) / "run"),
                   "--progress-jsonl", str(progress), "--listen", f"tcp/127.0.0.1:{free_port()}"]
        print(f"running {' '.join(command[3:])} ...", file=sys.stderr, flush=True)
        # camnet up prints its own progress line per calibration on stdout; pass it through.
        proc = subprocess.run(command, stdout=sys.stderr, timeout=args.seconds + 120)
        if proc.returncode != 0:
            print(f"camnet up failed with status {proc.returncode}", file=sys.stderr)
            return 1
        rows = [json.loads(line) for line in progress.read_text().splitlines()]
    print(f"\nLive network: {args.rig}, {args.detector}, {args.seconds:.0f} s\n")
    print("| elapsed s | solve | points | capture→calibration s | scale err % | scale σ % "
          "| max focal err % | max centre err mm |")
    print("|---|---|---|---|---|---|---|---|")
    nan = float("nan")
    for r in rows:
        print(f"| {r['elapsed_s']:.1f} | {r['solve']} | {r['points']} | {r.get('capture_to_solution_s', nan):.1f} "
              f"| {100 * r.get('scale_error_rel', nan):+.3f} | {100 * (r['scale_sigma_rel'] or nan):.3f} "
              f"| {100 * r.get('max_focal_error_rel', nan):.2f} | {r.get('max_centre_error_mm', nan):.2f} |")
    latencies = sorted(r["capture_to_solution_s"] for r in rows if "capture_to_solution_s" in r)
    if latencies:
        print(f"\ncapture→calibration: median {latencies[len(latencies) // 2]:.1f} s, max {latencies[-1]:.1f} s "
              f"over {len(latencies)} calibrations")
    return 0


if __name__ == "__main__":
    sys.exit(main())
