#!/usr/bin/env python3
"""The rendered surround rig (config/surround.yaml): is every reported sigma honest?

Renders frame slots of the rig's nine simulated cameras, runs the matcher's
chain on each (SIFT, pairs, tracks: what tests/test_surround.py runs), pools
windows of `--sets` frame sets (consecutive, disjoint; `--interleaved` adds
windows of every (slots / sets)-th slot) and solves each as the live
calibrator does (LiveConfig). Prints per window and camera:

- the focal length's error over its reported sigma (z), the scale's, and
  the share of |z| < 3 (honest sigmas: about 99.7%; the target is 95%);
- the same focal errors over the part of each sigma that the observations
  give: the rest is the prior on the guessed principal point, which in
  this simulation is exact, so it widens the sigma without adding error;
- those shares, and of the observations' part, what tracks between cameras
  whose axes are >= WIDE_DEG apart give (the floor, at grazing angles);
- per camera the residual RMS at the truth (true cameras, points
  triangulated from them; corrected for the 3 of 2n residual degrees of
  freedom a point takes), the share of observations off by more than
  FALSE_PX there (false tracks), and how many pooled tracks share a true
  point with another (within SAME_POINT_M).

`--variants` solves the same pools altered, to test where the error comes
from: "no false" drops tracks off the truth by more than FALSE_PX; "one per
point" keeps one track per true point; "ideal+noise" replaces every pixel by
its true projection plus independent noise of its camera's RMS at the truth;
"shuffled" deals each camera's residuals at the truth out again at random;
"... wide" does either only to tracks between wide cameras; "no wide" drops
those; a " strict" suffix solves without the floor under the outlier
threshold (Options.min_outlier_px = 0).

Matching 1280x1024 images is slow (tens of seconds per frame set of nine);
`--cache DIR` keeps each slot's tracks so that later runs only solve.

    python benchmarks/bench_surround_sigmas.py [--slots 36] [--sets 6] [--cache DIR] [--interleaved]
        [--variants pooled,no false,...] [--epipolar-px 0]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from camnet.drivers.base import create_camera
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from camnet.errors import CamnetError
from camnet.io.rig import Rig, load_rig
from camnet.live.policy import LiveConfig, judge
from camnet.matching.engine import match_frame_set
from camnet.matching.features import MatcherConfig
from camnet.matching.pool import PoolConfig, TrackPool
from camnet.matching.tracks import FrameTracks, build_tracks
from camnet.model.accuracy import compare_cameras
from camnet.model.camera import Camera, CameraInfo
from camnet.model.observations import Observations, Stereo
from camnet.solve import Result, calibrate
from camnet.solve.bundle import apply_step, residuals
from camnet.solve.uncertainty import with_guessed_pp

RIG_FILE = Path(__file__).resolve().parents[1] / "config" / "surround.yaml"
SAME_POINT_M = 0.002
# At the truth a residual this long is a false track: 5 sigma of the 0.2 px that true tracks show here.
FALSE_PX = 1.0
# Tracks between cameras whose axes are this far apart: the floor at grazing angles from both.
WIDE_DEG = 100.0


def slot_tracks(rig: Rig, slot: int, cache: Path | None) -> FrameTracks:
    """The tracks of frame slot `slot` of every camera, from `cache` when it holds them."""
    path = None if cache is None else cache / f"slot{slot:03d}.npz"
    if path is not None and path.exists():
        data = np.load(path)
        return FrameTracks(tuple(str(c) for c in data["camera_ids"]), data["uv"])
    images = {c.id: create_camera(c, rig).render(slot) for c in rig.cameras}
    stereo = rig.stereo
    tracks = build_tracks(match_frame_set(images, MatcherConfig(), stereo=stereo))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, camera_ids=np.array(tracks.camera_ids), uv=tracks.uv)
    return tracks


def rig_stereo(rig: Rig) -> Stereo:
    s = rig.stereo
    return Stereo(s.left, s.right, s.baseline_m, parallel=s.parallel)


def pooled(rig: Rig, tracks: list[FrameTracks], pool: PoolConfig | None = None) -> Observations:
    infos = [CameraInfo(c.id, c.config.width, c.config.height) for c in rig.cameras]
    track_pool = TrackPool(infos, rig_stereo(rig), pool or PoolConfig())
    for seq, frame_tracks in enumerate(tracks):
        track_pool.add(frame_tracks, frame_seq=seq)
    return track_pool.observations()


def triangulate_true(obs: Observations, truth: dict[str, Camera]) -> np.ndarray:
    """(T, 3) each track's point from the true cameras (linear, on ideal pinhole pixels), m."""
    P = np.stack([truth[c.id].K @ np.column_stack([truth[c.id].R, truth[c.id].t]) for c in obs.cameras])
    T = len(obs.track_ids)
    A = np.zeros((T, 3 * len(obs.cameras), 4))  # two rows per view, unused rows stay zero
    rows = P[obs.cam_index]
    u, v = obs.uv[:, 0:1], obs.uv[:, 1:2]
    A[obs.track_index, 2 * obs.cam_index] = u * rows[:, 2] - rows[:, 0]
    A[obs.track_index, 2 * obs.cam_index + 1] = v * rows[:, 2] - rows[:, 1]
    X = np.linalg.svd(A)[2][:, -1]
    return X[:, :3] / X[:, 3:]


