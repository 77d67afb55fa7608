#!/usr/bin/env python3
"""The live network on a simulated rig: accuracy against elapsed time, and capture-to-calibration latency.

Runs `camnet up RIG` (drivers, matcher, calibrator as processes on loopback
Zenoh, simulated time on the wall clock) and tabulates every calibration it
publishes: when it came, how long after the newest frame set it includes
was captured, and its errors against the simulation's ground truth. Then
the latency's median and max, and its budget: the median of every stage
between capture and publication (`camnet.bus.latency`), from the stage times
the matcher and the calibrator stamp in their documents.

    python benchmarks/bench_live.py [--rig config/sim.yaml] [--seconds 120] [--detector sift]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from camnet.bus.latency import STAGES
from camnet.matching.features import Detector
from camnet.testing.ports import free_port

ROOT = Path(__file__).resolve().parent.parent


def median(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[len(ordered) // 2] if len(ordered) % 2 else (ordered[len(ordered) // 2 - 1]
                                                                 + ordered[len(ordered) // 2]) / 2


def print_stages(rows: list[dict]) -> None:
    """The latency budget: each stage's median and max over the calibrations that stamp it."""
    print("\n| stage (ends when) | median s | max s | calibrations |\n|---|---|---|---|")
    total = 0.0
    for stage in STAGES[1:]:
        values = [r["stages_s"][stage] for r in rows if stage in r.get("stages_s", {})]
        if values:
            total += median(values)
            print(f"| {stage} | {median(values):.3f} | {max(values):.3f} | {len(values)} |")
    print(f"| sum of the medians | {total:.3f} | | |")


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
        print(f"\ncapture→calibration: median {median(latencies):.2f} s, max {latencies[-1]:.2f} s "
              f"over {len(latencies)} calibrations")
        print_stages(rows)
    if rows and "scale_error_rel" in rows[-1]:
        last = rows[-1]
        print(f"last calibration against the truth: scale {100 * last['scale_error_rel']:+.3f}% "
              f"(sigma {100 * (last['scale_sigma_rel'] or nan):.3f}%), max focal error "
              f"{100 * last['max_focal_error_rel']:.3f}%; median over the run: |scale| "
              f"{100 * median([abs(r['scale_error_rel']) for r in rows]):.3f}%, max focal "
              f"{100 * median([r['max_focal_error_rel'] for r in rows]):.3f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
