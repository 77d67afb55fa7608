#!/usr/bin/env python3
"""The matcher's CPU per frame set on a recorded live feature stream, stage by stage, offline.

`record` runs bench_hosts.py's network (config/hosts16.yaml's cameras on
camera hosts of four, with their feature stages, the router, the matcher
and the calibrator) for `--minutes`, then its first four cameras on one host
for `--compare-minutes`, and writes what a matcher receives, as it arrived:
every camera's features messages and every calibration, with their arrival
times (one file per rig, beside a copy of the rig file). The frames are not
recorded (the matcher does not receive the frames of cameras whose features
come).

`replay` feeds a recording, in arrival order, to `MatcherNode.process` in
this process, without the bus: the features go to the node's frame
synchronizer on the recorded clock (a frame set is taken when complete, or
once it has waited `max_wait_s`), the calibrations to its inbox, and the
pool's document is encoded at most once a second of that clock, as the live
node publishes it (`--publish-period-s 1.0`, as bench_hosts runs it). CPU
seconds of this process (every thread) per frame set, split by stage:

- matching: descriptor matching, RANSAC and the check on a pair's F, of the
  pairs of the frame set (`IncrementalMatcher`);
- pool: `TrackPool.add` (merging, the pairs' F check, eviction);
- calibrations: parsing a calibration and renewing the view graph;
- the rest: decoding the features, tracks, the document, the node's own.

and what the matching did per frame set: pairs matched, of them whole
(every keypoint of one camera against every keypoint of the other), and
the keypoint comparisons (rows times columns of the descriptor products,
millions). Then the pool's tracks seen by 3+ cameras (the median over the
sets once the pool is full) and the share of its observation pairs on the
true epipolar lines. `--solve-every N` also solves the pool of every Nth
frame set on the view graph (once it is full) as the live calibrator does
(`camnet.live.policy.LiveConfig`'s options, cold), and reports the
median scale error and largest focal error against the simulation's truth.
`--repeats` runs each recording again, taking turns.

    python benchmarks/bench_matcher_stream.py record --out DIR [--minutes 3] [--compare-minutes 2]
    python benchmarks/bench_matcher_stream.py replay DIR [--repeats 2] [--sets 120] [--solve-every 40]
"""

from __future__ import annotations

import argparse
import statistics
import struct
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from math import nan
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
if TYPE_CHECKING:
    from bench_matcher_stages import Stopwatch

    from camnet.model.observations import Observations

_RECORD = struct.Struct("<qHI")  # arrival ns since the start, key bytes, payload bytes
STAGES = ("matching", "pool", "calibrations", "rest")
PUBLISH_PERIOD_S = 1.0
SETTLE_SETS = 5  # frame sets on the view graph left out of the means


class StreamWriter:
    """Appends (arrival time, key, payload) records to a file; Zenoh's callback threads call `on_sample`."""

    def __init__(self, path: Path) -> None:
        self._file = path.open("wb")
        self._lock = threading.Lock()
        self._start_ns = time.monotonic_ns()
        self.count = 0

    def on_sample(self, sample) -> None:
        key, payload = str(sample.key_expr).encode(), sample.payload.to_bytes()
        with self._lock:
            if self._file.closed:
                return
            self._file.write(_RECORD.pack(time.monotonic_ns() - self._start_ns, len(key), len(payload)))
            self._file.write(key)
            self._file.write(payload)
            self.count += 1

    def close(self) -> None:
        with self._lock:
            self._file.close()


def read_stream(path: Path):
    """Yields (arrival s, key, payload) of a recording, in arrival order."""
    with path.open("rb") as f:
        while header := f.read(_RECORD.size):
            t_ns, key_len, size = _RECORD.unpack(header)
            key = f.read(key_len).decode()
            yield t_ns / 1e9, key, f.read(size)


