"""The verdict on seeded simulated rigs: each level and each action happens where its cause is made to happen."""

from dataclasses import replace

import numpy as np
import pytest

from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.live.policy import LIVE_FREE
from camnet.model.calibration import Calibration
from camnet.sim.families import family, observe_family
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate
from camnet.solve.report.verdict import Action, Level, Thresholds, format_verdict, judge

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
    # 55% of the tracks have one false observation of four: about 14% of the observations.
    cal = solve(make_rig(n_points=300, seed=1), noise_px=0.3, outlier_fraction=0.55)
    share = cal.report.inliers / cal.report.observations
    assert 0.8 <= share < 0.9
    assert not [f for f in judge(cal).findings if "inliers" in f.what]
    # Under 80% inliers: usable, and more texture is what helps.
    low = replace(cal, report=replace(cal.report, inliers=int(0.7 * cal.report.observations)))
    findings = [f for f in judge(low).findings if "inliers" in f.what]
    assert findings and findings[0].level == Level.USABLE and findings[0].action == Action.ADD_TEXTURE
    # Fewer than half inliers: poor.
    worse = replace(cal, report=replace(cal.report, inliers=cal.report.observations // 3))
    assert [f.level for f in judge(worse).findings if "inliers" in f.what] == [Level.POOR]


def test_a_factory_head_has_no_verdict():
    head = make_rig().cameras[0]
    cal = Calibration((head,), np.empty(0, np.int64), np.empty((0, 3)), float("nan"), head.id)
    assert judge(cal) is None and "verdict" not in calibration_to_doc(cal)


def test_a_rotation_is_graded_by_the_image_shift_it_makes(dense):
    # 0.2 degrees moves a 400 px lens's image by 1.4 px (good) and a 1500 px lens's by 5.2 px (poor);
    # graded in degrees both would be usable.
    def rotation_findings(cal, f_px):
        cam = next(c for c in cal.cameras if c.id not in (cal.world_frame,))
        K = np.diag([f_px, f_px, 1.0]) + np.array([[0, 0, cam.K[0, 2]], [0, 0, cam.K[1, 2]], [0, 0, 0]])
        sigmas = replace(cal.uncertainty.cameras[cam.id], rotation_deg=(0.0, 0.2, 0.0), cx_px=0.0, cy_px=0.0)
        cameras = tuple(replace(c, K=K) if c.id == cam.id else c for c in cal.cameras)
        uncertainty = replace(cal.uncertainty, cameras={**cal.uncertainty.cameras, cam.id: sigmas})
        verdict = judge(replace(cal, cameras=cameras, report=replace(cal.report, uncertainty=uncertainty)))
        return [f for c in verdict.cameras if c.camera == cam.id for f in c.findings if "rotation" in f.what]

    assert rotation_findings(dense, 400.0) == []
    [poor] = rotation_findings(dense, 1500.0)
    assert poor.level == Level.POOR and "5.2 px" in poor.what and poor.action == Action.ADD_TEXTURE, poor


def test_a_far_ring_cameras_rotation_that_the_guessed_principal_points_explain_is_usable_and_asks_for_k():
    # tape_pair: 8 cameras on a ring, the pair 45 degrees apart. The far side's rotation sigma is
    # 0.65-0.7 degrees, 0.1 with the principal points given; its true error 0.1-0.2. Graded poor, it would ask
    # for texture, which the scene has plenty of: the principal points are what pins it.
    drawn = family("tape_pair", seed=0)
    cal = calibrate(observe_family(drawn, noise_px=0.5, seed=0)).calibration
    verdict = judge(cal)
    assert verdict.level == Level.USABLE, format_verdict(verdict)
    rotation = {c.camera: f for c in verdict.cameras for f in c.findings if "rotation" in f.what}
    assert {"ring3", "ring4", "ring5"} <= set(rotation), format_verdict(verdict)
    for cam, finding in rotation.items():
        assert finding.level == Level.USABLE and finding.action == Action.GIVE_K, finding
        assert "principal points" in finding.what and cam in finding.todo, finding
    # Given the principal points (K, not fixed), the same cameras' rotations are good.
    given = observe_family(drawn, noise_px=0.5, seed=0)
    truth = {c.id: c.K for c in drawn.rig.cameras}
    given = replace(given, cameras=tuple(replace(c, K=truth[c.id]) for c in given.cameras))
    told = judge(calibrate(given).calibration)
    assert not [f for c in told.cameras for f in c.findings if "rotation" in f.what], format_verdict(told)


def test_a_principal_point_moved_where_no_lens_has_it_rates_that_camera_poor_and_reads_back(dense):
    cam_id = dense.cameras[2].id
    far = replace(dense, report=replace(dense.report, far_principal_points={cam_id: 0.25}))

    verdict = judge(far)

    levels = {c.camera: c.level for c in verdict.cameras}
    assert levels.pop(cam_id) == Level.POOR and set(levels.values()) == {Level.GOOD}, format_verdict(verdict)
    assert verdict.level == Level.POOR
    finding = next(f for c in verdict.cameras if c.camera == cam_id for f in c.findings)
    assert finding.action == Action.GIVE_K and "25% of the image" in finding.what, finding
    doc = calibration_to_doc(far)
    assert doc["diagnostics"]["far_principal_points"] == {cam_id: 0.25}
    assert parse_calibration(doc).report.far_principal_points == {cam_id: 0.25}
    assert "far_principal_points" not in calibration_to_doc(dense)["diagnostics"]


def test_no_camera_is_better_than_what_vouches_for_every_cameras_sigmas(dense):
    """A camera's own measures are its sigmas: with no second opinion nothing vouches for them, and with a
    competing solution they are widened to cover it; neither lets a camera stay good."""
    from camnet.model.calibration import HalvesCheck, Rival, RivalDifference

    none = HalvesCheck(splits=0, reason="no split keeps every camera's view in both halves")
    verdict = judge(replace(dense, report=replace(dense.report, halves=none)))
    assert verdict.level == Level.POOR and {c.level for c in verdict.cameras} == {Level.POOR}, format_verdict(verdict)
    assert not any(c.findings for c in verdict.cameras)  # said once, of the rig
    scale = RivalDifference("scale", None, kept=1.0, rival=1.05, kept_sigma=0.01)
    rival = Rival("strongest_pair", cost_px2=100.0, kept_cost_px2=99.0, cost_noise_px2=5.0, differences=(scale,))
    verdict = judge(replace(dense, report=replace(dense.report, rivals=(rival,))))
    assert verdict.level == Level.USABLE and {c.level for c in verdict.cameras} == {Level.USABLE}
