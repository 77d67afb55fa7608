"""Pooling tracks over frame sets: bound, duplicates, spread, output."""

from __future__ import annotations

import numpy as np
import pytest

from camnet.io.formats import observations_to_doc, parse_observations
from camnet.matching.pool import MOVED_FRAME_SETS, PoolConfig, TrackPool, crowding, dedupe_frame_tracks
from camnet.matching.tracks import FrameTracks
from camnet.model.camera import CameraInfo
from camnet.model.observations import Stereo

CAMS = (CameraInfo("L", 640, 480), CameraInfo("R", 640, 480), CameraInfo("M", 640, 480))
STEREO = Stereo("L", "R", 0.12)
NAN = np.nan


def _tracks(rows, ids=("L", "R", "M")) -> FrameTracks:
    return FrameTracks(tuple(ids), np.array(rows, dtype=float).reshape(len(rows), len(ids), 2))


def test_same_frame_duplicates_merge_when_consistent_else_weaker_dropped():
    uv = np.array(
        [
            [[100, 100], [80, 100], [NAN, NAN]],
            [[100.4, 100.3], [NAN, NAN], [120, 90]],  # same point via another pair: merge
            [[300, 300], [280, 300], [310, 290]],
            [[300.5, 300], [200, 300], [NAN, NAN]],  # same left pixel, other right: drop
        ]
    )
    out, removed = dedupe_frame_tracks(uv, 1.0)
    assert removed == 2
    assert np.isfinite(out[:, :, 0]).sum(axis=1).tolist() == [3, 3]
    assert np.allclose(out[0, 2], [120, 90])


def test_across_frames_one_coinciding_camera_is_a_new_point_two_are_the_same():
    pool = TrackPool(CAMS, STEREO)
    pool.add(_tracks([[[100, 100], [80, 100], [NAN, NAN]]]), frame_seq=0)
    # Same left pixel, different right pixel: a moved object at another depth.
    u1 = pool.add(_tracks([[[100, 100], [60, 100], [NAN, NAN]]]), frame_seq=1)
    assert (u1.added, u1.reobserved) == (1, 0)
    # Same pixels in L and R: same 3-D point (static background); M gets added to it.
    u2 = pool.add(_tracks([[[100.3, 100], [80.2, 100], [130, 95]]]), frame_seq=2)
    assert (u2.added, u2.reobserved) == (0, 1)
    obs = pool.observations()
    assert len(obs.track_ids) == 2
    assert np.bincount(obs.track_index).tolist() == [3, 2]


def test_pool_is_bounded_and_spreads_over_the_image():
    rng = np.random.default_rng(0)
    pool = TrackPool(CAMS, STEREO, PoolConfig(max_tracks=400, grid_cols=4, grid_rows=4))

    offered_outside = 0

    def batch(n, lo, hi):
        nonlocal offered_outside
        left = rng.uniform(lo, hi, size=(n, 2))
        offered_outside += int(np.sum((left[:, 0] >= 159.5) | (left[:, 1] >= 119.5)))
        right = left - [20.0, 0.0]
        return _tracks(np.stack([left, right, np.full((n, 2), NAN)], axis=1))

    for seq in range(5):
        # Each frame set: a dense textured patch in one corner plus a few points elsewhere.
        pool.add(batch(300, [5, 5], [120, 100]), frame_seq=seq)
        pool.add(batch(30, [0, 0], [639, 479]), frame_seq=seq)
    assert len(pool) == 400
    obs = pool.observations()
    left = obs.uv[obs.cam_index == 0]
    cols = np.clip((left[:, 0] + 0.5) / 640 * 4, 0, 3).astype(int)
    rows = np.clip((left[:, 1] + 0.5) / 480 * 4, 0, 3).astype(int)
    occupied = np.unique(rows * 4 + cols).size
    outside = int(np.sum((left[:, 0] >= 159.5) | (left[:, 1] >= 119.5)))
    assert occupied == 16
    # 1500 of 1650 offered tracks sit in the corner cell; eviction must take
    # from there and keep every sparse track elsewhere.
    assert outside == offered_outside
    assert 100 < outside < 400


