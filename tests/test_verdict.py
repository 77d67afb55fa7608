"""The verdict on seeded simulated rigs: each level and each action happens where its cause is made to happen."""

from dataclasses import replace

import numpy as np
import pytest

from camnet.geometry.calibrate import Options, calibrate
from camnet.geometry.live import LIVE_FREE
from camnet.geometry.model import Calibration
from camnet.geometry.verdict import Action, Level, Thresholds, format_verdict, judge
from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.sim.simulate import make_rig, observe

LIVE = Options(free=LIVE_FREE)


def solve(rig, options=LIVE, **observe_kw):
    return calibrate(observe(rig, seed=1, **observe_kw).observations, options).calibration


def actions(verdict, level=Level.POOR) -> set[Action]:
    return {f.action for _, f in verdict.all_findings() if f.level == level}


@pytest.fixture(scope="module")
def dense():
    """The live default free set on 300 points at 0.3 px: nothing to fault but the guessed principal points."""
    return solve(make_rig(n_points=300, seed=1), noise_px=0.3)


def test_a_dense_rig_is_good_and_the_guessed_principal_points_are_a_note(dense):
    verdict = judge(dense)
    assert verdict.level == Level.GOOD, format_verdict(verdict)
    assert all(c.level == Level.GOOD and not c.findings for c in verdict.cameras)
    assert not dense.warnings, dense.warnings
    assert any("principal points" in n for n in dense.report.notes), dense.report.notes


def test_the_verdict_is_in_the_document_and_the_notes_read_back(dense):
    doc = calibration_to_doc(dense)
    assert doc["verdict"]["level"] == "good" and set(doc["verdict"]["cameras"]) == {c.id for c in dense.cameras}
    assert doc["diagnostics"]["notes"] == list(dense.report.notes)
    assert parse_calibration(doc).report.notes == dense.report.notes
    assert calibration_to_doc(parse_calibration(doc)) == doc


def test_stricter_thresholds_can_fail_the_same_rig(dense):
    strict = Thresholds(centre_rel=(1e-6, 1e-5), scale_rel=(1e-5, 1e-4))
    verdict = judge(dense, strict)
    assert verdict.level == Level.POOR
    assert Action.MOVE_CAMERA in actions(verdict) and Action.GIVE_K in actions(verdict)


def test_few_points_are_usable_and_say_to_move_a_camera_or_let_it_run():
    verdict = judge(solve(make_rig(n_points=70, seed=2), noise_px=0.3))
    assert verdict.level != Level.GOOD, format_verdict(verdict)
    usable = [f for c in verdict.cameras for f in c.findings if "inlier observations" in f.what]
    assert usable and all(f.level == Level.USABLE and f.action == Action.MOVE_CAMERA for f in usable)


def test_a_camera_that_sees_little_is_poor_and_should_be_moved():
    verdict = judge(solve(make_rig(n_points=100, seed=1), noise_px=0.5, visibility=0.1))
    assert verdict.level == Level.POOR
    few = [(c.camera, f) for c in verdict.cameras for f in c.findings if "inlier observations" in f.what]
    assert any(f.level == Level.POOR and f.action == Action.MOVE_CAMERA for _, f in few), format_verdict(verdict)
    assert {cam for cam, _ in few} <= {"mono_a", "mono_b"}  # the pair sees every track


def test_a_far_scene_with_the_pairs_pose_estimated_is_poor_and_asks_for_k():
    verdict = judge(solve(make_rig(n_points=300, seed=1, depth_range_m=(8.0, 12.0)), noise_px=0.5))
    assert verdict.level == Level.POOR
    parallax = [f for f in verdict.findings if "parallax" in f.what]
    assert parallax and parallax[0].level == Level.POOR and parallax[0].action == Action.GIVE_K


def test_noisy_features_are_poor_by_rms_and_scale():
    verdict = judge(solve(make_rig(n_points=300, seed=1), noise_px=4.0))
    rig = {f.what.split()[0]: f for f in verdict.findings}
    assert rig["RMS"].level == Level.POOR and rig["RMS"].action == Action.GIVE_K
    assert rig["scale"].level == Level.POOR and rig["scale"].action == Action.ADD_FRAME_SET


def test_false_matches_lower_the_inlier_share_and_ask_for_texture():
    cal = solve(make_rig(n_points=300, seed=1), noise_px=0.3, outlier_fraction=0.55)
    share = cal.report.inliers / cal.report.observations
    assert 0.5 <= share < 0.8
    findings = [f for f in judge(cal).findings if "inliers" in f.what]
    assert findings and findings[0].level == Level.USABLE and findings[0].action == Action.ADD_TEXTURE
    # Fewer than half inliers: poor.
    worse = replace(cal, report=replace(cal.report, inliers=cal.report.observations // 3))
    assert [f.level for f in judge(worse).findings if "inliers" in f.what] == [Level.POOR]


def test_a_factory_head_has_no_verdict():
    head = make_rig().cameras[0]
    cal = Calibration((head,), np.empty(0, np.int64), np.empty((0, 3)), float("nan"), head.id)
    assert judge(cal) is None and "verdict" not in calibration_to_doc(cal)
