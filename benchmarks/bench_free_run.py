#!/usr/bin/env python3
"""Cameras not triggered together: how many frame sets the matcher forms, and how far apart their exposures are.

The paper's simulated rig (config/sim.yaml: left, right, mono_a, mono_b at
30 fps) with its box turning at `--rotation-deg-per-s`, each camera given a
clock (camnet.sim.clock) per set-up: triggered or free-running, with
latencies and drifts. The sim driver's cameras (camnet.drivers.sim.SimCamera,
their clocks set at the run's start) give each frame's exposure instant,
stamp and delivery; the frames go, in the order and at the instants they are
delivered, into the matcher's frame synchronizer (camnet.bus.sync) with the
matcher node's default tolerance and wait and the stereo pair required, and a
set is taken after every frame, as a matcher that keeps up would. Each set-up
runs twice: with the matcher's default rule (stamps within the tolerance) and
with the rig file's `sync: {free_run: true}` (each camera's frame nearest the
left's, within half its frame period). No image is rendered or matched: only
the sets' forming is measured, in simulated time. A free-running set-up is
run with `--draws` sets of phases drawn at random (seeded) in place of those
the cameras' ids give, since which frames pair up depends on them; its rates
are the means over the draws.

Per set-up and rule: the draws in which any frame set formed; complete and
partial (a mono camera left out after the wait) frame sets per second; the
mean number of cameras in a set; the largest offset a set records (a frame's
stamp minus the reference's, `FrameSet.offsets_ns`); the largest gap between
the exposures of one set's frames; and the largest image motion that gap
makes: how far, in pixels, a corner of the box moves in a camera's image
between the reference (left) camera's exposure and its own.

    python benchmarks/bench_free_run.py [--seconds 30] [--draws 10] [--rotation-deg-per-s 90]
"""

from __future__ import annotations

import argparse
import copy
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml
from camnet.drivers.sim import SimCamera
from camnet.services.matcher_config import MatcherNodeConfig

from camnet.bus.frame import Frame
from camnet.bus.sync import FrameSynchronizer
from camnet.io.rig import Rig, parse_rig
from camnet.sim.scene import Scene

RIG_FILE = Path(__file__).resolve().parents[1] / "config" / "sim.yaml"
START_NS = 1_800_000_000 * 1_000_000_000  # the run's start on the rig clock; the cameras' clocks are set then
LATENCIES_MS = (0.0, 10.0, 20.0, 30.0)  # left, right, mono_a, mono_b
DRIFTS_PPM = (0.0, 20.0, -20.0, 50.0)

# (name, clock of each camera in the rig's order; None: no clock)
SETUPS = [
    ("triggered, no clock (today)", [None] * 4),
    ("triggered, latency 12 ms each", [{"latency_ms": 12.0}] * 4),
    ("triggered, latencies 0/10/20/30 ms", [{"latency_ms": lat} for lat in LATENCIES_MS]),
    ("free-running", [{"free_run": True}] * 4),
    ("free-running, latency 12 ms each", [{"free_run": True, "latency_ms": 12.0}] * 4),
    ("free-running, latencies 0/10/20/30 ms", [{"free_run": True, "latency_ms": lat} for lat in LATENCIES_MS]),
    ("free-running, drifts 0/20/-20/50 ppm", [{"free_run": True, "drift_ppm": d} for d in DRIFTS_PPM]),
    ("free-running, latencies 0-30 ms, drifts 0-50 ppm",
     [{"free_run": True, "latency_ms": lat, "drift_ppm": d} for lat, d in zip(LATENCIES_MS, DRIFTS_PPM, strict=True)]),
]


def rig_with(clocks: list[dict | None], rotation_deg_per_s: float) -> Rig:
    doc = yaml.safe_load(RIG_FILE.read_text())
    doc = copy.deepcopy(doc)
    doc["scene"]["box_rotation_deg_per_s"] = rotation_deg_per_s
    for camera, clock in zip(doc["cameras"], clocks, strict=True):
        if clock is not None:
            camera["sim"]["clock"] = clock
    return parse_rig(doc, source=str(RIG_FILE))


def with_phases(rig: Rig, phases: np.ndarray) -> Rig:
    """`rig` with its free-running cameras' phases (fractions of a period) replaced by `phases`, in order."""
    cameras = []
    for entry, phase in zip(rig.cameras, phases, strict=True):
        clock = entry.config.clock
        if clock is not None and clock.free_run:
            entry = replace(entry, config=replace(entry.config, clock=replace(clock, phase=float(phase))))
        cameras.append(entry)
    return replace(rig, cameras=tuple(cameras))


def box_corners(scene: Scene, time_s: float) -> np.ndarray:
    """The box's 8 corners (world, m) at `time_s`."""
    half = np.array(scene.config.box_size_m) / 2
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    return np.array(scene.config.box_centre_m) + (signs * half) @ scene.box_rotation(time_s).T


def pixels(camera, X: np.ndarray) -> np.ndarray:
    """Pinhole pixels of world points `X` (the rig's sim cameras have no distortion): K (R X + t)."""
    xc = X @ camera.R.T + camera.t
    uv = xc @ camera.K.T
    return uv[:, :2] / uv[:, 2:]


