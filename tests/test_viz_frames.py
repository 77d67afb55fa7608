"""The calibrator's Rerun view logs a camera's frame when it is worth it, not at every solve.

Frames cross a real Zenoh pair on loopback into the view; its recording is saved to an .rrd and read back
with Rerun's own reader.
"""

import numpy as np
from camnet.services.calibrator import RerunView

from camnet import viz, viz_sinks
from camnet.bus import keys
from camnet.bus.frame import Frame, encode_frame
from camnet.io.messages import ObservationsMessage
from camnet.live.judged_solve import Status
from camnet.live.tracker import Outcome
from camnet.model.calibration import Calibration
from camnet.sim.simulate import make_rig, observe
from tests.conftest import matched_publisher, wait_for
from tests.test_viz import read_rrd

T0_NS = 1_700_000_000_000_000_000
SOLVE_GAP_S = 2  # capture time between solves: a pool solved every couple of seconds
RIG = "t"


def run_view(zenoh_pair, path, *, solves: int, moved_at: dict[int, str], late: str, **view_args):
    """`solves` solves shown by a calibrator's view saved to `path`, each after a new frame of every camera
    (of camera `late` only from the middle solve on); the camera `moved_at[k]` is taken for moved at solve k."""
    a, b = zenoh_pair
    rig = make_rig(n_cameras=4, n_points=150, seed=3)
    obs = observe(rig, noise_px=0.3, seed=3).observations
    cal = Calibration(tuple(rig.cameras), obs.track_ids, rig.points[obs.track_ids], 0.3, "left")
    rec = viz.open_recording(rig=RIG, sinks=[viz_sinks.parse_sink(f"save={path}")])
    view = RerunView(rec, **view_args)
    sub = b.declare_subscriber(keys.all_frames(RIG), view.on_frame)
    publishers = {cam.id: matched_publisher(a, keys.frame(RIG, cam.id)) for cam in rig.cameras}
    try:
        for k in range(solves):
            time_ns = T0_NS + k * SOLVE_GAP_S * 10**9
            sending = [c for c in publishers if c != late or 2 * k >= solves]
            for cam_id in sending:
                image = np.full((48, 64), 10 * k, np.uint8)
                publishers[cam_id].put(encode_frame(Frame(cam_id, k, time_ns, "mono8", image)))
            arrived = {c: k for c in sending}
            assert wait_for(lambda arrived=arrived: all(c in view._frames and view._frames[c].seq == seq
                                                        for c, seq in arrived.items()), timeout_s=60.0), k
            moved = (moved_at[k],) if k in moved_at else ()
            view.solved(Outcome(Status.GOOD, "", cal, moved), ObservationsMessage(obs, latest_capture_ns=time_ns),
                        solve=k)
    finally:
        sub.undeclare()
        for publisher in publishers.values():
            publisher.undeclare()
        viz.close_recording(rec)
    return [cam.id for cam in rig.cameras], read_rrd(path)


def test_frames_are_logged_every_period_not_every_solve(zenoh_pair, tmp_path):
    # Not every camera's frame at every solve (8 images each over 8 solves).
    solves = 8  # 2 s apart: 14 s of capture time, against the default of a frame per 10 s
    cams, data = run_view(zenoh_pair, tmp_path / "run.rrd", solves=solves, moved_at={3: "mono_a"}, late="mono_b")
    # A camera's first frame, then the first 10 s after it; mono_a also when taken for moved (and its 10 s
    # then start over); mono_b's first frame comes at solve 4.
    expected = {"left": [0, 5], "right": [0, 5], "mono_a": [0, 3], "mono_b": [4]}
    for cam in cams:
        images = data[f"/world/cameras/{cam}/image"]
        overlays = data[f"/world/cameras/{cam}/image/observations"]
        logged_at = [(t - T0_NS) // (SOLVE_GAP_S * 10**9) for t in images["capture_time"]]
        assert logged_at == expected[cam], cam
        assert len(images["EncodedImage:blob"]) == len(logged_at)
        # Every solve's observations, drawn over a frame of that camera logged at or before it (once it sent one).
        assert len(overlays["Points2D:positions"]) == solves
        assert cam == "mono_b" or min(overlays["capture_time"]) >= min(images["capture_time"])


def test_a_period_of_zero_logs_every_solve(zenoh_pair, tmp_path):
    solves = 3
    cams, data = run_view(zenoh_pair, tmp_path / "run.rrd", solves=solves, moved_at={}, late="", frame_period_s=0)
    for cam in cams:
        assert len(data[f"/world/cameras/{cam}/image"]["EncodedImage:blob"]) == solves
