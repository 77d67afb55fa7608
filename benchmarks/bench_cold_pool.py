"""A restarted calibrator without state meets a long pool: the whole pool solved cold, against its newest tracks
solved cold and the whole pool warm from there (the live policy, `LiveConfig.cold_start_tracks`).

Renders config/surround.yaml every `--step` frames (2 fps: 15 frames = 7.5 s, about what a loaded live
matcher manages per frame set), pools the frame sets as the matcher does (5000 tracks) and, at each
`--at` count, solves the pool both ways and compares it with the simulation's truth. Also prints how
many of the pool's multi-view tracks are false (triangulated from all their views with the true
cameras, some view more than 2 px off), in its older and newer half.

    python benchmarks/bench_cold_pool.py [--step 15] [--at 6,10,16] [--cache DIR] [--epipolar-px 0]
                                         [--save DIR [--no-solve]]

--save writes each pool as DIR/surround-pool-<frame sets>.json.gz (camnet.observations/1, pixels to
1e-3 px): tests/data/surround-pool-10.json.gz was written so, with --step 15 --at 10.
Matching 1280x1024 images is slow; `--cache DIR` keeps each frame set's tracks so that later runs (of another
pool, say) only pool and solve.
"""

from __future__ import annotations

import argparse
import gzip
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from camnet.drivers.base import create_camera

from camnet.io.formats import observations_to_doc
from camnet.io.rig import load_rig
from camnet.live.policy import LiveConfig
from camnet.live.tracker import Tracker
from camnet.matching.engine import match_frame_set
from camnet.matching.features import MatcherConfig
from camnet.matching.pool import PoolConfig, TrackPool
from camnet.matching.tracks import FrameTracks, build_tracks
from camnet.model.accuracy import compare_cameras
from camnet.model.camera import CameraInfo
from camnet.model.observations import Observations, Stereo

FALSE_PX = 2.0


def false_tracks(obs: Observations, truth: dict) -> tuple[np.ndarray, np.ndarray]:
    """(multi-view, false) per track: seen by at least three cameras; some view off by more than FALSE_PX."""
    cams = [truth[c.id] for c in obs.cameras]
    P = [c.K @ np.hstack([c.R, c.t[:, None]]) for c in cams]
    views = np.bincount(obs.track_index, minlength=len(obs.track_ids))
    order = np.argsort(obs.track_index, kind="stable")
    starts = np.concatenate([[0], np.cumsum(views)])
    false = np.zeros(len(obs.track_ids), dtype=bool)
    for t in np.flatnonzero(views >= 3):
        rows = order[starts[t]:starts[t + 1]]
        A = np.concatenate([[u * P[obs.cam_index[r]][2] - P[obs.cam_index[r]][0],
                             v * P[obs.cam_index[r]][2] - P[obs.cam_index[r]][1]]
                            for r, (u, v) in zip(rows, obs.uv[rows], strict=True)])
        X = np.linalg.svd(A)[2][-1]
        X = X[:3] / X[3]
        false[t] = max(np.linalg.norm(cams[obs.cam_index[r]].project(X[None])[0] - obs.uv[r]) for r in rows) > FALSE_PX
    return views >= 3, false


def frame_tracks(cameras: dict, frame: int, stereo: Stereo, cache: Path | None) -> FrameTracks:
    """The tracks of frame `frame` of every camera, from `cache` when it holds them."""
    path = None if cache is None else cache / f"frame{frame:04d}.npz"
    if path is not None and path.exists():
        data = np.load(path)
        return FrameTracks(tuple(str(c) for c in data["camera_ids"]), data["uv"])
    images = {c: cam.render(frame) for c, cam in cameras.items()}
    tracks = build_tracks(match_frame_set(images, MatcherConfig(), stereo=stereo))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, camera_ids=np.array(tracks.camera_ids), uv=tracks.uv)
    return tracks


def solve_row(sets: int, name: str, config: LiveConfig, obs: Observations, truth_cameras) -> str:
    t0 = time.perf_counter()
    out = Tracker(config).update(obs)
    seconds = time.perf_counter() - t0
    if out.calibration is None:
        return f"| {sets} | {name} | {out.status}: {out.reason[:70]} | {seconds:.0f} | | | | |"
    c = compare_cameras(out.calibration, truth_cameras)
    left_out = ", ".join(out.calibration.report.cameras_left_out) or "-"
    return (f"| {sets} | {name} | {out.status} | {seconds:.0f} | {100 * c.scale_rel:+.2f} "
            f"({100 * c.scale_sigma_rel:.2f}) | {100 * max(abs(e.focal_rel) for e in c.cameras):.2f} | "
            f"{max(e.centre_mm for e in c.cameras):.0f} | {left_out} |")


def save_pool(path: Path, obs: Observations) -> None:
    """`obs` as a gzipped camnet.observations/1 document, pixels rounded to 1e-3 px (a tenth of a kilobyte a track)."""
    obs = replace(obs, uv=np.round(obs.uv, 3))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(gzip.compress(json.dumps(observations_to_doc(obs), separators=(",", ":")).encode(), mtime=0))
    print(f"wrote {path} ({len(obs.track_ids)} tracks)", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=int, default=15, help="frames between the frame sets pooled")
    parser.add_argument("--at", default="6,10,16", help="solve the pool after these many frame sets")
    parser.add_argument("--save", type=Path, help="write each pool to this folder")
    parser.add_argument("--no-solve", action="store_true", help="only render, pool and save")
    parser.add_argument("--epipolar-px", type=float, default=PoolConfig().epipolar_px,
                        help="the pool's check of views against each pair's pooled F, px (0: none)")
    parser.add_argument("--cache", type=Path, default=None, help="folder keeping each frame set's tracks")
    args = parser.parse_args()
    at = sorted(int(n) for n in args.at.split(","))
    rig = load_rig("config/surround.yaml")
    truth_cameras = rig.simulated_truth()
    truth = {c.id: c for c in truth_cameras}
    cameras = {c.id: create_camera(c, rig) for c in rig.cameras}
    infos = [CameraInfo(c.id, c.config.width, c.config.height) for c in rig.cameras]
    stereo = Stereo(rig.stereo.left, rig.stereo.right, rig.stereo.baseline_m, parallel=rig.stereo.parallel)
    pool = TrackPool(infos, stereo, PoolConfig(max_tracks=5000, epipolar_px=args.epipolar_px))
    rows = []
    for k in range(at[-1]):
        pool.add(frame_tracks(cameras, k * args.step, stereo, args.cache), frame_seq=k)
        if k + 1 not in at:
            continue
        obs = pool.observations()
        if args.save is not None:
            save_pool(args.save / f"surround-pool-{k + 1}.json.gz", obs)
        if args.no_solve:
            continue
        multi, false = false_tracks(obs, truth)
        newer = obs.track_ids >= np.median(obs.track_ids)
        print(f"{k + 1} frame sets: multi-view tracks false: older half {np.mean(false[multi & ~newer]):.0%} of "
              f"{np.sum(multi & ~newer)}, newer half {np.mean(false[multi & newer]):.0%} of {np.sum(multi & newer)}",
              flush=True)
        rows.append(solve_row(k + 1, "whole pool cold", LiveConfig(cold_start_tracks=len(obs.track_ids)), obs,
                              truth_cameras))
        rows.append(solve_row(k + 1, "newest 2500 cold, whole warm", LiveConfig(), obs, truth_cameras))
    print("| frame sets | cold solve | outcome | s | scale err % (sigma) | max focal err % | max centre err mm | "
          "left out |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
