#!/usr/bin/env python3
"""Where the matcher's CPU goes per frame set, offline and without the bus: a table of stage costs.

Renders a simulated rig's frame sets on the feature stages' grid (every
`--period-s` of scene time), runs each camera's feature stage
(`camnet.matching.edge.FeatureExtractor`, as on the camera's host; not
timed) and encodes its message (`camnet.bus.features_wire`). Then, as the
matcher node does per frame set, timed stage by stage in CPU seconds of
this process (every thread):

- decode: the 16 feature messages to `CameraFeatures`;
- candidates: descriptor matching of each pair (ratio test, cross check);
- RANSAC: F of each pair matched whole, or the check of new candidates
  against the pair's F;
- tracks: chaining the pairs' matches (`build_tracks`);
- pool: `TrackPool.add`;
- document: the observations document and its JSON encoding, as one
  publish (the node publishes at most once a second: about every second set).

The first frame set is matched without a calibration (every pair), the
later ones on the view graph given the simulation's true calibration, as
the live node does once the rig is calibrated. The same for the rig's
first four cameras, and the ratio of the two. With `--epipolar-px 0,1`,
instead: the whole rig with the pool's check of each pair's F
(`PoolConfig.epipolar_px`) at each of these values, in turn, `--repeats`
times over the same messages, and each one's ratio to the first.

    python benchmarks/bench_matcher_stages.py [--rig config/hosts16.yaml] [--frame-sets 10]
                                              [--epipolar-px 0,1 [--repeats 2]]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections import defaultdict
from dataclasses import dataclass, replace
from itertools import combinations
from pathlib import Path

import numpy as np
from bench_matcher import ground_truth_calibration

from camnet.bus.features_wire import decode_features, encode_features
from camnet.io.formats import observations_to_doc
from camnet.io.rig import Rig, camera_info, load_rig
from camnet.matching import reuse
from camnet.matching.pool import PoolConfig, TrackPool
from camnet.matching.tracks import build_tracks
from camnet.matching.viewgraph import ViewGraph

ROOT = Path(__file__).resolve().parent.parent
TRUE_PX = 1.5
STAGES = ("decode", "candidates", "RANSAC", "tracks", "pool", "document")


class Stopwatch:
    """CPU seconds per stage, summed until `take`."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    def wrap(self, stage: str, fn):
        def timed(*args, **kwargs):
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds[stage] += time.process_time() - t0
        return timed

    def take(self) -> dict[str, float]:
        out, self.seconds = dict(self.seconds), defaultdict(float)
        return out


@dataclass(frozen=True)
class SetCost:
    pairs: int
    whole: int  # pairs matched whole in this set
    seconds: dict[str, float]
    tracks: int
    tracks_3plus: int
    pool: int
    pool_3plus: int  # the pool's tracks seen by 3+ cameras after this set
    document_kb: float
    inlier_share: float  # of the candidates, those verified (RANSAC or the pair's F)


@dataclass(frozen=True)
class PoolQuality:
    tracks: int
    tracks_3plus: int
    true_share: float  # of the pooled observation pairs, those within TRUE_PX of the true epipolar lines


def feature_messages(rig: Rig, *, frame_sets: int, period_s: float) -> list[list[bytes]]:
    """Each frame set's features messages, from the feature stages of the rig's cameras."""
    from camnet.drivers.base import create_camera
    from camnet.services.features import to_message

    from camnet.matching.edge import FeatureExtractor

    cameras = [create_camera(entry, rig) for entry in rig.cameras]
    extractors = [FeatureExtractor(entry.id) for entry in rig.cameras]
    sets = []
    for k in range(frame_sets):
        slot = round(k * period_s * rig.cameras[0].config.fps)
        sets.append([encode_features(to_message(x.extract(camera.render(slot), seq=slot, timestamp_ns=slot)))
                     for x, camera in zip(extractors, cameras, strict=True)])
    return sets