def test_eviction_prefers_fewer_views_then_older():
    pool = TrackPool(CAMS, STEREO, PoolConfig(max_tracks=2, grid_cols=1, grid_rows=1))
    pool.add(_tracks([[[10, 10], [5, 10], [NAN, NAN]]]), frame_seq=0)  # old, 2 views
    pool.add(_tracks([[[50, 50], [45, 50], [60, 50]]]), frame_seq=1)  # 3 views
    pool.add(_tracks([[[90, 90], [85, 90], [NAN, NAN]]]), frame_seq=2)  # new, 2 views
    obs = pool.observations()
    kept = sorted(obs.uv[obs.cam_index == 0, 0].tolist())
    assert kept == [50.0, 90.0]


def test_observations_round_trip_through_the_json_contract():
    pool = TrackPool(CAMS, STEREO)
    pool.add(_tracks([[[1, 2], [3, 4]], [[10, 20], [NAN, NAN]]], ids=("L", "M")), frame_seq=0)
    pool.add(_tracks([[[100, 200], [90, 200], [50, 60]]]), frame_seq=1)
    obs = pool.observations()
    back = parse_observations(observations_to_doc(obs))
    assert back.camera_ids == ["L", "R", "M"]
    assert back.stereo == STEREO
    assert back.track_ids.tolist() == obs.track_ids.tolist()
    # the single-view track is no track; the M-only row had one camera
    assert np.allclose(back.uv, obs.uv)


def test_unknown_camera_is_rejected():
    pool = TrackPool(CAMS, STEREO)
    with pytest.raises(ValueError, match="'X'"):
        pool.add(_tracks([[[1, 2], [3, 4]]], ids=("L", "X")), frame_seq=0)


def test_crowding_counts_the_fullest_cell():
    uv = np.array([[[10, 10]], [[20, 20]], [[600, 400]]], dtype=float)
    assert crowding(uv, np.array([[640, 480]]), 2, 2).tolist() == [2, 2, 1]


def _camera(centre, yaw_deg, f=500.0, size=(640, 480)):
    """3x4 projection of a camera at `centre` (m) turned by `yaw_deg` about the y axis (x_cam = R X + t)."""
    a = np.radians(yaw_deg)
    R = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
    K = np.array([[f, 0, (size[0] - 1) / 2], [0, f, (size[1] - 1) / 2], [0, 0, 1]])
    return K @ np.column_stack([R, -R @ np.asarray(centre, float)])