@dataclass(frozen=True)
class Residuals:
    rms_px: dict[str, float]  # per camera, at the truth
    bad_share: dict[str, float]  # per camera, residual > FALSE_PX at the truth (a false track, most likely)
    duplicate_tracks: int  # tracks whose true point another track of the pool also holds
    tracks: int


def residuals_at_truth(obs: Observations, truth: dict[str, Camera], X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) each observation's residual length at the truth, px (NaN: no point), and (T,) false tracks:
    those with a residual over FALSE_PX or none."""
    r = np.full(len(obs.uv), np.nan)
    for c, info in enumerate(obs.cameras):
        rows = obs.cam_index == c
        r[rows] = np.linalg.norm(truth[info.id].project(X[obs.track_index[rows]]) - obs.uv[rows], axis=1)
    false = np.zeros(len(X), bool)
    np.logical_or.at(false, obs.track_index, ~(r <= FALSE_PX))
    return r, false


def at_truth(obs: Observations, truth: dict[str, Camera]) -> Residuals:
    X = triangulate_true(obs, truth)
    r, bad_track = residuals_at_truth(obs, truth, X)
    good = ~bad_track[obs.track_index]
    views = np.bincount(obs.track_index, minlength=len(X))
    rms, bad = {}, {}
    for c, info in enumerate(obs.cameras):
        rows = obs.cam_index == c
        # A track's point takes 3 of its 2n residual degrees of freedom: scale each residual up to match.
        n = views[obs.track_index[rows & good]]
        rms[info.id] = float(np.sqrt(np.mean(r[rows & good] ** 2 * n / (2 * n - 3))))  # per axis
        bad[info.id] = float(np.mean(~(r[rows] <= FALSE_PX)))
    ok = np.flatnonzero(~bad_track)
    pairs = cKDTree(X[ok]).query_pairs(SAME_POINT_M, output_type="ndarray")
    duplicates = len(np.unique(pairs)) if len(pairs) else 0
    return Residuals(rms, bad, duplicates, len(X))


def keep_tracks(obs: Observations, keep: np.ndarray) -> Observations:
    """`obs` with only the tracks where `keep` (T,) is true."""
    rows = keep[obs.track_index]
    new_index = np.cumsum(keep) - 1
    return replace(obs, track_ids=obs.track_ids[keep], cam_index=obs.cam_index[rows],
                   track_index=new_index[obs.track_index[rows]], uv=obs.uv[rows])


def one_per_point(obs: Observations, X: np.ndarray) -> np.ndarray:
    """(T,) keep mask: of tracks whose true points lie within SAME_POINT_M, the one seen by most cameras."""
    finite = np.all(np.isfinite(X), axis=1)
    pairs = cKDTree(np.where(finite[:, None], X, 1e6 + np.arange(len(X))[:, None])).query_pairs(
        SAME_POINT_M, output_type="ndarray")
    n = len(X)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else \
        coo_matrix((n, n))
    _, label = connected_components(graph, directed=False)
    views = np.bincount(obs.track_index, minlength=n)
    order = np.lexsort((-views, label))  # by group, most views first
    keep = np.zeros(n, bool)
    first = np.ones(n, bool)
    first[1:] = label[order][1:] != label[order][:-1]
    keep[order[first]] = True
    return keep


def ideal_with_noise(obs: Observations, truth: dict[str, Camera], X: np.ndarray, rms_px: dict[str, float],
                     seed: int, only: np.ndarray | None = None) -> Observations:
    """`obs` with each pixel replaced by the true projection of its track's point plus independent noise
    of its camera's measured RMS: the same tracks and geometry, the noise the solve assumes."""
    rng = np.random.default_rng(seed)
    uv = obs.uv.copy()
    for c, info in enumerate(obs.cameras):
        rows = (obs.cam_index == c) & (True if only is None else only[obs.track_index])
        uv[rows] = truth[info.id].project(X[obs.track_index[rows]]) + rng.normal(0, rms_px[info.id], (rows.sum(), 2))
    return replace(obs, uv=uv)


