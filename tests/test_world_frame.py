"""The world frame from the scene (camnet.solve.world_frame): the floor, up and an origin on the floor."""

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from camnet.errors import InputError
from camnet.io.formats import calibration_to_doc, observations_to_doc, parse_calibration
from camnet.model.calibration import Calibration, FloorFrame, HalvesCheck
from camnet.model.camera import Camera
from camnet.model.projection import look_at, rotation_exp
from camnet.sim.families import FLOOR_FAMILIES, family, observe_family
from camnet.sim.simulate import make_rig, observe, rolled, with_floor
from camnet.solve import Options, calibrate
from camnet.solve.halves import with_check_carried
from camnet.solve.options import World
from camnet.solve.report.verdict import Level, judge
from camnet.solve.world_frame import camera_down, fit_floor, floor_frame, floor_sigmas, world_frame


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def room(seed: int = 0, *, floor: int = 400, box: int = 300, wall: int = 300,
         table: int = 0) -> tuple[list[Camera], np.ndarray, np.ndarray]:
    """Cameras, points and the true up of a room with gravity along +y (y down), floor at y = 1.2 m: a box (0.6 m
    high, its top a horizontal plane of many points), a wall and a table top 0.75 m over the floor hiding most of
    it; in the first camera's frame, as a calibration."""
    rng = np.random.default_rng(seed)
    K = np.array([[800.0, 0, 639.5], [0, 800.0, 359.5], [0, 0, 1]])
    cameras = []
    for k, angle in enumerate(np.radians([-40.0, -15.0, 15.0, 40.0])):
        centre = np.array([2.5 * np.sin(angle), rng.uniform(-0.1, 0.1), -2.5 * np.cos(angle)])
        R, t = look_at(centre, np.array([0.0, 0.8, 0.0]))  # pitched down at the box
        cameras.append(Camera(f"cam{k}", 1280, 720, K, np.zeros(5), R, t))
    on_floor = np.column_stack([rng.uniform(-1.5, 1.5, floor), np.full(floor, 1.2), rng.uniform(-1.0, 1.5, floor)])
    top = np.column_stack([rng.uniform(-0.4, 0.4, box), np.full(box, 0.6), rng.uniform(-0.3, 0.3, box)])
    side = box // 2
    sides = np.column_stack([np.full(side, -0.4), rng.uniform(0.6, 1.2, side), rng.uniform(-0.3, 0.3, side)])
    on_wall = np.column_stack([rng.uniform(-1.5, 1.5, wall), rng.uniform(-1.0, 1.2, wall), np.full(wall, 1.5)])
    on_table = np.column_stack([rng.uniform(-1.0, 1.0, table), np.full(table, 0.45), rng.uniform(-0.8, 1.2, table)])
    points = np.concatenate([on_floor, top, sides, on_wall, on_table])
    points += rng.normal(scale=0.002, size=points.shape)
    R0, t0 = cameras[0].R, cameras[0].t
    cameras = [Camera(c.id, c.width, c.height, c.K, c.dist, c.R @ R0.T, c.t - c.R @ R0.T @ t0) for c in cameras]
    return cameras, points @ R0.T + t0, R0 @ np.array([0.0, -1.0, 0.0])


def calibration(cameras: list[Camera], points: np.ndarray) -> Calibration:
    return Calibration(tuple(cameras), np.arange(len(points)), points, 0.5, cameras[0].id)


def test_the_floor_is_the_lowest_plane_not_the_box_top_with_more_points_nor_the_wall():
    cameras, points, up_truth = room(0, floor=200, box=400, wall=600)
    frame = world_frame(calibration(cameras, points), x_toward=("cam1", "cam2"))
    assert frame.floor is not None and frame.reason == ""
    assert angle_deg(frame.floor.up_left, up_truth) < 0.2
    assert 195 <= frame.floor.inliers <= 215  # the floor, and the few points of the wall and box sides at its level
    # In the world frame the floor is z = 0, the box's top 0.6 m above it and the cameras above both.
    world = frame.to_world(points)
    assert np.median(np.abs(world[:200, 2])) < 0.003
    assert np.median(world[200:600, 2]) == pytest.approx(0.6, abs=0.005)
    centres = frame.to_world(np.array([c.centre for c in cameras]))
    assert np.all(centres[:, 2] > 1.0)