def test_false_tracks_do_not_accumulate_in_the_sparse_cells():
    # A moving object in the middle of every image gives new true tracks each frame set; a few false
    # ones (each frame set's matching lets some through) fall where true ones are sparse, near the
    # image corners, which eviction spares. Pooled with the default check, their share must stay near a
    # frame set's (without it: 12% of the pool against 6% offered).
    rng = np.random.default_rng(3)
    P = [_camera([0, 0, 0], 0), _camera([0.12, 0, 0], 0), _camera([-0.8, 0, 0.2], -35)]
    pool = TrackPool(CAMS, STEREO, PoolConfig(max_tracks=600))
    false_offered = offered = 0
    for seq in range(20):
        X = rng.uniform([-0.15, -0.15, 1.4], [0.25, 0.15, 1.8], size=(120, 3))
        x = np.stack([(p @ np.column_stack([X, np.ones(len(X))]).T).T for p in P], axis=1)
        true_uv = x[:, :, :2] / x[:, :, 2:] + rng.normal(0, 0.2, (len(X), 3, 2))
        corner = rng.uniform([0, 0], [100, 80], size=(8, 3, 2)) + rng.integers(0, 2, (8, 3, 1)) * [540, 400]
        corner[: len(corner) // 2, 1] = NAN  # some seen by L and M only
        uv = np.concatenate([true_uv, corner])
        offered += len(uv)
        false_offered += len(corner)
        pool.add(FrameTracks(("L", "R", "M"), uv), frame_seq=seq)
    obs = pool.observations()
    # The object's points project within 100 px of L's centre column; every false track has an L corner.
    off_object = (obs.cam_index == 0) & (np.abs(obs.uv[:, 0] - 319.5) > 150)
    false_share = np.unique(obs.track_index[off_object]).size / len(obs.track_ids)
    assert false_share <= 2 * false_offered / offered, f"{false_share:.1%} of the pool is false"
    assert len(pool) == 600  # true tracks are not dropped with them


RIG = (_camera([0, 0, 0], 0), _camera([0.12, 0, 0], 0), _camera([-0.8, 0, 0.2], -35))


def _project(X: np.ndarray, rng, noise_px: float = 0.2) -> np.ndarray:
    """(n, 3, 2) pixels of points X (n, 3) in RIG's cameras, with noise."""
    x = np.stack([(p @ np.column_stack([X, np.ones(len(X))]).T).T for p in RIG], axis=1)
    return x[:, :, :2] / x[:, :, 2:] + rng.normal(0, noise_px, (len(X), 3, 2))


def test_true_tracks_survive_an_f_first_fitted_to_a_plane():
    # The first frame sets see only the floor: every F through the floor's homography fits them, so the F
    # the pool fits first may be pixels off the later, off-floor points (docs/benchmarks.md, "The surround
    # rig, live"). Those are true: none may go.
    rng = np.random.default_rng(5)
    pool = TrackPool(CAMS, STEREO, PoolConfig(max_tracks=10_000))
    for seq in range(8):
        if seq < 3:
            X = np.column_stack([rng.uniform(-0.3, 0.4, 150), np.full(150, 0.25), rng.uniform(1.3, 1.9, 150)])
        else:
            X = rng.uniform([-0.15, -0.15, 1.4], [0.25, 0.15, 1.8], size=(150, 3))
        update = pool.add(FrameTracks(("L", "R", "M"), _project(X, rng)), frame_seq=seq)
        assert update.rejected == 0, f"frame set {seq}: {update.rejected} true tracks dropped"
    assert len(pool) > 1000 and len(pool.observations().uv) == 3 * len(pool)  # and every view kept


def test_a_false_view_goes_and_its_track_stays():
    # A track whose M view is false is off its F in L-M and R-M but not in L-R: the M view is to blame.
    rng = np.random.default_rng(6)
    pool = TrackPool(CAMS, STEREO, PoolConfig(max_tracks=10_000))
    for seq in range(4):
        X = rng.uniform([-0.15, -0.15, 1.4], [0.25, 0.15, 1.8], size=(100, 3))
        pool.add(FrameTracks(("L", "R", "M"), _project(X, rng)), frame_seq=seq)
    uv = _project(np.array([[0.05, 0.0, 1.6], [0.1, 0.05, 1.5]]), rng)
    uv[0, 2] += [0.0, 25.0]  # M's view of the first point: 25 px off, across the epipolar lines
    before = len(pool)
    pool.add(FrameTracks(("L", "R", "M"), uv), frame_seq=4)
    obs = pool.observations()
    views = np.bincount(obs.track_index, minlength=len(pool))
    assert len(pool) == before + 2
    assert views[-2:].tolist() == [2, 3]
    assert np.allclose(obs.uv[obs.track_index == len(pool) - 2], uv[0, :2])


def _pool_across_a_move(forget: bool) -> tuple[TrackPool, int, int]:
    """(pool, first track id after M moved 4 cm down, M views offered since): 8 frame sets before the move,
    then one of 4 points (a camera that just came back sees little) and 6 of 100; with `forget`, the pool
    forgets M between."""
    moved = RIG[:2] + (_camera([-0.8, -0.04, 0.2], -35),)
    rng = np.random.default_rng(7)
    pool = TrackPool(CAMS, STEREO, PoolConfig(max_tracks=10_000))
    for seq in range(8):
        X = rng.uniform([-0.15, -0.15, 1.4], [0.25, 0.15, 1.8], size=(100, 3))
        pool.add(FrameTracks(("L", "R", "M"), _project(X, rng)), frame_seq=seq)
    if forget:
        pool.forget_camera("M")
    first, offered = pool.observations().track_ids.max() + 1, 0
    for seq, n in enumerate([4] + [100] * 6, start=8):
        X = rng.uniform([-0.15, -0.15, 1.4], [0.25, 0.15, 1.8], size=(n, 3))
        x = np.stack([(p @ np.column_stack([X, np.ones(n)]).T).T for p in moved], axis=1)
        pool.add(FrameTracks(("L", "R", "M"), x[:, :, :2] / x[:, :, 2:] + rng.normal(0, 0.2, (n, 3, 2))),
                 frame_seq=seq)
        offered += n
    return pool, first, offered


def test_a_forgotten_moved_camera_keeps_its_new_views():
    # A moved camera's new views judged against the F its old-pose views dominate would be dropped, and those
    # that happen to fit the old geometry survive: a biased selection the calibrator cannot see. Forgotten,
    # its views are all gone (old tracks keep their other views), and its new ones are judged only against
    # an F fitted to them, the first few too.
    pool, first, offered = _pool_across_a_move(forget=True)
    obs = pool.observations()
    new_m = (obs.cam_index == 2) & (obs.track_ids[obs.track_index] >= first)
    old_m = (obs.cam_index == 2) & (obs.track_ids[obs.track_index] < first)
    kept = obs.track_ids[obs.track_index[new_m]]
    assert set(range(first, first + 4)) <= set(kept.tolist()), "the first few new views were judged by the old F"
    assert pool.forgotten == {"M": first}  # said with the observations: the calibrator places M from these
    assert new_m.sum() + old_m.sum() >= 0.95 * offered, f"{new_m.sum()} of {offered} new views kept"
    # Old tracks hold M only where a new view merged into them (coinciding in L and R).
    assert old_m.sum() < 0.1 * offered


def test_a_camera_whose_new_views_break_its_pairs_geometry_alone_is_taken_for_moved():
    # Not told (the calibrator, seeing only the views the old F let through, would never find the move):
    # the third frame set running of 100 tracks in which M alone is off its pairs' F makes the pool forget M's
    # earlier views, and keep the new ones since the first, not judge them against the old F, which keeps few
    # and leaves the move unseen.
    pool, first, offered = _pool_across_a_move(forget=False)
    obs = pool.observations()
    new_m = (obs.cam_index == 2) & (obs.track_ids[obs.track_index] >= first)
    old_m = (obs.cam_index == 2) & (obs.track_ids[obs.track_index] < first)
    assert new_m.sum() >= 0.9 * (offered - 4), f"{new_m.sum()} of {offered} new views kept"
    assert old_m.sum() < 0.1 * offered  # its views of the old pose are gone
    # From the frame set that found the move on: the calibrator places M from those, not from the few of the
    # first new frame set that its old F let through.
    assert first + 4 <= pool.forgotten["M"] <= obs.track_ids.max() and set(pool.forgotten) == {"M"}
    # A camera that did not move is never taken for moved: L and R keep every view of the 8 sets before.
    assert ((obs.cam_index == 0) & (obs.track_ids[obs.track_index] < first)).sum() >= 0.95 * 800


def test_a_camera_off_its_pairs_geometry_in_fewer_frame_sets_running_than_a_move_takes_is_not_taken_for_moved():
    # A person moving between free-running cameras' capture instants puts one camera's views off for a frame
    # set or two: not a move, and its views of before are kept.
    skewed = RIG[:2] + (_camera([-0.8, -0.04, 0.2], -35),)
    rng = np.random.default_rng(7)
    pool = TrackPool(CAMS, STEREO, PoolConfig(max_tracks=10_000))
    for seq in range(8 + MOVED_FRAME_SETS + 2):
        seen_by = skewed if 8 <= seq < 8 + MOVED_FRAME_SETS - 1 else RIG
        X = rng.uniform([-0.15, -0.15, 1.4], [0.25, 0.15, 1.8], size=(100, 3))
        x = np.stack([(p @ np.column_stack([X, np.ones(100)]).T).T for p in seen_by], axis=1)
        pool.add(FrameTracks(("L", "R", "M"), x[:, :, :2] / x[:, :, 2:] + rng.normal(0, 0.2, (100, 3, 2))),
                 frame_seq=seq)

    assert pool.forgotten == {}
    obs = pool.observations()
    # Its views of the 8 frame sets before (the first 800 tracks) are all kept.
    assert ((obs.cam_index == 2) & (obs.track_ids[obs.track_index] < 800)).sum() >= 0.95 * 800


def test_forgetting_a_camera_drops_the_tracks_left_with_one_view():
    pool = TrackPool(CAMS, STEREO, PoolConfig(epipolar_px=0))
    pool.add(_tracks([[(10, 10), (20, 10), (NAN, NAN)], [(50, 50), (NAN, NAN), (60, 50)],
                      [(90, 90), (95, 90), (99, 90)]]),
             frame_seq=0)
    assert pool.forget_camera("M") == 1
    obs = pool.observations()
    assert obs.track_ids.tolist() == [0, 2] and 2 not in obs.cam_index.tolist()
    with pytest.raises(ValueError, match="not in the pool"):
        pool.forget_camera("X")
