"""Rerun shows a calibration with a floor frame in that frame, Z up, over a floor grid; one without, as before."""

from dataclasses import replace

import numpy as np
import pytest

from camnet import viz, viz_sinks
from camnet.model.calibration import in_world_frame
from camnet.solve.world_frame import floor_frame, world_frame
from tests.test_viz import T0_NS, read_rrd
from tests.test_world_frame import calibration, room


def view_xyz(view) -> list:
    """The axes of view coordinates as a saved recording holds them."""
    return [batch.as_arrow_array().to_pylist() for batch in view.as_component_batches()][0]


@pytest.fixture(scope="module")
def on_floor():
    cameras, points, _ = room(4)
    cal = calibration(cameras, points)
    return replace(cal, floor_frame=floor_frame(world_frame(cal, x_toward=("cam1", "cam2"))))


def save(path, *cals):
    rec = viz.open_recording(rig="room", sinks=[viz_sinks.parse_sink(f"save={path}")])
    for k, cal in enumerate(cals):
        viz.log_calibration(rec, cal, time_ns=T0_NS + k * 10**9)
    viz.close_recording(rec)
    return read_rrd(path)


def test_a_floor_frame_is_shown_z_up_in_that_frame_over_a_floor_grid(on_floor, tmp_path):
    import rerun as rr

    data = save(tmp_path / "floor.rrd", on_floor)
    world = in_world_frame(on_floor)
    for cam in world.cameras:
        entity = data[f"/world/cameras/{cam.id}"]
        np.testing.assert_allclose(entity["Transform3D:translation"][-1][0], cam.centre, atol=1e-6)
        np.testing.assert_allclose(np.reshape(entity["Transform3D:mat3x3"][-1][0], (3, 3)).T, cam.R.T, atol=1e-6)
        assert cam.centre[2] > 1.0  # upright over the floor, not in the left camera's frame
    np.testing.assert_allclose(data["/world/points"]["Points3D:positions"][-1], world.points, atol=1e-6)
    assert data["/world"]["ViewCoordinates:xyz"][-1] == view_xyz(rr.ViewCoordinates.RIGHT_HAND_Z_UP)
    strips = np.array(data["/world/floor"]["LineStrips3D:strips"][-1])
    assert data["/world/floor"]["solve"] == [0] and len(strips) >= 4
    assert np.all(strips[..., 2] == 0.0)
    lo, hi = strips[..., :2].reshape(-1, 2).min(axis=0), strips[..., :2].reshape(-1, 2).max(axis=0)
    centres = np.array([cam.centre for cam in world.cameras])[:, :2]
    assert np.all(centres >= lo) and np.all(centres <= hi)
    assert np.all(hi - lo < 3 * np.ptp(np.vstack([centres, world.points[:, :2]]), axis=0) + 2.0)


def test_without_a_floor_frame_the_left_cameras_frame_rdf_and_no_floor(on_floor, tmp_path):
    import rerun as rr

    left = replace(on_floor, floor_frame=None)
    data = save(tmp_path / "left.rrd", left)
    for cam in left.cameras:
        np.testing.assert_allclose(data[f"/world/cameras/{cam.id}"]["Transform3D:translation"][-1][0], cam.centre,
                                   atol=1e-6)
    np.testing.assert_allclose(data["/world/points"]["Points3D:positions"][-1], left.points, atol=1e-6)
    assert data["/world"]["ViewCoordinates:xyz"][-1] == view_xyz(rr.ViewCoordinates.RDF)
    assert "/world/floor" not in data


def test_a_solve_without_the_floor_after_one_with_it_clears_the_floor_and_turns_the_view_back(on_floor, tmp_path):
    import rerun as rr

    data = save(tmp_path / "both.rrd", on_floor, replace(on_floor, floor_frame=None))
    assert data["/world"]["ViewCoordinates:xyz"][-1] == view_xyz(rr.ViewCoordinates.RDF)
    assert data["/world/floor"]["solve"] == [0, 1]  # the grid at the first solve, its clear at the second
    assert len(data["/world/floor"]["LineStrips3D:strips"]) == 1
    np.testing.assert_allclose(data["/world/cameras/cam3"]["Transform3D:translation"][-1][0],
                               on_floor.cameras[3].centre, atol=1e-6)
