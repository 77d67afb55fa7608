"""The live world frame stays put: held from solve to solve while the floor does, carried through the cameras that
stayed when a stereo head is moved, and set anew, said so, when the floor itself moves beyond its sigmas."""

from dataclasses import replace

import numpy as np

from camnet.live.held_world import HOLD_SIGMAS, held_floor
from camnet.live.policy import LIVE_FREE, LiveConfig
from camnet.live.tracker import Tracker
from camnet.model.calibration import FloorFrame, in_world_frame
from camnet.model.projection import rotation_exp
from camnet.sim.simulate import make_rig, observe, with_floor
from camnet.solve import Options
from camnet.solve.options import World
from tests.test_live import moved, pooled


def floor_rig(seed: int):
    rig, _ = with_floor(make_rig(n_points=300, seed=seed), pitch_deg=10.0, seed=seed)
    return rig


def centres(cal) -> dict:
    return {c.id: c.centre for c in in_world_frame(cal).cameras}


def test_the_world_frame_is_held_and_a_moved_camera_moves_only_itself_in_it():
    before = floor_rig(3)
    tracker = Tracker(LiveConfig(options=Options(free=LIVE_FREE, world=World.FLOOR)))
    first = tracker.update(observe(before, seed=5).observations)
    assert first.status == "good" and first.calibration.floor_frame.found, first.reason
    shift = np.array([0.0, -0.04, 0.0])  # mono_b lifted 4 cm, in the left camera's frame
    after = replace(floor_rig(4), cameras=[*before.cameras[:3], moved(before.cameras[3], shift, 0.0)])
    pool = pooled(observe(before, seed=5).observations, observe(after, seed=6).observations)

    out = tracker.update(pool)

    assert out.status == "good" and out.moved == ("mono_b",), (out.reason, out.moved)
    cal, was = out.calibration, centres(first.calibration)
    now, sigma = centres(cal), cal.uncertainty.cameras
    assert not any(w.startswith("the world frame was set anew") for w in cal.warnings), cal.warnings
    lift = first.calibration.floor_frame.R @ shift  # the same 4 cm in the world frame
    for cam_id in now:
        expected = was[cam_id] + (lift if cam_id == "mono_b" else 0.0)
        error = np.linalg.norm(now[cam_id] - expected)
        assert error <= 3 * np.linalg.norm(sigma[cam_id].centre_m) + 1e-3, (cam_id, error)
    assert abs(now["mono_b"][2] - was["mono_b"][2] - 0.04) < 0.01  # it rose 4 cm above the floor
    # Solved again on a grown pool, the frame is the one held: the cameras that stayed keep their world place to
    # what the solve itself moved them in the left camera's frame, not the floor's fresh fit's jitter on top.
    again = tracker.update(pooled(pool, observe(replace(after, points=after.points[:60] + 0.002),
                                                seed=7).observations)).calibration
    assert again.floor_frame.found and not any("set anew" in w for w in again.warnings)
    for cam_id, c in centres(again).items():
        assert np.linalg.norm(c - now[cam_id]) <= 3 * np.linalg.norm(sigma[cam_id].centre_m) + 1e-3, cam_id


def test_a_floor_that_moved_beyond_its_sigmas_is_set_anew_and_said_so():
    rig = floor_rig(2)
    tracker = Tracker(LiveConfig(options=Options(free=LIVE_FREE, world=World.FLOOR)))
    cal = tracker.update(observe(rig, seed=1).observations).calibration
    frame = cal.floor_frame
    same, said = held_floor(cal, cal, {c.id for c in cal.cameras})
    assert said == "" and np.allclose(same.R, frame.R) and np.allclose(same.t, frame.t)
    # The same calibration with its floor found 5 sigma of height lower: the floor moved, not the jitter.
    lower = replace(cal, floor_frame=replace(frame, t=frame.t + [0.0, 0.0, 5 * frame.height_sigma_m]))
    kept, said = held_floor(cal, lower, {c.id for c in cal.cameras})
    assert kept is lower.floor_frame
    assert said.startswith("the world frame was set anew: the floor moved by") and "5.0 sigma)" in said, said
    # Within HOLD_SIGMAS the held frame stays.
    near = replace(cal, floor_frame=replace(frame, t=frame.t + [0.0, 0.0, 0.5 * HOLD_SIGMAS * frame.height_sigma_m]))
    kept, said = held_floor(cal, near, {c.id for c in cal.cameras})
    assert said == "" and np.allclose(kept.t, frame.t) and np.allclose(kept.R, frame.R)


