"""The lens check: a camera whose lens nobody described, held straight, freed to see what its focal length does.

A live rig holds distortion nobody gave at none; a lens that bends the
image then biases its camera's focal length beyond its sigmas, with an RMS
that does not show it. Simulated on a ring whose one camera has a bent lens:
the check names that camera and rates it poor; with straight lenses it
names none.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.live.policy import LIVE_FREE, LiveConfig
from camnet.live.tracker import Tracker
from camnet.sim.families import family, observe_family
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate, solved_from
from camnet.solve.lens_check import with_lens_check
from camnet.solve.report.lens_shifts import SHIFT_SIGMAS
from camnet.solve.report.verdict import Level, judge

BENT = "ring7"


def ring_observations(k1: float, seed: int = 1):
    """ring_K's observations with camera BENT's lens given k1 (its dist is not given to the solve)."""
    drawn = family("ring_K", seed=seed)
    cameras = tuple(replace(c, dist=np.array([k1, 0.0, 0.0, 0.0, 0.0])) if c.id == BENT else c
                    for c in drawn.rig.cameras)
    return drawn.rig.cameras, observe_family(replace(drawn, rig=replace(drawn.rig, cameras=cameras)), seed=seed)


@pytest.fixture(scope="module")
def bent():
    truth, obs = ring_observations(0.2)
    cal = calibrate(obs, Options(free=LIVE_FREE, halves=False)).calibration
    return truth, obs, cal


def test_a_bent_lens_held_straight_is_named_and_its_camera_rated_poor(bent):
    truth, obs, cal = bent
    f_true = next(c for c in truth if c.id == BENT).K[0, 0]
    f_held = next(c for c in cal.cameras if c.id == BENT).K[0, 0]
    sigma = cal.report.uncertainty.cameras[BENT].f_px
    assert abs(f_held - f_true) > 3 * sigma  # held straight, its focal length is wrong beyond its sigmas

    checked = with_lens_check(obs, cal, Options(free=LIVE_FREE), solved_from)

    shift = checked.report.lens_shifts[BENT]
    assert shift.in_sigmas > SHIFT_SIGMAS and shift.k1 > 0.1, shift
    assert [c for c, s in checked.report.lens_shifts.items() if s.in_sigmas > SHIFT_SIGMAS] == [BENT]
    assert any(w.startswith(f"camera {BENT}'s focal length moves by") for w in checked.report.warnings)
    camera = next(c for c in judge(checked).cameras if c.camera == BENT)
    assert camera.level == Level.POOR
    assert any("with its lens distortion free" in f.what for f in camera.findings), camera.findings
    back = parse_calibration(calibration_to_doc(checked))
    assert back.report.lens_shifts == checked.report.lens_shifts


def test_straight_lenses_are_not_named():
    _, obs = ring_observations(0.0)
    cal = calibrate(obs, Options(free=LIVE_FREE, halves=False)).calibration

    checked = with_lens_check(obs, cal, Options(free=LIVE_FREE), solved_from)

    assert checked.report.lens_shifts, "no camera was checked"
    assert max(s.in_sigmas for s in checked.report.lens_shifts.values()) < SHIFT_SIGMAS
    assert not any("lens distortion free" in f.what for _, f in judge(checked).all_findings())


def test_the_automatic_rule_is_not_second_guessed(bent):
    _, obs, cal = bent
    assert with_lens_check(obs, cal, Options(), solved_from).report.lens_shifts is None


def test_the_live_tracker_checks_the_lenses_with_its_second_opinion(bent):
    _, obs, _ = bent

    outcome = Tracker(LiveConfig()).update(obs)

    assert outcome.status == "good"
    assert outcome.calibration.report.lens_shifts[BENT].in_sigmas > SHIFT_SIGMAS


def test_a_live_rig_under_the_automatic_rule_frees_the_lenses_its_grown_pool_determines():
    # The first few tracks fix only the stereo pair's k1; a warm solve keeps the free set it starts from, so the
    # second opinion tries the rule again once the pool has turned over.
    obs = observe(make_rig(n_cameras=5, n_points=700, seed=2, k1=-0.15), noise_px=0.3, seed=2).observations
    tracker = Tracker(LiveConfig(options=Options(free="auto"), halves_interval_s=0.0))

    first = tracker.update(only_tracks(obs, 60)).calibration
    grown = tracker.update(only_tracks(obs, 700))

    assert "k1" not in first.report.free.intrinsics["mono_a"]
    assert grown.warm and grown.status == "good"
    assert all("k1" in names for names in grown.calibration.report.free.intrinsics.values())


def only_tracks(obs, n: int):
    """`obs` with only its first `n` tracks."""
    keep = obs.track_index < n
    return replace(obs, track_ids=obs.track_ids[:n], cam_index=obs.cam_index[keep], track_index=obs.track_index[keep],
                   uv=obs.uv[keep])


def test_each_lens_is_also_freed_alone_with_the_others_held_straight(bent):
    _, obs, cal = bent
    solves = []

    def solve(obs, options, initial):  # the real solve; kept to see what each pass freed
        solves.append(solved_from(obs, options, initial))
        return solves[-1]

    checked = with_lens_check(obs, cal, Options(free=LIVE_FREE), solve)
    undescribed = sorted(c.id for c in obs.cameras if c.dist is None)
    assert len(solves) == 1 + len(undescribed)  # all at once, then each alone
    for freed, alone in zip(solves[1:], undescribed, strict=True):
        k1 = {c.id: c.dist[0] for c in freed.cameras if c.id in undescribed}
        assert all(value == 0.0 for c, value in k1.items() if c != alone), (alone, k1)
        assert k1[alone] != 0.0
    # The larger move of the two passes is the one reported.
    for camera_id, shift in checked.report.lens_shifts.items():
        moves = [abs(next(c for c in s.cameras if c.id == camera_id).K[0, 0] / next(
            c for c in cal.cameras if c.id == camera_id).K[0, 0] - 1) for s in (solves[0], solves[1 + undescribed.index(
                camera_id)])]
        assert abs(shift.f_rel) in [pytest.approx(m) for m in moves]