def record(out: Path, *, minutes: float, compare_minutes: float, features_period_s: float) -> None:
    from bench_hosts import CAMERAS_PER_HOST, HostsNetwork

    from camnet.bus import keys

    out.mkdir(parents=True, exist_ok=True)
    rig = yaml.safe_load((ROOT / "config" / "hosts16.yaml").read_text())
    few = {**rig, "rig": f"{rig['rig']}_first{CAMERAS_PER_HOST}", "cameras": rig["cameras"][:CAMERAS_PER_HOST]}
    for phase_rig, phase_minutes in ((rig, minutes), (few, compare_minutes)):
        if phase_minutes <= 0:
            continue
        name = phase_rig["rig"]
        (out / f"{name}.yaml").write_text(yaml.safe_dump(phase_rig, sort_keys=False))
        writer = StreamWriter(out / f"{name}.stream")
        with tempfile.TemporaryDirectory(prefix="camnet-bench-stream-") as tmp, \
                HostsNetwork(Path(tmp), phase_rig, cameras_per_host=CAMERAS_PER_HOST,
                             features_period_s=features_period_s) as net:
            net.session.declare_subscriber(keys.all_features(name), writer.on_sample)
            net.session.declare_subscriber(keys.calibration(name), writer.on_sample)
            start_s = time.monotonic()
            while time.monotonic() - start_s < 60 * phase_minutes:
                time.sleep(10.0)
                net.launch.check()
                print(f"  {name}: {time.monotonic() - start_s:4.0f} s, {writer.count} messages, "
                      f"{len(net.calibrations)} good calibrations", file=sys.stderr, flush=True)
        writer.close()


@dataclass(frozen=True)
class SetCost:
    seconds: dict[str, float]
    pairs: int
    whole: int  # pairs matched whole
    compared_m: float  # keypoint comparisons, millions (rows x columns of the descriptor products)
    pool: int
    pool_3plus: int
    calibrated: bool  # the view graph chose the pairs
    every_camera: bool  # and its calibration held every camera of the rig


class _Publisher:
    def put(self, payload: bytes, *, attachment: bytes | None = None) -> None:
        self.last = payload


class _Recorded:
    """A recorded calibration as the matcher's subscriber hands it over: its payload, no attachment."""

    def __init__(self, payload: bytes) -> None:
        import zenoh

        self.payload, self.attachment = zenoh.ZBytes(payload), None


def replay(directory: Path, name: str, *, max_sets: int,
           solve_every: int = 0) -> tuple[list[SetCost], object, list[Observations]]:
    """Feed the recording of rig `name` to a matcher node; the cost of each frame set, the pool's quality,
    and the pool of every `solve_every`th frame set on the view graph once it is full (none for 0)."""
    from bench_matcher_stages import Stopwatch, pool_quality
    from camnet.services.matcher import MatcherNode, MatcherNodeConfig, rig_options

    from camnet.bus import keys
    from camnet.bus.features_wire import decode_features
    from camnet.io.rig import load_rig

    rig = load_rig(directory / f"{name}.yaml")
    node = MatcherNode(None, rig, config=MatcherNodeConfig(**rig_options(rig), publish_period_s=PUBLISH_PERIOD_S))
    watch = Stopwatch()
    engine = node.engine
    engine._match_pairs = watch.wrap("matching", engine._match_pairs)  # the pairs' tasks in the thread pool too
    engine.matcher.prepare = watch.wrap("matching", engine.matcher.prepare)  # which keypoints were seen before
    node._take_calibration = watch.wrap("calibrations", node._take_calibration)
    engine._ensure_pool = _wrap_pool(engine._ensure_pool, watch)
    publisher, costs, pools = _Publisher(), [], []
    calibration_key = keys.calibration(rig.name)
    max_tracks = node.config.max_tracks
    on_graph = [0]  # frame sets on the view graph so far

    def take(now_s: float) -> None:
        frame_set = node._sync.pop(now_s=now_s)
        if frame_set is None:
            return
        whole, compared = engine.matcher.whole, engine.matcher.compared
        t0 = time.process_time()
        node.process(frame_set)
        node._publish_if_due(publisher, now_s)
        total = time.process_time() - t0
        seconds = watch.take()
        seconds["rest"] = total - sum(seconds.values())
        pool = engine.pool
        costs.append(SetCost(seconds, engine.stats.pairs[0], engine.matcher.whole - whole,
                             (engine.matcher.compared - compared) / 1e6, len(pool),
                             int(np.sum(np.bincount(pool.observations().track_index) >= 3)),
                             bool(engine.view_graph.calibrated),
                             engine.view_graph.calibrated >= set(node.camera_ids)))
        on_graph[0] += costs[-1].calibrated
        if solve_every and costs[-1].calibrated and on_graph[0] % solve_every == 0 and len(pool) >= 0.9 * max_tracks:
            pools.append(node.message().observations)

    for t_s, key, payload in read_stream(directory / f"{name}.stream"):
        if len(costs) >= max_sets:
            break
        take(t_s)
        if key == calibration_key:
            node.calibration.on_sample(_Recorded(payload))
        elif key.endswith("/features"):
            node._sync.add(decode_features(payload), now_s=t_s)
            take(t_s)
    return costs, pool_quality(engine.observations(), rig.simulated_truth()), pools


