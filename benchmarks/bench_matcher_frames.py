#!/usr/bin/env python3
"""The matcher's CPU per frame set when every camera sends features beside its frames, in a process of its own.

The rig's cameras (default config/hosts16.yaml: 16 at 640x512, 10 fps) are
played by this process from ready-made messages, so that no renderer or
feature stage competes with the matcher for the cores: each camera's frames
at its frame rate, and keypoints and descriptors (detected beforehand on
`--slots` rendered frames by `camnet.matching.edge.FeatureExtractor`, as
`camnet driver --features` does, and cycled) every `--features-period-s` on
the same capture grid; and the simulation's true calibration once a second,
so that the matcher matches its view graph's pairs as it does beside a
calibrator. `camnet matcher` runs alone as a child process.
After `--settle-s`, for `--seconds`, the table gives the matcher's CPU seconds
(/proc, user + system) per frame set matched and per second, and how many
frames reached it (`frames in` of its statistics).

Run it from two checkouts, taking turns, to compare versions under the same load.

    python benchmarks/bench_matcher_frames.py [--seconds 60]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from bench_hosts import cpu_s
from camnet.services.features import to_message
from soak import MatcherStats

from camnet.bus import keys
from camnet.bus.features_wire import encode_features
from camnet.bus.frame import Frame, encode_frame
from camnet.bus.launch import Launch
from camnet.bus.session import BusOptions, open_session
from camnet.bus.source import SourcedPublisher, declare_calibrator, declare_stage
from camnet.io.formats import calibration_to_doc
from camnet.io.rig import load_rig
from camnet.matching.edge import FeatureExtractor
from camnet.model.calibration import Calibration
from camnet.testing.ports import free_port

ROOT = Path(__file__).resolve().parent.parent


def prepare(rig, slots: int, features_every: int) -> tuple[dict, dict]:
    """Per camera: its rendered frames, and the features of every `features_every`-th of them."""
    from camnet.drivers.base import create_camera

    images, features = {}, {}
    for entry in rig.cameras:
        camera = create_camera(entry, rig)
        images[entry.id] = [camera.render(slot) for slot in range(slots)]
        extractor = FeatureExtractor(entry.id)
        features[entry.id] = [to_message(extractor.extract(image, seq=slot, timestamp_ns=0))
                              for slot, image in enumerate(images[entry.id]) if slot % features_every == 0]
        print(f"  {entry.id}: {len(features[entry.id])} feature messages", file=sys.stderr, flush=True)
    return images, features


def true_calibration(rig) -> bytes:
    """The simulation's cameras, with points in its box, as a calibration: the matcher then matches the
    pairs of its view graph, as beside a calibrator, not every pair."""
    cameras = tuple(entry.config.camera(entry.id) for entry in rig.cameras)
    scene = rig.scene
    points = np.asarray(scene.box_centre_m) + (np.random.default_rng(0).random((500, 3)) - 0.5) * scene.box_size_m
    calibration = Calibration(cameras, np.arange(len(points)), points, float("nan"), cameras[0].id)
    return json.dumps(calibration_to_doc(calibration)).encode()


def play(session, rig, images: dict, features: dict, *, period_s: float, features_every: int,
         stop: threading.Event) -> None:
    """Every camera's frames on the capture grid, its features every `features_every` slots, and the
    calibration once a second."""
    frames = {c: session.declare_publisher(keys.frame(rig.name, c)) for c in images}
    calibration = true_calibration(rig)
    feature_keys = {c: keys.features(rig.name, c) for c in images}
    # Each camera's stage declared, as a live one is, or its features are refused; kept while it plays.
    stages = [declare_stage(session, rig.name, camera_id) for camera_id in images]
    # Published as the calibrator publishes, or the matcher ignores it.
    calibrator = declare_calibrator(session, rig.name)
    calibration_publisher = SourcedPublisher(session.declare_publisher(keys.calibration(rig.name)))
    period_ns = round(period_s * 1e9)
    slot = time.time_ns() // period_ns + 1
    while not stop.is_set():
        timestamp_ns = slot * period_ns
        time.sleep(max(0.0, timestamp_ns / 1e9 - time.time()))
        for camera_id, pool in images.items():
            frames[camera_id].put(encode_frame(Frame(camera_id, slot, timestamp_ns, "mono8",
                                                     pool[slot % len(pool)])))
            if slot % features_every == 0:
                messages = features[camera_id]
                message = messages[(slot // features_every) % len(messages)]
                session.put(feature_keys[camera_id], encode_features(replace(message, seq=slot,
                                                                             timestamp_ns=timestamp_ns)))
        if slot % round(1 / period_s) == 0:
            calibration_publisher.put(calibration)
        slot = max(slot + 1, time.time_ns() // period_ns)  # late: skip slots, as a camera does
    for stage in stages:
        stage.undeclare()
    calibrator.undeclare()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rig", type=Path, default=ROOT / "config" / "hosts16.yaml")
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--settle-s", type=float, default=20.0)
    parser.add_argument("--features-period-s", type=float, default=0.5)
    parser.add_argument("--slots", type=int, default=12, help="rendered frames per camera, cycled (default: 12)")
    args = parser.parse_args()
    rig = load_rig(args.rig)
    fps = {e.config.fps for e in rig.cameras}
    period_s = 1 / min(fps)
    features_every = max(1, round(args.features_period_s / period_s))
    print(f"preparing {len(rig.cameras)} cameras' frames and features ...", file=sys.stderr, flush=True)
    images, features = prepare(rig, args.slots, features_every)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    stop = threading.Event()
    logs = Path(tempfile.mkdtemp(prefix="camnet-bench-frames-"))  # kept: the matcher's log tells what it did
    with open_session(BusOptions(listen=(endpoint,))) as session, Launch(logs) as launch:
        stats = MatcherStats()
        session.declare_subscriber(keys.node_stats(rig.name, "matcher", "matcher"), stats)
        player = threading.Thread(target=play, args=(session, rig, images, features), daemon=True,
                                  kwargs=dict(period_s=period_s, features_every=features_every, stop=stop))
        player.start()
        matcher = launch.start("matcher", ["matcher", "--rig", str(args.rig), "--connect", endpoint])
        try:
            time.sleep(args.settle_s)
            launch.check()
            first = (cpu_s(matcher.process.pid), stats.latest.frames if stats.latest else 0, time.monotonic())
            time.sleep(args.seconds)
            launch.check()
            last = (cpu_s(matcher.process.pid), stats.latest.frames if stats.latest else 0, time.monotonic())
            detail = stats.latest.detail if stats.latest else ""
        finally:
            stop.set()
            player.join(timeout=30)
    cpu, sets, span_s = (b - a for a, b in zip(first, last, strict=True))
    print(f"{len(rig.cameras)} cameras at {1 / period_s:g} fps, features every {features_every * period_s:g} s; "
          f"{args.seconds:g} s after {args.settle_s:g} s; the matcher's log: {logs / 'matcher.log'}")
    print("| frame sets matched | matcher CPU s per set | matcher CPU % of a core | its statistics |")
    print("|---|---|---|---|")
    per_set = f"{cpu / sets:.3f}" if sets else "n/a"
    print(f"| {sets} | {per_set} | {100 * cpu / span_s:.0f} | {detail} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
