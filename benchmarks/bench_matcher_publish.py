#!/usr/bin/env python3
"""Encoding the matcher's observations message at a full pool: from scratch against track by track.

A pool of `--tracks` tracks over `--cameras` cameras (640x512; each track seen
by 2 to 4 of them at random pixels) is filled, then each of `--sets` frame
sets adds `--new` tracks (evicting as many) and sees `--reseen` pooled tracks
again with one more camera. After each set the message is encoded both ways,
alternating which goes first: `encode_observations_message` (json.dumps of the
whole document) and `ObservationsEncoder.encode` (camnet.io.observations_encoder),
checked equal byte for byte. Prints the median and max of each, and their ratio.

    python benchmarks/bench_matcher_publish.py [--tracks 5000 --cameras 16 --sets 20]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from camnet.bus.latency import StageStamps  # noqa: E402
from camnet.io.messages import ObservationsMessage, encode_observations_message  # noqa: E402
from camnet.io.observations_encoder import ObservationsEncoder  # noqa: E402
from camnet.matching.pool import PoolConfig, TrackPool  # noqa: E402
from camnet.model.camera import CameraInfo  # noqa: E402
from camnet.model.observations import Stereo
from camnet.testing.random_tracks import HEIGHT, WIDTH, random_tracks, reseen  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tracks", type=int, default=5000)
    parser.add_argument("--cameras", type=int, default=16)
    parser.add_argument("--sets", type=int, default=20)
    parser.add_argument("--new", type=int, default=300, help="tracks added per frame set (default: 300)")
    parser.add_argument("--reseen", type=int, default=50, help="pooled tracks seen again per set (default: 50)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    cameras = [CameraInfo(f"cam{i:02d}", WIDTH, HEIGHT) for i in range(args.cameras)]
    ids = tuple(c.id for c in cameras)
    pool = TrackPool(cameras, Stereo(ids[0], ids[1], 0.125), PoolConfig(max_tracks=args.tracks))
    while len(pool) < args.tracks:
        pool.add(random_tracks(rng, ids, 1000), frame_seq=0)
    encoder = ObservationsEncoder()
    encoder.encode(ObservationsMessage(pool.observations()))
    scratch_ms, cached_ms, encoded = [], [], []
    for frame_seq in range(1, args.sets + 1):
        pool.add(random_tracks(rng, ids, args.new), frame_seq=frame_seq)
        pool.add(reseen(rng, pool, args.reseen), frame_seq=frame_seq)
        message = ObservationsMessage(pool.observations(), rig="bench", pool_id="0" * 32, frame_sets=frame_seq,
                                      latest_capture_ns=0, latency_ns=StageStamps(), published_ns=time.time_ns())
        results = {}
        for way in (("scratch", "cached") if frame_seq % 2 else ("cached", "scratch")):
            start_s = time.perf_counter()
            encode = encode_observations_message if way == "scratch" else encoder.encode
            results[way] = encode(message)
            (scratch_ms if way == "scratch" else cached_ms).append(1e3 * (time.perf_counter() - start_s))
        assert results["scratch"] == results["cached"], "the cached document differs from the codec's"
        encoded.append(encoder.encoded)
    size_mb = len(results["cached"]) / 1e6
    print(f"pool {len(pool)} tracks over {args.cameras} cameras, {size_mb:.2f} MB; {args.sets} sets of +{args.new} "
          f"tracks, {args.reseen} seen again; tracks encoded per set by the cache: median "
          f"{statistics.median(encoded):.0f}")
    print("| encoding | median ms | max ms |")
    print("|---|---|---|")
    for name, ms in (("from scratch (json.dumps of the document)", scratch_ms), ("track by track, cached", cached_ms)):
        print(f"| {name} | {statistics.median(ms):.1f} | {max(ms):.1f} |")
    print(f"ratio of medians: {statistics.median(scratch_ms) / statistics.median(cached_ms):.1f}x; "
          "documents equal byte for byte")
    return 0


if __name__ == "__main__":
    sys.exit(main())