def solve_errors(pools: list[Observations], truth) -> dict[str, float]:
    """Median over `pools` of each one's calibration's scale error and largest focal error (%), solved cold
    with the live calibrator's options."""
    from camnet.live.policy import LiveConfig
    from camnet.model.accuracy import compare_cameras
    from camnet.solve import calibrate

    scale, focal = [], []
    for obs in pools:
        c = compare_cameras(calibrate(obs, LiveConfig().options).calibration, truth)
        scale.append(100 * abs(c.scale_rel))
        focal.append(100 * max(abs(e.focal_rel) for e in c.cameras))
    return {"solves": len(pools), "scale_pct": statistics.median(scale) if scale else nan,
            "focal_pct": statistics.median(focal) if focal else nan}


def _wrap_pool(ensure_pool, watch: Stopwatch):
    """The engine's `_ensure_pool`, its pool's `add` timed as the pool stage."""
    def ensured():
        pool = ensure_pool()
        if not getattr(pool.add, "_timed", False):
            pool.add = watch.wrap("pool", pool.add)
            pool.add._timed = True
        return pool
    return ensured


def summary(costs: list[SetCost]) -> dict[str, float]:
    """Means over the frame sets on the view graph, after the first `SETTLE_SETS` of them (the keyframes'
    whole matches are in the mean, as in a CPU-per-set measure of the live node)."""
    later = [c for c in costs if c.calibrated][SETTLE_SETS:] or costs
    out = {stage: statistics.fmean(c.seconds.get(stage, 0.0) for c in later) for stage in STAGES}
    out["total"] = sum(out[stage] for stage in STAGES)
    out["sets"] = len(later)
    out["pairs"] = statistics.fmean(c.pairs for c in later)
    out["whole"] = statistics.fmean(c.whole for c in later)
    out["compared_m"] = statistics.fmean(c.compared_m for c in later)
    full = [c.pool_3plus for c in later if c.pool >= 0.9 * max(x.pool for x in costs)] or [costs[-1].pool_3plus]
    out["pool_3plus"] = statistics.median(full)
    # bench_hosts.py counts from the first minute, when the calibration holds every camera: a camera it does
    # not hold is matched with every camera, which the first sets on the view graph pay for.
    held = [c for c in later if c.every_camera]
    out["held_sets"] = len(held)
    out["held_total"] = statistics.fmean(sum(c.seconds.get(s, 0.0) for s in STAGES) for c in held) if held else nan
    out["held_pairs"] = statistics.fmean(c.pairs for c in held) if held else nan
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="run the network and record what the matcher receives")
    rec.add_argument("--out", type=Path, required=True)
    rec.add_argument("--minutes", type=float, default=3.0)
    rec.add_argument("--compare-minutes", type=float, default=2.0)
    rec.add_argument("--features-period-s", type=float, default=0.5)
    rep = sub.add_parser("replay", help="feed recordings to the matcher node, offline")
    rep.add_argument("recording", type=Path)
    rep.add_argument("--repeats", type=int, default=1)
    rep.add_argument("--sets", type=int, default=10**9, help="at most this many frame sets of each recording")
    rep.add_argument("--only", help="only the recording of this rig")
    rep.add_argument("--solve-every", type=int, default=0, metavar="N",
                     help="solve the full pool of every Nth frame set on the view graph (0: none)")
    args = parser.parse_args()
    if args.command == "record":
        record(args.out, minutes=args.minutes, compare_minutes=args.compare_minutes,
               features_period_s=args.features_period_s)
        return 0
    from camnet.io.rig import load_rig

    names = sorted((p.stem for p in args.recording.glob("*.stream") if args.only in (None, p.stem)),
                   key=lambda n: ("_first" in n, n))
    rows = {}
    for k in range(args.repeats):
        for name in names:
            costs, quality, pools = replay(args.recording, name, max_sets=args.sets, solve_every=args.solve_every)
            if pools:
                print(f"  {name} #{k + 1}: solving {len(pools)} pools", file=sys.stderr, flush=True)
            errors = solve_errors(pools, load_rig(args.recording / f"{name}.yaml").simulated_truth())
            measured = summary(costs)
            rows[f"{name} #{k + 1}"] = (len(costs), measured | errors, quality)
            print(f"  {name} #{k + 1}: {len(costs)} frame sets, {measured['total']:.3f} CPU s a set",
                  file=sys.stderr, flush=True)
    print_table(rows)
    return 0


