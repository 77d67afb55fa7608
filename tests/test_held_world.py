"""The live world frame stays put: held from solve to solve while the floor does, carried through the cameras that
stayed when a stereo head is moved, and set anew, said so, when the floor itself moves beyond its sigmas."""

from dataclasses import replace

import numpy as np

from camnet.live.held_world import HOLD_SIGMAS, held_floor
from camnet.live.policy import LIVE_FREE, LiveConfig
from camnet.live.tracker import Tracker
from camnet.model.calibration import in_world_frame
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
