"""The report's plots end near the body of the cloud, whatever far points it has, and their labels do not overlap.

Held against a cloud with two far points, the ring rig (camnet.sim.families), and KITTI (the shared data, skipped
where absent); each page is also rendered in headless Chromium where it is installed.
"""

import shutil
from dataclasses import replace

import cv2
import numpy as np
import pytest

from camnet.io.report import render_report
from camnet.io.report_plots import bounding_box_figure, layout_figure, robust_box
from camnet.sim.families import family
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate
from tests._groundtruth import KITTI_ROOT
from tests.test_report import screenshot

MAX_BOX_TO_ROBUST = 3.0


def robust_extent(cal) -> np.ndarray:
    box = robust_box(cal.points)
    return box.max_m - box.min_m


def assert_plots_end_near_the_body(cal) -> None:
    extent_mm = 1e3 * robust_extent(cal)
    fig = bounding_box_figure(cal, robust_box(cal.points))
    for ax, (i, j) in zip(fig.axes, [(0, 1), (2, 1)], strict=True):
        width, height = np.ptp(ax.get_xlim()), np.ptp(ax.get_ylim())
        assert width <= MAX_BOX_TO_ROBUST * extent_mm[i] and height <= MAX_BOX_TO_ROBUST * extent_mm[j], (
            width, height, extent_mm)
    fig = layout_figure(cal)
    ax = fig.axes[0]
    centres = np.array([c.centre for c in cal.cameras])
    body = np.vstack([centres, *np.percentile(cal.points, [1, 99], axis=0)])[:, [0, 2]]
    assert np.ptp(ax.get_xlim()) <= MAX_BOX_TO_ROBUST * np.ptp(body, axis=0).max()
    fig.draw_without_rendering()
    boxes = [t.get_window_extent() for t in ax.texts]
    assert len(boxes) == len(cal.cameras)
    for a in range(len(boxes)):
        for b in range(a):
            assert not boxes[a].overlaps(boxes[b]), (ax.texts[a].get_text(), ax.texts[b].get_text())


def assert_renders(cal, tmp_path) -> None:
    html = tmp_path / "report.html"
    html.write_text(render_report(cal))
    assert "given" in html.read_text() or cal.uncertainty is None or all(
        s.f_px != 0 for s in cal.uncertainty.cameras.values())
    if shutil.which("chromium") is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium): the plot data were checked")
    png = tmp_path / "report.png"
    screenshot(html, png, tmp_path / "profile")
    image = cv2.imread(str(png))
    assert image is not None and image.std() > 20


def test_two_far_points_do_not_stretch_the_box(tmp_path):
    rig = make_rig(n_points=300, seed=2)
    cal = calibrate(observe(rig, noise_px=0.3, seed=2).observations).calibration
    far = np.array([[3.0, 2.0, 12.0], [-1.5, -1.0, 9.0]])  # as a track with no parallax lands
    stretched = replace(cal, points=np.vstack([cal.points, far]), point_ids=np.r_[cal.point_ids, [9998, 9999]])
    assert np.ptp(stretched.points, axis=0).max() > 50 * robust_extent(stretched).max()
    assert_plots_end_near_the_body(stretched)
    page = render_report(stretched)
    assert f"2 of {len(stretched.points)} points lie far beyond it" in page
    assert_renders(stretched, tmp_path)


def test_the_ring_rig(tmp_path):
    ring = family("ring", seed=0)
    obs = observe(ring.rig, noise_px=0.5, seed=0, normals=ring.normals).observations
    cal = calibrate(obs, Options(free=frozenset({"f", "stereo_rotation", "stereo_direction"}))).calibration
    assert len(cal.cameras) >= 8
    assert_plots_end_near_the_body(cal)
    assert_renders(cal, tmp_path)


@pytest.mark.skipif(not KITTI_ROOT.exists(), reason="the KITTI extract is not in the shared data")
def test_kitti(tmp_path):
    from camnet.datasets.kitti import KittiExtract, pooled_observations, prepare_scenario

    kitti = KittiExtract.open(KITTI_ROOT)
    obs = pooled_observations(kitti)
    prepared, head = prepare_scenario(obs, kitti.cameras, "all-K")
    cal = calibrate(prepared, Options(), initial=head).calibration
    assert_plots_end_near_the_body(cal)
    assert_renders(cal, tmp_path)