def pool_quality(obs, truth) -> PoolQuality:
    """The pool's tracks, those seen by 3+ cameras, and the share of its observation pairs on the true
    epipolar lines (the simulated cameras have no distortion)."""
    uv = np.full((len(obs.track_ids), len(obs.cameras), 2), np.nan)
    uv[obs.track_index, obs.cam_index] = obs.uv
    views = np.isfinite(uv[:, :, 0]).sum(axis=1)
    true, total = 0, 0
    for i, j in combinations(range(len(truth)), 2):
        both = np.isfinite(uv[:, i, 0]) & np.isfinite(uv[:, j, 0])
        if both.any():
            true += int(reuse.epipolar_inliers(true_fundamental(truth[i], truth[j]), uv[both, i], uv[both, j],
                                               TRUE_PX).sum())
            total += int(both.sum())
    return PoolQuality(len(views), int(np.sum(views >= 3)), true / max(total, 1))


def true_fundamental(cam_a, cam_b) -> np.ndarray:
    """F with x_b^T F x_a = 0 in pixels, from x_cam = R X + t."""
    R = cam_b.R @ cam_a.R.T
    t = cam_b.t - R @ cam_a.t
    skew = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return np.linalg.inv(cam_b.K).T @ skew @ R @ np.linalg.inv(cam_a.K)


def run(rig: Rig, messages: list[list[bytes]],
        pool_config: PoolConfig | None = None) -> tuple[list[SetCost], PoolQuality]:
    """Match the frame sets as the node does; the cost of each."""
    from camnet.services.features import from_message
    from camnet.services.matcher import rig_stereo

    stereo = rig_stereo(rig)
    watch = Stopwatch()
    originals = {name: getattr(reuse, name) for name in ("candidate_matches", "ransac_fundamental",
                                                         "epipolar_inliers")}
    reuse.candidate_matches = watch.wrap("candidates", originals["candidate_matches"])
    reuse.ransac_fundamental = watch.wrap("RANSAC", originals["ransac_fundamental"])
    reuse.epipolar_inliers = watch.wrap("RANSAC", originals["epipolar_inliers"])
    try:
        matcher = reuse.IncrementalMatcher(stereo=stereo)
        graph = ViewGraph(always={frozenset((stereo.left, stereo.right))})
        truth = ground_truth_calibration(rig)
        pool = TrackPool([camera_info(rig, c.id, c.config.width, c.config.height) for c in rig.cameras], stereo,
                         pool_config or PoolConfig())
        costs = []
        for seq, wire in enumerate(messages):
            t0 = time.process_time()
            cameras = [from_message(decode_features(m)) for m in wire]
            watch.seconds["decode"] += time.process_time() - t0
            if seq == 1:
                graph.update(truth)
            whole_before = matcher.whole
            pairs = graph.pairs([c.camera_id for c in cameras],
                                matched_well=matcher.matched_well(graph.config.good_matches))
            matches = matcher.match(cameras, pairs=pairs)
            tracks = watch.wrap("tracks", build_tracks)(matches)
            watch.wrap("pool", pool.add)(tracks, frame_seq=seq)
            t0 = time.process_time()
            obs = pool.observations()
            document = json.dumps(observations_to_doc(replace(obs, baselines=()))).encode()
            watch.seconds["document"] += time.process_time() - t0
            verified = sum(len(p) for p in matches.pairs) / max(1, sum(p.candidates for p in matches.pairs))
            pool_3plus = int(np.sum(np.bincount(obs.track_index) >= 3))
            costs.append(SetCost(len(matches.pairs), matcher.whole - whole_before, watch.take(), len(tracks),
                                 int(np.sum(tracks.views >= 3)), len(pool), pool_3plus, len(document) / 1e3,
                                 verified))
        return costs, pool_quality(pool.observations(), rig.simulated_truth())
    finally:
        for name, fn in originals.items():
            setattr(reuse, name, fn)


def summary(costs: list[SetCost]) -> dict[str, float]:
    """Medians (and the mean total) over the frame sets after the first two (the cold start, and the first on
    the view graph)."""
    later = costs[2:] or costs
    out = {stage: statistics.median(c.seconds.get(stage, 0.0) for c in later) for stage in STAGES}
    out["total"] = statistics.median(sum(c.seconds.values()) for c in later)
    # Keyframes (every EdgeConfig.keyframe_period frames of a stage) match their pairs whole: the mean has them.
    out["mean total"] = statistics.fmean(sum(c.seconds.values()) for c in later)
    return out