def shuffled_residuals(obs: Observations, truth: dict[str, Camera], X: np.ndarray, seed: int,
                       only: np.ndarray | None = None) -> Observations:
    """`obs` with each camera's residuals at the truth dealt out again among its observations at random:
    the same distribution of errors per camera, with any tie to the scene or the image position broken."""
    rng = np.random.default_rng(seed)
    uv = obs.uv.copy()
    views = np.bincount(obs.track_index, minlength=len(X))
    for c, info in enumerate(obs.cameras):
        rows = np.flatnonzero((obs.cam_index == c) & (True if only is None else only[obs.track_index]))
        ideal = truth[info.id].project(X[obs.track_index[rows]])
        n = views[obs.track_index[rows]]
        r = (obs.uv[rows] - ideal) * np.sqrt(2 * n / (2 * n - 3))[:, None]
        uv[rows] = ideal + r[rng.permutation(len(rows))]
    return replace(obs, uv=uv)


def widest_axis_angle_deg(obs: Observations, truth: dict[str, Camera]) -> np.ndarray:
    """(T,) the largest angle between the optical axes of two cameras that see a track, degrees."""
    axes = np.stack([truth[c.id].R[2] for c in obs.cameras])
    seen = np.zeros((len(obs.track_ids), len(obs.cameras)), bool)
    seen[obs.track_index, obs.cam_index] = True
    cos = np.clip(axes @ axes.T, -1.0, 1.0)
    widest = np.zeros(len(obs.track_ids))
    for a in range(len(axes)):
        for b in range(a + 1, len(axes)):
            both = seen[:, a] & seen[:, b]
            widest[both] = np.maximum(widest[both], np.degrees(np.arccos(cos[a, b])))
    return widest


VARIANTS = ("pooled", "no false", "one per point", "ideal+noise", "shuffled", "no wide", "no wide+false",
            "ideal+noise wide", "shuffled wide")


def variant(name: str, obs: Observations, truth: dict[str, Camera], seed: int) -> Observations:
    if name == "pooled":
        return obs
    if name == "no wide":
        return keep_tracks(obs, widest_axis_angle_deg(obs, truth) < WIDE_DEG)
    if name == "no wide+false":
        obs = keep_tracks(obs, widest_axis_angle_deg(obs, truth) < WIDE_DEG)
        name = "no false"
    X = triangulate_true(obs, truth)
    res = at_truth(obs, truth)
    _, bad = residuals_at_truth(obs, truth, X)
    clean = keep_tracks(obs, ~bad)
    if name == "no false":
        return clean
    Xc = X[~bad]
    if name == "one per point":
        return keep_tracks(clean, one_per_point(clean, Xc))
    wide = widest_axis_angle_deg(clean, truth) >= WIDE_DEG if name.endswith(" wide") else None
    if name.startswith("shuffled"):
        return shuffled_residuals(clean, truth, Xc, seed, wide)
    return ideal_with_noise(clean, truth, Xc, res.rms_px, seed, wide)


@dataclass(frozen=True)
class Window:
    slots: tuple[int, ...]
    verdict: str  # "" when the live policy accepts the solve
    focal_z: dict[str, float]
    focal_sigma_pct: dict[str, float]
    scale_z: float
    scale_sigma_pct: float
    sigma_px: float
    residuals: Residuals
    focal_data_share: dict[str, float]  # of the focal variance, what the observations give (the rest: pp prior)
    focal_wide_share: dict[str, float]  # of the observations' part, what tracks between wide cameras give