def print_table(rows: dict) -> None:
    names = list(rows)
    print("| CPU s per frame set (mean over the sets on the view graph) | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    print("| frame sets (on the view graph) | " + " | ".join(f"{rows[n][0]} ({rows[n][1]['sets']})" for n in names)
          + " |")
    for label, key, fmt in (("pairs matched", "pairs", "{:.1f}"), ("of them whole", "whole", "{:.2f}"),
                            ("keypoint comparisons, millions", "compared_m", "{:.1f}"),
                            *((stage, stage, "{:.3f}") for stage in STAGES), ("total", "total", "{:.3f}"),
                            ("frame sets with every camera calibrated", "held_sets", "{:.0f}"),
                            ("their pairs matched", "held_pairs", "{:.1f}"), ("their total", "held_total", "{:.3f}"),
                            ("pool: tracks seen by 3+ cameras (median, full pool)", "pool_3plus", "{:.0f}")):
        print(f"| {label} | " + " | ".join(fmt.format(rows[n][1][key]) for n in names) + " |")
    print("| pool: observation pairs within 1.5 px of the true epipolar lines | "
          + " | ".join(f"{100 * rows[n][2].true_share:.2f}%" for n in names) + " |")
    if any(rows[n][1]["solves"] for n in names):
        for label, key in (("pools solved", "solves"), ("their scale error, median %", "scale_pct"),
                           ("their largest focal error, median %", "focal_pct")):
            print(f"| {label} | " + " | ".join(f"{rows[n][1][key]:.3g}" for n in names) + " |")
    for key, label in (("total", "every set"), ("held_total", "with every camera calibrated")):
        sixteen = [rows[n][1][key] for n in names if "_first" not in n]
        four = [rows[n][1][key] for n in names if "_first" in n]
        if sixteen and four:
            print(f"\nratio of the medians, {label}: {statistics.median(sixteen) / statistics.median(four):.2f}x "
                  f"({statistics.median(sixteen):.3f} / {statistics.median(four):.3f} CPU s a set)")


if __name__ == "__main__":
    sys.exit(main())