def test_a_table_top_over_the_floor_showing_more_than_it_is_passed_over_and_the_floor_called_ambiguous():
    # Little of the floor shows beside the table: the table has too few points below it to be refused.
    cameras, points, up_truth = room(6, floor=35, box=0, wall=0, table=700)
    fit = fit_floor(points, camera_down(np.array([c.R for c in cameras])), np.array([c.centre for c in cameras]))
    assert not isinstance(fit, str) and fit.inliers[:35].all() and fit.inliers.sum() == 35
    assert angle_deg(fit.normal, up_truth) < 1.0
    assert fit.ambiguity.startswith("the floor is ambiguous: another plane 0.75 m above it, tilted 0 degrees from "
                                    "it, holds about 70"), fit.ambiguity
    frame = world_frame(calibration(cameras, points))
    assert frame.ambiguity == fit.ambiguity
    # Its sigmas cover the other plane too, as a rival solution's are: its height within two of them.
    assert 0.75 <= 2 * frame.floor.height_sigma_m < 0.8
    written = floor_frame(frame)  # as a calibration holds it: said in its document, and read back
    assert written.ambiguity == fit.ambiguity
    doc = calibration_to_doc(replace(calibration(cameras, points), floor_frame=written))
    assert doc["floor"]["ambiguity"] == fit.ambiguity
    assert parse_calibration(doc).floor_frame.ambiguity == fit.ambiguity
    assert np.median(frame.floor.height_m(points[-700:])) == pytest.approx(0.75, abs=0.01)
    # With the wall down to the floor behind it, the table has points below it: it is no floor, and the floor's
    # few points are found among those below it, unambiguous.
    cameras, points, up_truth = room(7, floor=45, box=0, wall=300, table=700)
    fit = fit_floor(points, camera_down(np.array([c.R for c in cameras])), np.array([c.centre for c in cameras]))
    assert not isinstance(fit, str) and fit.inliers[:45].all() and fit.ambiguity == ""
    assert angle_deg(fit.normal, up_truth) < 1.0