def test_a_solve_that_sees_no_floor_keeps_the_held_frame_through_the_cameras_that_stayed():
    # After a stereo head's move the rig is solved afresh from the new tracks alone, in the moved left camera's
    # frame, and those may show no floor: the floor has not left the room, so the held frame is carried.
    rig = floor_rig(2)
    tracker = Tracker(LiveConfig(options=Options(free=LIVE_FREE, world=World.FLOOR)))
    cal = tracker.update(observe(rig, seed=1).observations).calibration
    Q, d = rotation_exp(np.radians([2.0, -5.0, 1.0])), np.array([0.04, -0.02, 0.01])  # X_new = Q X + d
    cameras = []
    for c in cal.cameras:
        R = c.R @ Q.T
        cameras.append(replace(c, R=R, t=-R @ (Q @ c.centre + d)))
    unseen = FloorFrame(np.eye(3), np.zeros(3), reason="no floor in view (none below the cameras)")
    new = replace(cal, cameras=tuple(cameras), floor_frame=unseen)

    kept, said = held_floor(cal, new, {c.id for c in cal.cameras})

    assert said == "" and kept.found, said
    assert (kept.normal_sigma_deg, kept.height_sigma_m) == (cal.floor_frame.normal_sigma_deg,
                                                           cal.floor_frame.height_sigma_m)
    was, now = centres(cal), centres(replace(new, floor_frame=kept))
    for cam_id in was:
        assert np.linalg.norm(now[cam_id] - was[cam_id]) < 1e-9, cam_id
    # The tracker's calibration keeps the held frame, and no warning of a floor out of view.
    warned = replace(new, report=replace(new.report, warnings=(*new.report.warnings, unseen.reason)))
    held = tracker._world_held(warned, ())
    assert np.allclose(held.floor_frame.R, kept.R) and np.allclose(held.floor_frame.t, kept.t)
    assert held.floor_frame.found and unseen.reason not in held.warnings, held.warnings


def surround(seed: int):
    rig, _ = with_floor(make_rig(n_cameras=8, n_points=400, seed=seed), pitch_deg=10.0, seed=seed)
    return rig


def moved_at_once(indices: list[int]):
    """(tracker, its first outcome, the outcome on a pool of tracks from before and after the cameras at
    `indices` moved 4 cm down in the left camera's frame, that shift) on an 8-camera rig, world frame floor."""
    before = surround(3)
    tracker = Tracker(LiveConfig(options=Options(free=LIVE_FREE, world=World.FLOOR)))
    first = tracker.update(observe(before, seed=5).observations)
    assert first.status == "good" and first.calibration.floor_frame.found, first.reason
    shift = np.array([0.0, 0.04, 0.0])
    cameras = [moved(c, shift, 0.0) if k in indices else c for k, c in enumerate(before.cameras)]
    after = replace(surround(4), cameras=cameras)
    pool = pooled(observe(before, seed=5).observations, observe(after, seed=6).observations)
    return tracker, first, tracker.update(pool), shift


def test_a_stereo_head_moved_is_found_and_moves_only_itself_in_the_world():
    # Each of the pair sees most of its tracks with the other, which puts them all off: each is judged without
    # its partner, the rig solved afresh from the new tracks, and the world held through the cameras that stayed.
    _, first, out, shift = moved_at_once([0, 1])

    assert out.status == "good" and out.moved == ("left", "right"), (out.reason, out.moved)
    cal, was = out.calibration, centres(first.calibration)
    # The new tracks alone may show no floor: the frame held says nothing of one out of view.
    assert cal.floor_frame.found and not any(w.startswith("no floor in view") for w in cal.warnings), cal.warnings
    now, sigma = centres(cal), cal.uncertainty.cameras
    drop = first.calibration.floor_frame.R @ shift  # the same 4 cm in the world frame
    for cam_id in now:
        expected = was[cam_id] + (drop if cam_id in ("left", "right") else 0.0)
        error = np.linalg.norm(now[cam_id] - expected)
        assert error <= 3 * np.linalg.norm(sigma[cam_id].centre_m) + 1e-3, (cam_id, error)


def test_one_stereo_camera_moved_alone_is_not_placed_again_on_a_known_distance_that_no_longer_holds():
    # Solved afresh, the rig would take its scale from the pair's distance, which the move changed: the cameras
    # that stayed say so, and the last calibration's evidence stands, with why.
    _, first, out, _ = moved_at_once([0])

    assert out.status == "good" and out.moved == (), (out.reason, out.moved)
    said = [w for w in out.calibration.warnings if w.startswith("camera left moved, not placed again: ")]
    assert said and "the stereo pair's known distance no longer holds" in said[0], out.calibration.warnings
    was, now = centres(first.calibration), centres(out.calibration)
    for cam_id in now:
        assert np.linalg.norm(now[cam_id] - was[cam_id]) < 0.005, cam_id
