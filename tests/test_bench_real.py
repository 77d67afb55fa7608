"""The real-scene benchmark's judgement (benchmarks/bench_real.py, camnet.datasets.sigma_check) on a simulated
rig whose truth is known: its calibration is right, and the same calibration made wrong where its sigmas are
tight is wrong in silence, or poor and wrong when its verdict says poor; refusals and tracebacks are told apart.
No shared data is read."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from camnet.datasets.published import in_frame_of
from camnet.datasets.sigma_check import Measure, Outcome, check_calibration, classify, error_line
from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.io.rig import load_rig
from camnet.model.camera import LensModel
from camnet.model.projection import rotation_exp
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate
from tests._bench_real import load_bench


def in_another_frame(cameras, R_world: np.ndarray, shift_m: np.ndarray) -> dict:
    """The cameras in a world frame turned by R_world and shifted (X' = R_world X + shift): a reference's own."""
    return {c.id: replace(c, R=c.R @ R_world.T, t=c.t + c.R @ R_world.T @ shift_m) for c in cameras}


@pytest.fixture(scope="module")
def solved():
    """(truth by id in a world frame of its own, the calibration of the paper's rig as `camnet calibrate` writes
    it and a reader reads it)."""
    rig = make_rig(n_points=300, seed=1)
    cal = calibrate(observe(rig, seed=1, noise_px=0.3).observations, Options()).calibration
    truth = in_another_frame(rig.cameras, rotation_exp(np.array([0.3, -1.2, 0.7])), np.array([5.0, -2.0, 40.0]))
    return truth, parse_calibration(calibration_to_doc(cal))


def scaled(cal, factor: float):
    """`cal` with every length times `factor` about its world origin (the left camera): its report unchanged."""
    return replace(cal, cameras=tuple(replace(c, t=factor * c.t) for c in cal.cameras), points=factor * cal.points)


def test_a_calibration_within_its_sigmas_of_the_truth_is_right(solved):
    truth, cal = solved
    check = check_calibration(cal, truth, "left")
    assert check.level in ("good", "usable")
    assert check.scale_rel is not None and 0 < check.scale_rel.sigma < 0.02  # a tenth lies 5 of them away
    assert not check.beyond(), check.beyond()
    assert classify(0, "", check) == Outcome.RIGHT


def test_the_same_calibration_ten_percent_too_large_is_wrong_in_silence(solved):
    truth, cal = solved
    check = check_calibration(scaled(cal, 1.1), truth, "left")
    assert check.scale_rel.error == pytest.approx(0.1, abs=0.005)
    assert [what for what, _ in check.beyond()] == ["scale"]
    assert check.level in ("good", "usable")
    assert classify(0, "", check) == Outcome.WRONG_IN_SILENCE
    # Said poor, the same error is honest.
    assert classify(0, "", replace(check, level="poor")) == Outcome.POOR_AND_WRONG


def test_a_focal_length_ten_percent_off_is_named_with_its_camera(solved):
    truth, cal = solved
    K = cal.cameras[2].K.copy()
    K[0, 0] *= 1.1
    wrong = replace(cal, cameras=tuple(replace(c, K=K) if i == 2 else c for i, c in enumerate(cal.cameras)))
    check = check_calibration(wrong, truth, "left")
    camera = cal.cameras[2].id
    assert [what for what, _ in check.beyond()] == [f"f {camera}"]
    assert check.silent() == [camera]
    assert classify(0, "", check) == Outcome.WRONG_IN_SILENCE


def test_the_left_camera_is_the_frame_and_no_error_of_its_pose_counts(solved):
    truth, cal = solved
    check = check_calibration(cal, truth, "left")
    left = next(c for c in check.cameras if c.id == "left")
    assert left.rotation_deg == Measure(0.0, 0.0) and left.centre_mm == Measure(0.0, 0.0)


def test_a_calibration_in_another_frame_than_the_left_cameras_is_not_compared(solved):
    truth, cal = solved
    with pytest.raises(ValueError, match="world frame"):
        check_calibration(replace(cal, world_frame="floor"), truth, "left")


def test_two_cameras_leave_the_scale_to_the_known_distance(solved):
    truth, cal = solved
    pair = replace(cal, cameras=cal.cameras[:2])
    assert check_calibration(pair, truth, "left").scale_rel is None


def test_held_values_count_exact_or_wrong_and_no_sigma_is_not_right():
    assert Measure(0.0, 0.0).within() and Measure(1e-12, 0.0).within()
    assert not Measure(0.01, 0.0).within()
    assert not Measure(0.01, float("nan")).within()
    assert Measure(0.03, 0.01).within() and not Measure(0.0301, 0.01).within()


def test_a_refusal_and_a_traceback_are_told_apart_by_exit_status_and_stderr():
    refused = "camnet calibrate: warning: something\ncamnet calibrate: error: the calibration is refused: why\n"
    assert classify(2, refused, None) == Outcome.REFUSED
    assert error_line(refused) == "the calibration is refused: why"
    crash = ("camnet calibrate:    0.0 s  solving 5000 tracks\nTraceback (most recent call last):\n"
             "  File \"x.py\", line 1, in <module>\nTypeError: expected non-empty vector for x\n")
    assert classify(1, crash, None) == Outcome.CRASH
    assert error_line(crash) == "TypeError: expected non-empty vector for x"
    assert classify(-9, "", None) == Outcome.CRASH
    assert classify(2, crash, None) == Outcome.CRASH


def test_the_rig_files_it_writes_load_and_give_the_pair_its_reference_K_and_dist(tmp_path):
    bench = load_bench()
    rig = make_rig(seed=3)
    fisheye = replace(rig.cameras[3], model=LensModel.FISHEYE, dist=np.array([0.05, -0.01, 0.002, -0.0005]))
    right = replace(rig.cameras[1], dist=np.array([-0.3, 0.1, 0.001, 0.002, -0.05]))
    reference = {c.id: c for c in [rig.cameras[0], right, rig.cameras[2], fisheye]}
    scene = bench.Scene("sim", reference, "left", "right", {"all": {}})
    for known in ("none", "K"):
        path = tmp_path / f"{known}.yaml"
        path.write_text(yaml.safe_dump(bench.rig_document(scene, list(reference), known)))
        loaded = load_rig(path)
        assert loaded.stereo.baseline_m == pytest.approx(rig.baseline_m, abs=1e-12)
        entries = {e.id: e for e in loaded.cameras}
        assert entries["mono_b"].model == LensModel.FISHEYE
        given = {c for c, e in entries.items() if e.intrinsics is not None}
        assert given == (set() if known == "none" else {"left", "right"})
    K = entries["right"].intrinsics
    assert np.array_equal(K.K, right.K) and np.array_equal(K.dist, right.dist)
    assert entries["left"].intrinsics.dist is None  # its reference has no distortion: K alone is given


def test_the_tracebacks_a_node_survived_are_found_in_its_log(tmp_path):
    bench = load_bench()
    (tmp_path / "calibrator.log").write_text(
        "INFO camnet.status: calibrator: 0 solves\nTraceback (most recent call last):\n  File \"x.py\", line 1\n"
        "    raise TypeError(\"no x\")\nTypeError: no x\nINFO camnet.status: calibrator: 1 solves\n")
    (tmp_path / "matcher.log").write_text("INFO camnet.status: matcher: 3 frame sets\n")
    assert bench.logged_exceptions(tmp_path) == ["calibrator: TypeError: no x"]


def test_a_reference_in_its_left_cameras_frame_keeps_its_lens_model():
    rig = make_rig(seed=2)
    fisheye = replace(rig.cameras[2], model=LensModel.FISHEYE, dist=np.array([0.05, -0.01, 0.002, -0.0005]))
    moved = in_frame_of({c.id: c for c in [rig.cameras[0], rig.cameras[1], fisheye]}, "right")
    assert moved["mono_a"].model == LensModel.FISHEYE and np.array_equal(moved["mono_a"].dist, fisheye.dist)
    assert np.allclose(moved["right"].R, np.eye(3)) and np.allclose(moved["right"].t, 0.0)


def test_a_floor_is_checked_against_the_plane_of_the_references_camera_centres():
    from camnet.datasets.sigma_check import reference_up
    from camnet.sim.simulate import with_floor
    from camnet.solve.options import World

    rig, truth_floor = with_floor(make_rig(n_points=300, seed=2), seed=2)  # level cameras, all at one height
    cal = calibrate(observe(rig, seed=2, noise_px=0.3).observations, Options(world=World.FLOOR)).calibration
    truth = in_another_frame(rig.cameras, rotation_exp(np.array([0.3, -1.2, 0.7])), np.array([5.0, -2.0, 40.0]))
    assert cal.floor_frame.found
    np.testing.assert_allclose(reference_up(list(in_frame_of(truth, "left").values())), truth_floor.up_left,
                               atol=1e-9)
    check = check_calibration(parse_calibration(calibration_to_doc(cal)), truth, "left")
    assert check.floor.found and check.floor.tilt_deg.within(), check.floor
    # The same floor turned 5 degrees: wrong, and among what lies beyond.
    frame = cal.floor_frame
    turned = replace(frame, R=frame.R @ rotation_exp(np.radians([5.0, 0.0, 0.0])))
    check = check_calibration(replace(cal, floor_frame=turned), truth, "left")
    assert "floor" in [what for what, _ in check.beyond()], check.floor
    # Cameras along a line give no up: the floor is not judged.
    line = {c.id: replace(c, t=-c.R @ (np.array([1.0, 0.0, 0.0]) * k)) for k, c in enumerate(truth.values())}
    assert reference_up(list(line.values())) is None