def print_table(rows: dict[str, tuple[list[SetCost], dict[str, float], PoolQuality]]) -> None:
    names = list(rows)
    print("| stage, CPU s per frame set (median) | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for stage in (*STAGES, "total", "mean total"):
        print(f"| {stage} | " + " | ".join(f"{rows[n][1][stage]:.3f}" for n in names) + " |")
    for label, get in (("pairs matched (whole)", lambda c: f"{c.pairs} ({c.whole})"),
                       ("tracks (seen by 3+)", lambda c: f"{c.tracks} ({c.tracks_3plus})"),
                       ("pool tracks", lambda c: str(c.pool)),
                       ("document kB", lambda c: f"{c.document_kb:.0f}")):
        print(f"| {label}, last set | " + " | ".join(get(rows[n][0][-1]) for n in names) + " |")
    print("| verified share of the candidates, later sets | "
          + " | ".join(f"{statistics.median(c.inlier_share for c in rows[n][0][2:] or rows[n][0]):.2f}"
                       for n in names) + " |")
    print("| pool: tracks seen by 3+ cameras | " + " | ".join(f"{rows[n][2].tracks_3plus}" for n in names) + " |")
    # The last set's count swings by hundreds with the order of eviction alone: the median says more.
    print("| pool: tracks seen by 3+ cameras, median from the 9th set (a full pool) | "
          + " | ".join(f"{statistics.median(c.pool_3plus for c in rows[n][0][8:] or rows[n][0]):.0f}" for n in names)
          + " |")
    print(f"| pool: observation pairs within {TRUE_PX:g} px of the true epipolar lines | "
          + " | ".join(f"{100 * rows[n][2].true_share:.1f}%" for n in names) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rig", type=Path, default=ROOT / "config" / "hosts16.yaml")
    parser.add_argument("--frame-sets", type=int, default=10)
    parser.add_argument("--period-s", type=float, default=0.5, help="scene time between frame sets")
    parser.add_argument("--first", type=int, default=4, help="the smaller rig: the first this many cameras")
    parser.add_argument("--epipolar-px", help="instead, the whole rig with these pool checks (comma-separated px)")
    parser.add_argument("--repeats", type=int, default=2, help="with --epipolar-px: runs of each, alternating")
    parser.add_argument("--per-set", action="store_true", help="also print every frame set's stages")
    args = parser.parse_args()
    rig = load_rig(args.rig)
    if args.epipolar_px:
        messages = feature_messages(rig, frame_sets=args.frame_sets, period_s=args.period_s)
        runs = [(f"{px:g} px #{k + 1}", rig, messages, PoolConfig(epipolar_px=px)) for k in range(args.repeats)
                for px in (float(v) for v in args.epipolar_px.split(","))]
    else:
        few = replace(rig, cameras=rig.cameras[:args.first])
        runs = [(f"{len(r.cameras)} cameras", r, feature_messages(r, frame_sets=args.frame_sets,
                                                                    period_s=args.period_s), PoolConfig())
                for r in (rig, few)]
    rows = {}
    for name, r, messages, pool_config in runs:
        costs, quality = run(r, messages, pool_config)
        rows[name] = (costs, summary(costs), quality)
        if args.per_set:
            for k, c in enumerate(costs):
                print(f"{name} set {k}: {c.pairs} pairs ({c.whole} whole), "
                      + ", ".join(f"{s} {c.seconds.get(s, 0.0):.3f}" for s in STAGES))
    print(f"{args.rig.name}: {args.frame_sets} frame sets {args.period_s:g} s apart; CPU s of this process")
    print_table(rows)
    totals = {n: rows[n][1]["total"] for n in rows}
    first = next(iter(totals.values()))
    print("\n" + "; ".join(f"{n} {t / first:.2f}x ({t:.3f} s)" for n, t in totals.items())
          + " per frame set, against the first")


if __name__ == "__main__":
    main()