def test_the_frame_is_right_handed_z_up_x_toward_the_cameras_named_origin_below_what_most_cameras_see():
    cameras, points, _ = room(1)
    frame = world_frame(calibration(cameras, points), x_toward=("cam1", "cam2"))
    np.testing.assert_allclose(frame.R @ frame.R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(frame.R) == pytest.approx(1.0)
    toward = frame.to_world(np.mean([cameras[1].centre, cameras[2].centre], axis=0)[None])[0]
    assert abs(toward[1]) < 1e-9 and toward[0] > 0  # X points at them, horizontally
    # The box's middle is what all four cameras see: the origin lies on the floor below it.
    box_middle = frame.to_world(np.median(points[400:700], axis=0)[None])[0]
    assert np.hypot(*box_middle[:2]) < 0.3
    origin_left = frame.R.T @ -frame.t
    assert frame.floor.height_m(origin_left)[0] == pytest.approx(0.0, abs=1e-9)
    assert frame.to_world(np.zeros((1, 3)))[0, 2] == pytest.approx(frame.floor.left_height_m, abs=1e-9)


def test_a_scene_without_a_floor_says_so_and_takes_up_from_the_cameras():
    cameras, points, _ = room(2)
    above = points[400:]  # the box and the wall: every horizontal plane has points below it
    frame = world_frame(calibration(cameras, above))
    assert frame.floor is None
    assert "no floor in view" in frame.reason and "cameras' own down" in frame.reason
    np.testing.assert_allclose(frame.up_left, -camera_down(np.array([c.R for c in cameras])), atol=1e-12)
    assert isinstance(fit_floor(above[:10], np.array([0.0, 1.0, 0.0]), np.zeros((1, 3))), str)


def test_cameras_whose_down_directions_cancel_out_leave_up_to_the_left_cameras():
    cameras, points, _ = room(8)
    upside_down = replace(cameras[0], id="upside_down", R=np.diag([-1.0, -1.0, 1.0]))  # turned 180 degrees in place
    with pytest.raises(ValueError, match="cancel out"):
        camera_down(np.array([cameras[0].R, upside_down.R]))
    frame = world_frame(calibration([cameras[0], upside_down], points[400:]))
    assert frame.floor is None and "the left camera's own down direction" in frame.reason
    np.testing.assert_allclose(frame.up_left, [0.0, -1.0, 0.0], atol=1e-12)


def test_a_covariance_that_leaves_the_floor_undetermined_gives_way_to_its_scatter():
    cameras, points, _ = room(9)
    fit = fit_floor(points, camera_down(np.array([c.R for c in cameras])), np.array([c.centre for c in cameras]))
    scatter = floor_sigmas(fit, points)
    undetermined = floor_sigmas(fit, points, variance=lambda gradient: float("inf"))
    assert (undetermined.normal_sigma_deg, undetermined.height_sigma_m) == (scatter.normal_sigma_deg,
                                                                            scatter.height_sigma_m)
    assert np.isfinite(scatter.normal_sigma_deg) and np.isfinite(scatter.height_sigma_m)
    wider = floor_sigmas(fit, points, variance=lambda gradient: 1e-4 * float(np.sum(gradient**2)) / 1e-6)
    assert wider.normal_sigma_deg > scatter.normal_sigma_deg and wider.height_sigma_m > scatter.height_sigma_m


def test_a_camera_named_that_the_calibration_lacks_is_refused():
    cameras, points, _ = room(3)
    with pytest.raises(ValueError, match="x_toward names camera 'nope'"):
        world_frame(calibration(cameras, points), x_toward=("nope",))


def test_the_down_prior_is_the_mean_image_y_axis():
    turned = rotation_exp(np.array([0.0, 0.0, np.radians(10.0)]))  # rolled 10 degrees about the optical axis
    down = camera_down(np.array([np.eye(3), turned]))
    assert angle_deg(down, np.array([0.0, 1.0, 0.0])) == pytest.approx(5.0, abs=1e-9)


@pytest.mark.parametrize("name", FLOOR_FAMILIES)
def test_a_simulated_floor_lies_where_its_truth_says_and_leaves_the_rest_of_the_rig_as_drawn(name):
    plain, floored = family(name, seed=3), family(name, seed=3, floor_points=50)
    n = len(plain.rig.points)
    np.testing.assert_array_equal(floored.rig.points[:n], plain.rig.points)
    assert [c.id for c in floored.rig.cameras] == [c.id for c in plain.rig.cameras]
    floor = floored.floor
    on_floor = floored.rig.points[n:]
    np.testing.assert_allclose(on_floor @ floor.up_left + floor.left_height_m, 0.0, atol=1e-12)
    np.testing.assert_allclose(floored.normals[n:], np.tile(floor.up_left, (50, 1)), atol=1e-12)
    assert plain.floor is None and 0.9 < floor.left_height_m < 1.3  # cameras at chest height
    with pytest.raises(ValueError, match="family 'wide' has no floor"):
        family("wide", floor_points=10)


def test_a_calibration_in_the_floor_frame_is_written_as_the_contract_says_and_read_back_in_the_left_frame():
    cameras, points, _ = room(4)
    cal = calibration(cameras, points)
    frame = world_frame(cal, x_toward=("cam1", "cam2"))
    doc = json.loads(json.dumps(calibration_to_doc(replace(cal, floor_frame=floor_frame(frame))), allow_nan=False))
    assert list(doc)[:4] == ["format", "world_frame", "world_from_left", "floor"]
    assert doc["world_frame"] == "floor"
    assert doc["floor"] == {"normal_sigma_deg": frame.floor.normal_sigma_deg,
                            "height_sigma_m": frame.floor.height_sigma_m}
    # A reader recovers the left camera's frame from the document alone: X_left = R^T (X_world - t).
    R, t = np.array(doc["world_from_left"]["R"]), np.array(doc["world_from_left"]["t"])
    world = np.array([p["xyz"] for p in doc["points"]])
    np.testing.assert_allclose((world - t) @ R, points, atol=1e-12)
    assert np.median(np.abs(world[:400, 2])) < 0.003  # the floor's points at z = 0
    for written, cam in zip(doc["cameras"], cameras, strict=True):  # x_cam = R_c X_world + t_c, the same pixels
        Rc, tc = np.array(written["R"]), np.array(written["t"])
        np.testing.assert_allclose(world @ Rc.T + tc, points @ cam.R.T + cam.t, atol=1e-12)
    back = parse_calibration(doc)
    assert back.world_frame == "cam0" and back.floor_frame.found
    np.testing.assert_allclose(back.points, points, atol=1e-12)
    for got, cam in zip(back.cameras, cameras, strict=True):
        np.testing.assert_allclose(got.R, cam.R, atol=1e-12)
        np.testing.assert_allclose(got.t, cam.t, atol=1e-12)
    np.testing.assert_allclose(back.floor_frame.R, frame.R, atol=0)
    again = calibration_to_doc(back)  # written again: the same document, to rounding
    assert list(again) == list(doc) and again["floor"] == doc["floor"]
    assert again["world_from_left"] == doc["world_from_left"]
    np.testing.assert_allclose([p["xyz"] for p in again["points"]], world, atol=1e-12)
    np.testing.assert_allclose([c["t"] for c in again["cameras"]], [c["t"] for c in doc["cameras"]], atol=1e-12)


def test_a_floor_frame_without_a_floor_says_why_and_a_wrong_world_from_left_is_refused():
    cameras, points, _ = room(5)
    cal = calibration(cameras, points[400:])
    frame = world_frame(cal)
    doc = calibration_to_doc(replace(cal, floor_frame=floor_frame(frame)))
    assert doc["floor"] == {"found": False, "reason": frame.reason}
    back = parse_calibration(doc)
    assert not back.floor_frame.found and back.floor_frame.reason == frame.reason
    left = calibration_to_doc(cal)  # no floor frame: the left camera's, named as the contract names it
    assert left["world_frame"] == "left" and "floor" not in left and "world_from_left" not in left
    assert parse_calibration(left).world_frame == "cam0"
    assert parse_calibration({**left, "world_frame": "cam0"}).world_frame == "cam0"  # as earlier versions wrote it
    with pytest.raises(InputError, match='world_frame: "cam9" is neither "left", "floor" nor a camera'):
        parse_calibration({**left, "world_frame": "cam9"})
    moved = calibration_to_doc(replace(cal, cameras=tuple(replace(c, t=c.t + 1.0) for c in cal.cameras)))
    with pytest.raises(InputError, match='world_frame "left": no camera is at the origin'):
        parse_calibration(moved)
    doc["world_from_left"]["t"] = [0.0, 0.0, 5.0]
    with pytest.raises(InputError, match="world_from_left: no camera lands at the left camera's origin"):
        parse_calibration(doc)
    del doc["floor"]
    with pytest.raises(InputError, match="floor"):
        parse_calibration(doc)


def solved(name: str, seed: int, floor_points: int = 300, world: World = World.FLOOR):
    drawn = family(name, seed=seed, floor_points=floor_points)
    return drawn, calibrate(observe_family(drawn, seed=seed), Options(world=world)).calibration


# ring_K: the head's K given, so that its principal points do not leave its pitch and yaw open; ring: guessed.
@pytest.mark.parametrize(("name", "seed"), [("ring_K", 0), ("ring_K", 1), ("ring_K", 2), ("ring", 4),
                                            ("tape_pair", 5)])
def test_the_floor_of_a_simulated_rig_is_within_three_of_its_sigmas(name, seed):
    drawn, cal = solved(name, seed)
    frame = cal.floor_frame
    assert frame.found, frame.reason
    # The frame's up in the left camera's frame is its third row; the left camera stands at t's height.
    assert angle_deg(frame.R[2], drawn.floor.up_left) <= 3 * frame.normal_sigma_deg
    assert abs(frame.t[2] - drawn.floor.left_height_m) <= 3 * frame.height_sigma_m
    # The sigmas say something: the ring's floor is known to a fraction of a degree and a centimetre.
    assert frame.normal_sigma_deg < 0.5 and frame.height_sigma_m < 0.01
    # X points from the origin toward the stereo pair, horizontally.
    pair = frame.R @ np.mean([c.centre for c in cal.cameras[:2]], axis=0) + frame.t
    assert pair[0] > 1.0 and abs(pair[1]) < 1e-9


@pytest.mark.parametrize("seed", [0, 1])
def test_the_floor_of_the_papers_rig_pitched_down_and_rolled_is_within_three_of_its_sigmas(seed):
    rig, truth = with_floor(make_rig(seed=seed), pitch_deg=15.0, roll_deg=3.0, seed=seed)
    rig = rolled(rig, 4.0, seed=seed)
    frame = calibrate(observe(rig, seed=seed).observations, Options(world=World.FLOOR)).calibration.floor_frame
    assert frame.found, frame.reason
    assert angle_deg(frame.R[2], truth.up_left) <= 3 * frame.normal_sigma_deg
    assert abs(frame.t[2] - truth.left_height_m) <= 3 * frame.height_sigma_m
    assert frame.normal_sigma_deg < 1.0 and frame.height_sigma_m < 0.02
    assert angle_deg(frame.R[2], np.array([0.0, -1.0, 0.0])) > 10.0  # not the left camera's up by luck


def test_a_simulated_rig_without_a_floor_in_view_falls_back_to_the_cameras_down_and_warns():
    drawn, cal = solved("ring", 6, floor_points=0)
    frame = cal.floor_frame
    assert not frame.found and "no floor in view" in frame.reason
    assert frame.reason in cal.warnings
    # The verdict says so too: the frame rests on less than a floor, the cameras are as good as they are.
    finding = next(f for f in judge(cal).findings if f.what == "no floor in view")
    assert finding.level == Level.USABLE and finding.cause == frame.reason
    assert not any(f.what == "no floor in view" for f in judge(replace(cal, floor_frame=None)).findings)
    ambiguous = FloorFrame(frame.R, frame.t, 0.1, 0.01, ambiguity="the floor is ambiguous: another plane ...")
    finding = next(f for f in judge(replace(cal, floor_frame=ambiguous)).findings if "floor" in f.what)
    assert finding.what == "the floor is ambiguous" and finding.cause == ambiguous.ambiguity
    plain = replace(cal, floor_frame=replace(ambiguous, ambiguity=""))
    assert not any("floor" in f.what for f in judge(plain).findings)
    truth = family("ring", seed=6, floor_points=10).floor.up_left
    # The ring's cameras pitch down at the person from all round: their mean down is gravity's to a degree or two.
    assert angle_deg(frame.R[2], truth) < 2.0


def test_the_left_camera_frame_stays_the_default():
    _, cal = solved("ring_K", 0, world=World.LEFT_CAMERA)
    assert cal.floor_frame is None and cal.world_frame == "head0_left"
    assert calibration_to_doc(cal)["world_frame"] == "left"


def test_camnet_calibrate_writes_the_floor_frame_when_asked(tmp_path):
    drawn = family("ring_K", seed=0, floor_points=300)
    (tmp_path / "obs.json").write_text(json.dumps(observations_to_doc(observe_family(drawn, seed=0))))
    proc = subprocess.run([sys.executable, "-m", "camnet", "calibrate", str(tmp_path / "obs.json"), "-o",
                           str(tmp_path / "cal.json"), "--world", "floor"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "cal.json").read_text())
    assert doc["world_frame"] == "floor" and set(doc["floor"]) == {"normal_sigma_deg", "height_sigma_m"}
    R, t = np.array(doc["world_from_left"]["R"]), np.array(doc["world_from_left"]["t"])
    left = next(c for c in doc["cameras"] if c["id"] == "head0_left")
    # The left camera's pose in the world is world_from_left's inverse: X_left = R^T (X_world - t).
    np.testing.assert_allclose(np.array(left["R"]), R.T, atol=1e-9)
    np.testing.assert_allclose(np.array(left["t"]), -R.T @ t, atol=1e-9)
    assert abs(t[2] - drawn.floor.left_height_m) <= 3 * doc["floor"]["height_sigma_m"]
    assert "written in the floor's frame" in proc.stderr
    # A warm start from it reads it back into the left camera's frame and solves to the same poses.
    proc = subprocess.run([sys.executable, "-m", "camnet", "calibrate", str(tmp_path / "obs.json"), "-o",
                           str(tmp_path / "warm.json"), "--initial", str(tmp_path / "cal.json")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    warm = parse_calibration(json.loads((tmp_path / "warm.json").read_text()))
    cold = parse_calibration(doc)
    assert warm.floor_frame is None and warm.world_frame == cold.world_frame == "head0_left"
    for a, b in zip(warm.cameras, cold.cameras, strict=True):
        np.testing.assert_allclose(a.centre, b.centre, atol=1e-4)


def test_a_second_opinion_that_widens_every_sigma_widens_the_floors():
    _, cal = solved("ring_K", 0)
    names = ["scale", *(f"f {c.id}" for c in cal.cameras[:5])]
    check = HalvesCheck(1, dict.fromkeys(names, 0.01), dict.fromkeys(names, 4.0))
    widened = with_check_carried(cal, check)
    assert widened.report.halves.sigma_factor == pytest.approx(4.0)
    assert widened.floor_frame.normal_sigma_deg == pytest.approx(4.0 * cal.floor_frame.normal_sigma_deg)
    assert widened.floor_frame.height_sigma_m == pytest.approx(4.0 * cal.floor_frame.height_sigma_m)
    np.testing.assert_array_equal(widened.floor_frame.R, cal.floor_frame.R)