def run(rig: Rig, scene: Scene, seconds: float, free_run: bool) -> dict:
    config = MatcherNodeConfig(sync_free_run=free_run)
    cameras = {e.id: SimCamera(e.id, e.config, scene, clock_epoch_ns=START_NS) for e in rig.cameras}
    truth = {e.id: e.config.camera(e.id) for e in rig.cameras}
    sync = FrameSynchronizer(tuple(cameras), required=(rig.stereo.left, rig.stereo.right),
                             tolerance_ns=round(config.sync_tolerance_ms * 1e6), max_wait_s=config.max_wait_s,
                             frames_per_camera=config.frames_per_camera, free_run=config.sync_free_run)
    end_ns = START_NS + round(seconds * 1e9)
    deliveries = []  # (delivered at, camera id, slot)
    for camera_id, camera in cameras.items():
        slot = camera.slot_at(START_NS) + 1
        while camera.exposure_ns(slot) < end_ns:
            deliveries.append((camera.due_ns(slot), camera_id, slot))
            slot += 1
    deliveries.sort()
    image = np.zeros((1, 1), np.uint8)
    sets = []
    for delivered_ns, camera_id, slot in deliveries:
        frame = Frame(camera_id, slot, cameras[camera_id].slot_timestamp_ns(slot), "mono8", image)
        sync.add(frame, now_s=delivered_ns / 1e9)
        while (frame_set := sync.pop(now_s=delivered_ns / 1e9)) is not None:
            sets.append(frame_set)
    skew_ms, motion_px = [], []
    for frame_set in sets:
        exposures = {c: cameras[c].exposure_ns(f.seq) for c, f in frame_set.frames.items()}
        reference_s = exposures[rig.stereo.left] / 1e9
        skew_ms.append((max(exposures.values()) - min(exposures.values())) / 1e6)
        at_reference = box_corners(scene, reference_s)
        motion_px.append(max(
            np.linalg.norm(pixels(truth[c], box_corners(scene, t / 1e9)) - pixels(truth[c], at_reference),
                           axis=1).max() for c, t in exposures.items()))
    counts = sync.counts
    return {"complete": counts.complete_sets / seconds, "partial": counts.partial_sets / seconds,
            "cameras": np.mean([len(s.frames) for s in sets]) if sets else 0.0,
            "offset_ms": max((abs(o) / 1e6 for s in sets for o in s.offsets_ns.values()), default=float("nan")),
            "skew_ms": max(skew_ms, default=float("nan")), "motion_px": max(motion_px, default=float("nan"))}


def largest(values: list[float]) -> str:
    return f"{max(values):.1f}" if values else "-"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="simulated seconds per set-up")
    parser.add_argument("--draws", type=int, default=10, help="phase draws per free-running set-up")
    parser.add_argument("--rotation-deg-per-s", type=float, default=90.0, help="how fast the box turns")
    args = parser.parse_args()
    started = time.monotonic()
    scene = Scene(rig_with([None] * 4, args.rotation_deg_per_s).scene)
    print(f"Paper's rig (config/sim.yaml), 4 cameras at 30 fps, box turning {args.rotation_deg_per_s:g} deg/s, "
          f"{args.seconds:g} s simulated per set-up; matcher's defaults: tolerance "
          f"{MatcherNodeConfig().sync_tolerance_ms:g} ms, wait {MatcherNodeConfig().max_wait_s:g} s, "
          "stereo pair required.\n")
    print("| Cameras (left, right, mono_a, mono_b) | matcher's sync | draws with sets | complete sets/s "
          "| partial sets/s | cameras per set | largest offset a set records (ms) "
          "| largest exposure gap in a set (ms) | largest box motion in a set (px) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for free_run in (False, True):
        rule = "free_run" if free_run else f"tolerance {MatcherNodeConfig().sync_tolerance_ms:g} ms"
        for name, clocks in SETUPS:
            rig = rig_with(clocks, args.rotation_deg_per_s)
            free = any(clock is not None and clock.get("free_run") for clock in clocks)
            draws = [with_phases(rig, np.random.default_rng(draw).random(len(rig.cameras)))
                     for draw in range(args.draws)] if free else [rig]
            rows = [run(r, scene, args.seconds, free_run) for r in draws]
            formed = [row for row in rows if row["complete"] + row["partial"] > 0]
            print(f"| {name} | {rule} | {len(formed)}/{len(rows)} | {np.mean([r['complete'] for r in rows]):.1f} "
                  f"| {np.mean([r['partial'] for r in rows]):.1f} "
                  f"| {np.mean([r['cameras'] for r in formed]) if formed else 0.0:.2f} "
                  f"| {largest([r['offset_ms'] for r in formed])} | {largest([r['skew_ms'] for r in formed])} "
                  f"| {largest([r['motion_px'] for r in formed])} |")
    own = rig_with(SETUPS[3][1], args.rotation_deg_per_s)
    print("\nThe phases the rig's camera ids give (fractions of a period), not drawn: "
          + ", ".join(f"{e.id} {e.config.clock.phase:.2f}" for e in own.cameras))
    print(f"({time.monotonic() - started:.0f} s)")


if __name__ == "__main__":
    main()