def solve_window(rig: Rig, slots: tuple[int, ...], obs: Observations, *, strict: bool = False) -> Window | str:
    truth = {c.id: c for c in rig.simulated_truth()}
    live = LiveConfig()
    if strict:  # reject by the robust sigma alone, with no floor under the threshold
        live = replace(live, options=replace(live.options, min_outlier_px=0.0))
    try:
        result = calibrate(obs, live.options)
    except CamnetError as exc:
        return f"refused: {str(exc)[:100]}"
    cal = result.calibration
    errors = compare_cameras(cal, list(truth.values()))
    focal_z = {e.id: e.focal_rel / e.focal_sigma_rel for e in errors.cameras}
    focal_sigma = {e.id: 100 * e.focal_sigma_rel for e in errors.cameras}
    sigma_px = result.covariance.sigma_px if result.covariance is not None else float("nan")
    data_share, wide_share = focal_influence(result, widest_axis_angle_deg(obs, truth) >= WIDE_DEG)
    return Window(slots, judge(cal, obs, live), focal_z, focal_sigma, errors.scale_rel / errors.scale_sigma_rel,
                  100 * errors.scale_sigma_rel, sigma_px, at_truth(obs, truth), data_share, wide_share)


def focal_influence(result: Result, wide_track: np.ndarray) -> tuple[dict[str, float], dict[str, float]]:
    """Per camera: the share of its focal variance the observations give (the rest is the guessed
    principal point's prior), and of that, the share of the observations of `wide_track` (T,) tracks.

    The influence of observation k on focal length j is ``J_k H^-1 e_j`` (px per px), taken by a central
    difference along ``H^-1 e_j``; the classic variance is sigma^2 times the sum of its squares.
    """
    cov, state = result.covariance, result.state
    problem = with_guessed_pp(result.problem, np.ones(len(result.order), bool))
    cols = problem.columns()[0]
    ids = [result.calibration.cameras[i].id for i in result.order]
    wide_row = wide_track[result.track_rows][problem.pt]
    data, wide = {}, {}
    for m, j in enumerate(cols[:, 0]):
        if j < 0 or cov is None or not cov.S_inv[j, j] > 0:
            continue
        y_cam = cov.S_inv[:, j]
        y_pts = -np.einsum("nij,nj->ni", cov.V_inv, (cov.W.T @ y_cam).reshape(-1, 3))
        eps = 1e-4 / np.sqrt(cov.S_inv[j, j])
        a = (residuals(problem, apply_step(problem, state, eps * y_cam, eps * y_pts))
             - residuals(problem, apply_step(problem, state, -eps * y_cam, -eps * y_pts))) / (2 * eps)
        w = np.sum(a * a, axis=1)
        data[ids[m]] = float(w.sum() / cov.S_inv[j, j])
        wide[ids[m]] = float(w[wide_row].sum() / w.sum())
    return data, wide


def label(slots: tuple[int, ...]) -> str:
    step = slots[1] - slots[0] if len(slots) > 1 else 1
    return f"{slots[0]}-{slots[-1]}" + (f"/{step}" if step > 1 else "")


