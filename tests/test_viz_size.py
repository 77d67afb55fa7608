"""A saved .rrd grows by what each solve's data take, not by Rerun's framing of its many small log calls."""

import time
from dataclasses import replace

import numpy as np

from camnet import viz, viz_sinks
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations
from camnet.sim.simulate import make_rig, observe

T0_NS = 1_700_000_000_000_000_000


def tracks_between(obs: Observations, first: int, stop: int) -> Observations:
    """`obs` with only the tracks whose ids lie in [first, stop): a pool's window."""
    keep = (obs.track_ids >= first) & (obs.track_ids < stop)
    rows = keep[obs.track_index]
    new_row = np.cumsum(keep) - 1
    return replace(obs, track_ids=obs.track_ids[keep], cam_index=obs.cam_index[rows],
                   track_index=new_row[obs.track_index[rows]], uv=obs.uv[rows])


def saved_size(path, solves: list[tuple[Calibration, Observations]], truth) -> int:
    rec = viz.open_recording(rig="sim", sinks=[viz_sinks.parse_sink(f"save={path}")])
    try:
        for k, (cal, obs) in enumerate(solves):
            viz.log_calibration(rec, cal, time_ns=T0_NS + k * 10**9, observations=obs, truth=truth)
            # A live calibrator solves seconds apart: longer than Rerun's default batching (200 ms).
            time.sleep(0.3)
    finally:
        viz.close_recording(rec)
    return path.stat().st_size


def test_a_saved_recording_grows_by_what_each_solve_logs(tmp_path):
    # Written as it is logged, each of a solve's 30-odd log calls (cameras, observations, one per series) is
    # a chunk of its own with its own schema, several times the data's size (docs/benchmarks.md, "Bus,
    # recording, Rerun").
    rig = make_rig(n_cameras=4, n_points=700, seed=5)
    every = observe(rig, noise_px=0.3, seed=5).observations
    rng = np.random.default_rng(0)
    solves = []
    for k in range(10):  # a pool that moves on by 40 tracks a solve, its points solved again each time
        obs = tracks_between(every, 40 * k, 40 * k + 300)
        points = rig.points[obs.track_ids] + rng.normal(0.0, 1e-3, (len(obs.track_ids), 3))
        solves.append((Calibration(tuple(rig.cameras), obs.track_ids, points, 0.3, "left"), obs))
    one = saved_size(tmp_path / "one.rrd", solves[:1], rig.cameras)
    all_ = saved_size(tmp_path / "all.rrd", solves, rig.cameras)
    per_solve = (all_ - one) / (len(solves) - 1)
    # What a solve's data take: each point (3 float32 and an RGBA colour), each observation (2 float32 and a
    # colour), a few dozen scalars, the cameras' poses and pinholes. Batched, with LZ4 within a chunk, a solve
    # takes less than that.
    data = np.mean([16 * len(cal.points) + 12 * len(obs.uv) for cal, obs in solves[1:]]) + 2000
    assert per_solve < data, f"{per_solve / 1e3:.1f} kB a solve whose data take {data / 1e3:.1f} kB"
