"""The report's camera layout: with a floor frame, a floor plan and a side view in that frame, to scale; without
one, the left camera's frame from above."""

from dataclasses import replace

import numpy as np
import pytest

from camnet.io.report import render_report
from camnet.io.report_plots import layout_figure
from camnet.model.calibration import in_world_frame
from camnet.solve.world_frame import floor_frame, world_frame
from tests.test_world_frame import calibration, room

FLOOR = "floor frame: Z up, origin on the floor"


@pytest.fixture(scope="module")
def on_floor():
    cameras, points, _ = room(4)
    cal = calibration(cameras, points)
    return replace(cal, floor_frame=floor_frame(world_frame(cal, x_toward=("cam1", "cam2"))))


def labels_at(ax) -> np.ndarray:
    return np.array([text.xy for text in ax.texts])


def assert_labels_apart(fig, ax) -> None:
    fig.draw_without_rendering()
    boxes = [t.get_window_extent() for t in ax.texts]
    assert not any(boxes[a].overlaps(boxes[b]) for a in range(len(boxes)) for b in range(a))


def test_with_a_floor_frame_the_layout_is_a_floor_plan_and_a_side_view_in_it(on_floor):
    world = in_world_frame(on_floor)
    centres = np.array([cam.centre for cam in world.cameras])
    fig = layout_figure(on_floor)
    top, side = fig.axes
    assert top.get_title().startswith("floor plan (X-Y") and FLOOR in top.get_title()
    assert side.get_title().startswith("side view (X-Z") and FLOOR in side.get_title()
    assert (top.get_xlabel(), top.get_ylabel()) == ("X (m)", "Y (m)")
    assert (side.get_xlabel(), side.get_ylabel()) == ("X (m)", "Z (m)")
    for ax in (top, side):
        assert ax.get_aspect() == 1.0  # to scale
        assert_labels_apart(fig, ax)
    np.testing.assert_allclose(labels_at(top), centres[:, [0, 1]], atol=1e-12)
    np.testing.assert_allclose(labels_at(side), centres[:, [0, 2]], atol=1e-12)
    assert top.get_xlim() == side.get_xlim()
    # The floor, at z = 0, and the cameras over it, are in the side view.
    assert side.get_ylim()[0] < 0.0 < 1.0 < centres[:, 2].max() < side.get_ylim()[1]
    floor = [line for line in side.get_lines() if line.get_label() == "floor (z = 0)"]
    assert len(floor) == 1 and np.all(np.asarray(floor[0].get_ydata()) == 0.0)


def test_without_a_floor_frame_the_layout_is_the_left_cameras_from_above(on_floor):
    left = replace(on_floor, floor_frame=None)
    fig = layout_figure(left)
    (ax,) = fig.axes
    assert "left camera's frame (camera cam0)" in ax.get_title() and "floor" not in ax.get_title()
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("X (m)", "Z (m)")
    np.testing.assert_allclose(labels_at(ax), [cam.centre[[0, 2]] for cam in left.cameras], atol=1e-12)


def test_the_page_names_the_frame_of_its_layout(on_floor):
    page = render_report(on_floor)
    layout = page[page.index('<section id="layout">'):]
    assert f"floor plan (X-Y, from above); {FLOOR}" in layout and f"side view (X-Z); {FLOOR}" in layout
    assert layout.count("<svg") == 1
    left = render_report(replace(on_floor, floor_frame=None))
    assert FLOOR not in left and "left camera's frame (camera cam0): X right, Z forward, from above" in left