def print_table(windows: list[Window], camera_ids: list[str]) -> None:
    print("focal error / reported sigma (z) per camera, then scale; * where |z| >= 3")
    print(f"{'slots':<8}" + "".join(f"{c[-6:]:>8}" for c in camera_ids) + f"{'scale':>8}{'sigma px':>9}  verdict")
    for w in windows:
        cells = [w.focal_z.get(c, np.nan) for c in camera_ids] + [w.scale_z]
        text = "".join(f"{z:>7.2f}{'*' if abs(z) >= 3 else ' '}" for z in cells)
        print(f"{label(w.slots):<8}{text}{w.sigma_px:>9.3f}  {w.verdict or 'good'}")
    print(f"{'sigma %':<8}" + "".join(
        f"{np.median([w.focal_sigma_pct.get(c, np.nan) for w in windows]):>8.3f}" for c in camera_ids)
        + f"{np.median([w.scale_sigma_pct for w in windows]):>8.3f}  (medians)")
    z = np.array([[w.focal_z.get(c, np.nan) for c in camera_ids] + [w.scale_z] for w in windows])
    finite = np.isfinite(z)
    print(f"|z| < 3: {np.mean(np.abs(z[finite]) < 3):.1%} of {finite.sum()}; "
          f"RMS z per column: " + " ".join(f"{np.sqrt(np.nanmean(col ** 2)):.2f}" for col in z.T))
    print("focal error over the observations' part of its sigma (the simulation's principal points are the "
          "guessed ones exactly, so their prior adds sigma but no error)")
    zd = np.array([[w.focal_z.get(c, np.nan) / np.sqrt(w.focal_data_share.get(c, np.nan)) for c in camera_ids]
                   for w in windows])
    for w, row in zip(windows, zd, strict=True):
        print(f"{label(w.slots):<8}" + "".join(f"{z:>7.2f}{'*' if abs(z) >= 3 else ' '}" for z in row))
    finite = np.isfinite(zd)
    print(f"|z| < 3: {np.mean(np.abs(zd[finite]) < 3):.1%} of {finite.sum()}; "
          f"RMS z {np.sqrt(np.mean(zd[finite] ** 2)):.2f}; per column: "
          + " ".join(f"{np.sqrt(np.nanmean(col ** 2)):.2f}" for col in zd.T))
    print("share of each focal variance from the observations (the rest: the principal point's prior), "
          f"and of that, from tracks between cameras >= {WIDE_DEG:.0f} degrees apart")
    for w in windows:
        print(f"{label(w.slots):<8}" + "".join(f"{w.focal_data_share.get(c, np.nan):>8.2f}" for c in camera_ids))
        print(f"{'  wide':<8}" + "".join(f"{w.focal_wide_share.get(c, np.nan):>8.2f}" for c in camera_ids))
    print()
    print("at the truth: per-axis residual RMS px per camera (tracks with a residual over "
          f"{FALSE_PX} px left out), share of observations beyond it, tracks sharing a true point")
    print(f"{'slots':<8}" + "".join(f"{c[-6:]:>8}" for c in camera_ids) + f"{'dup':>7}{'tracks':>8}")
    for w in windows:
        r = w.residuals
        print(f"{label(w.slots):<8}" + "".join(f"{r.rms_px[c]:>8.3f}" for c in camera_ids)
              + f"{r.duplicate_tracks:>7}{r.tracks:>8}")
        print(f"{'  >' + str(FALSE_PX):<8}" + "".join(f"{100 * r.bad_share[c]:>7.1f}%" for c in camera_ids))


def selections(n_slots: int, sets: int, *, interleaved: bool) -> list[tuple[int, ...]]:
    """Disjoint windows of `sets` consecutive slots; with `interleaved`, also every (n_slots // sets)-th slot."""
    out = [tuple(range(start, start + sets)) for start in range(0, n_slots - sets + 1, sets)]
    if interleaved:
        step = n_slots // sets
        out += [tuple(range(first, first + step * sets, step)) for first in range(step)]
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slots", type=int, default=36, help="frame slots to render and match")
    parser.add_argument("--sets", type=int, default=6, help="frame sets per solve")
    parser.add_argument("--cache", type=Path, default=None, help="folder keeping each slot's tracks")
    parser.add_argument("--variants", default="pooled",
                        help=f"comma-separated, of {', '.join(VARIANTS)}, each also with ' strict' "
                        "(outliers by the robust sigma alone)")
    parser.add_argument("--epipolar-px", type=float, default=PoolConfig().epipolar_px,
                        help="the pool's check of views against each pair's pooled F, px (0: none)")
    parser.add_argument("--interleaved", action="store_true",
                        help="also solve windows of every (slots / sets)-th slot (other frame-set selections)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    rig = load_rig(RIG_FILE)
    t0 = time.perf_counter()
    tracks = []
    for slot in range(args.slots):
        tracks.append(slot_tracks(rig, slot, args.cache))
        print(f"slot {slot}: {len(tracks[-1])} tracks ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    truth = {c.id: c for c in rig.simulated_truth()}
    for name in args.variants.split(","):
        windows = []
        for slots in selections(args.slots, args.sets, interleaved=args.interleaved):
            base = name.removesuffix(" strict")
            pool = PoolConfig(epipolar_px=args.epipolar_px)
            obs = variant(base, pooled(rig, [tracks[s] for s in slots], pool), truth, seed=slots[0])
            w = solve_window(rig, slots, obs, strict=name.endswith(" strict"))
            if isinstance(w, str):
                print(f"slots {slots}: {w}")
                continue
            windows.append(w)
        print(f"== {name}: {len(windows)} windows of {args.sets} frame sets")
        print_table(windows, [c.id for c in rig.cameras])
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
