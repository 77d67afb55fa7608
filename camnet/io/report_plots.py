"""The report's plots and the point cloud's extent: matplotlib figures as inline SVG.

Per camera, the reprojection error of every point (the paper's Fig. 5), the
residual histograms and the uncertainty; the point cloud's robust bounding
box seen from the front and the side; the camera layout (`plot_layout`). matplotlib
is imported here without pyplot, so no global backend is set.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from camnet.model.calibration import Calibration, CameraSigmas
from camnet.solve.report.reprojection import Residuals


@dataclass(frozen=True)
class BoundingBox:
    """Axis-aligned box of a point cloud in the world frame (the left stereo camera's), metres."""

    min_m: np.ndarray  # (3,)
    max_m: np.ndarray  # (3,)

    @property
    def size_mm(self) -> np.ndarray:
        """Extent along X, Y, Z in millimetres (the paper's "98mm x 168mm x 75mm")."""
        return 1e3 * (self.max_m - self.min_m)


def bounding_box(points_m: np.ndarray) -> BoundingBox | None:
    """The cloud's axis-aligned bounding box; None for no points."""
    points_m = np.asarray(points_m, dtype=float).reshape(-1, 3)
    if not len(points_m):
        return None
    return BoundingBox(points_m.min(axis=0), points_m.max(axis=0))


ROBUST_PERCENTILES = (1.0, 99.0)


def robust_box(points_m: np.ndarray) -> BoundingBox | None:
    """The box of the 1st to 99th percentile along each axis: a few far points (no parallax, a false
    match) do not stretch it. None for no points."""
    points_m = np.asarray(points_m, dtype=float).reshape(-1, 3)
    if not len(points_m):
        return None
    lo, hi = np.percentile(points_m, ROBUST_PERCENTILES, axis=0)
    return BoundingBox(lo, hi)


def outside(points_m: np.ndarray, box: BoundingBox) -> np.ndarray:
    """(N,) bool: the points outside `box` on any axis."""
    return np.any((points_m < box.min_m) | (points_m > box.max_m), axis=1)


def plot_limits(lo: np.ndarray, hi: np.ndarray, margin: float = 0.08) -> tuple[np.ndarray, np.ndarray]:
    """Axis limits around [lo, hi] with a margin, so that points clipped to the edge stay visible."""
    pad = margin * np.maximum(hi - lo, 1e-6)
    return lo - pad, hi + pad


def _clipped(ax, x: np.ndarray, y: np.ndarray, lim_x, lim_y, *, colour: str, label: str) -> None:
    """Points inside the limits as dots; those beyond drawn on the edge as red triangles, counted."""
    cx, cy = np.clip(x, *lim_x), np.clip(y, *lim_y)
    far = (cx != x) | (cy != y)
    ax.plot(cx[~far], cy[~far], ".", color=colour, markersize=3, label=label)
    if far.any():
        ax.plot(cx[far], cy[far], "^", color="C3", markersize=5, label=f"{int(far.sum())} beyond, at the edge")


def camera_colour(m: int) -> str:
    """The colour of camera `m` in every plot (matplotlib's tab10 cycle)."""
    return f"C{m % 10}"


def _svg(fig) -> str:
    import matplotlib

    buf = io.StringIO()
    # A fixed salt and no metadata (date, creator) keep the page the same for the same calibration;
    # text stays text (searchable, small) rather than glyph outlines.
    with matplotlib.rc_context({"svg.hashsalt": "camnet", "svg.fonttype": "none"}):
        fig.savefig(buf, format="svg", metadata=dict.fromkeys(("Date", "Creator", "Format", "Type")))
    text = buf.getvalue()
    return text[text.index("<svg") :]


def _figure(n_panels: int, *, columns: int, panel_in: tuple[float, float]):
    from matplotlib.figure import Figure

    rows = max(1, math.ceil(n_panels / columns))
    cols = min(columns, max(1, n_panels))
    fig = Figure(figsize=(panel_in[0] * cols, panel_in[1] * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[n_panels:]:
        ax.set_visible(False)
    return fig, axes


def plot_per_point_errors(cal: Calibration, res: Residuals, limit_px: float) -> str:
    """The paper's Fig. 5: per camera, the reprojection error (px) of each point against its track id.

    The axis stops at twice the outlier limit (dashed); errors beyond it are
    drawn as triangles on the top edge, so that outliers do not flatten the rest.
    """
    fig, axes = _figure(len(cal.cameras), columns=2, panel_in=(5.8, 2.6))
    error = res.error_px
    inside = error[error <= limit_px]
    top = max(2.0 * limit_px if math.isfinite(limit_px) else 0.0, 1.1 * float(np.max(inside, initial=0.0)), 1e-3)
    for m, (cam, ax) in enumerate(zip(cal.cameras, axes, strict=False)):
        mine = res.cam_index == m
        track, e = cal.point_ids[res.point_index[mine]], error[mine]
        beyond = ~(e <= top)
        ax.vlines(track, 0.0, np.minimum(e, top), color=camera_colour(m), linewidth=1.0)
        ax.plot(track[~beyond], e[~beyond], "o", color=camera_colour(m), markersize=2.5)
        ax.plot(track[beyond], np.full(beyond.sum(), 0.96 * top), "^", color="C3", markersize=6)
        if math.isfinite(limit_px):
            ax.axhline(limit_px, color="0.4", linestyle="--", linewidth=0.8)
        ax.set_title(f"{cam.id}: {int(mine.sum())} observations, {int(beyond.sum())} off scale", fontsize=10)
        ax.set_xlabel("point (track id)")
        ax.set_ylabel("error (px)")
        ax.set_ylim(0.0, top)
        ax.grid(alpha=0.3)
    return _svg(fig)


def plot_residual_histograms(cal: Calibration, res: Residuals, limit_px: float, sigma_px: float | None) -> str:
    """Per camera, histograms of the u and v residuals (px) within +-limit_px (outliers pile up at the
    edges), with the normal density of sigma_px for comparison."""
    fig, axes = _figure(len(cal.cameras), columns=4, panel_in=(2.9, 2.4))
    if not math.isfinite(limit_px):
        finite = np.abs(res.residual_px[np.all(np.isfinite(res.residual_px), axis=1)])
        limit_px = float(np.max(finite, initial=1.0))
    bins = np.linspace(-limit_px, limit_px, 31)
    for m, (cam, ax) in enumerate(zip(cal.cameras, axes, strict=False)):
        r = np.clip(res.residual_px[res.cam_index == m], -limit_px, limit_px)
        ax.hist(r[:, 0], bins=bins, color=camera_colour(m), alpha=0.75, label="u")
        ax.hist(r[:, 1], bins=bins, histtype="step", color="k", label="v")
        if sigma_px and len(r):
            x = np.linspace(-limit_px, limit_px, 200)
            density = np.exp(-0.5 * (x / sigma_px) ** 2) / (sigma_px * math.sqrt(2 * math.pi))
            ax.plot(x, len(r) * (bins[1] - bins[0]) * density, "--", color="0.4", label=f"N(0, {sigma_px:.2f})")
        ax.set_title(cam.id, fontsize=10)
        ax.set_xlabel("residual (px)")
        ax.legend(fontsize=7)
    return _svg(fig)


def plot_uncertainty(cal: Calibration, per_camera: Mapping[str, CameraSigmas]) -> str:
    """Per camera, 1-sigma of the intrinsics (px), the centre (mm) and the rotation (deg); held: 'given'."""
    panels = [
        ("intrinsics (px)", ["f", "cx", "cy"], lambda u: [u.f_px, u.cx_px, u.cy_px]),
        ("centre (mm)", ["x", "y", "z"], lambda u: [1e3 * v for v in u.centre_m]),
        ("rotation (deg)", ["x", "y", "z"], lambda u: list(u.rotation_deg)),
    ]
    fig, axes = _figure(len(panels), columns=3, panel_in=(3.9, 2.9))
    width = 0.8 / max(1, len(cal.cameras))
    for ax, (title, labels, values) in zip(axes, panels, strict=True):
        for m, cam in enumerate(cal.cameras):
            if cam.id not in per_camera:
                continue
            heights = np.array(values(per_camera[cam.id]), dtype=float)
            x = np.arange(len(labels)) + (m + 0.5) * width - 0.4
            ax.bar(x, np.where(np.isfinite(heights), heights, 0.0), width=width, color=camera_colour(m), label=cam.id)
            for xi, h in zip(x, heights, strict=True):
                if h == 0.0 or not np.isfinite(h):  # held: no bar of height 0 that reads as "known exactly"
                    ax.annotate("given" if h == 0.0 else "n/d", (xi, 0.0), textcoords="offset points",
                                xytext=(0, 2), rotation=90, ha="center", va="bottom", fontsize=7,
                                color=camera_colour(m))
        ax.set_xticks(np.arange(len(labels)), labels)
        ax.set_title(f"1 sigma: {title}", fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7)
    return _svg(fig)


def plot_bounding_box(cal: Calibration, box: BoundingBox) -> str:
    """The cloud seen from the front (X-Y) and the side (Z-Y), in mm, with its robust box (`box`); the
    axes end near the box, and points beyond are drawn on the edge."""
    return _svg(bounding_box_figure(cal, box))


def bounding_box_figure(cal: Calibration, box: BoundingBox):
    """The figure of `plot_bounding_box`."""
    from matplotlib.patches import Rectangle

    fig, axes = _figure(2, columns=2, panel_in=(4.6, 4.2))
    P = 1e3 * cal.points
    lo, hi = 1e3 * box.min_m, 1e3 * box.max_m
    lim_lo, lim_hi = plot_limits(lo, hi)
    for ax, (i, j), name in zip(axes, [(0, 1), (2, 1)], ["front (X-Y)", "side (Z-Y)"], strict=True):
        ax.add_patch(Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], fill=False, color="C3", linewidth=1.5))
        _clipped(ax, P[:, i], P[:, j], (lim_lo[i], lim_hi[i]), (lim_lo[j], lim_hi[j]), colour="0.2", label="points")
        ax.set_xlim(lim_lo[i], lim_hi[i])
        ax.set_ylim(lim_hi[j], lim_lo[j])  # camera y points down
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(f"{'XYZ'[i]} (mm)")
        ax.set_ylabel(f"{'XYZ'[j]} (mm, down)")
        ax.set_title(f"{name}: {hi[i] - lo[i]:.1f} x {hi[j] - lo[j]:.1f} mm", fontsize=10)
        ax.legend(fontsize=7, loc="upper right")
    return fig


def frustum(cam, depth_m: float, *, vertical: bool = False) -> np.ndarray:
    """World points (metres) of the camera centre and its field of view's edges at `depth_m`: (3, 3), centre, first
    edge, second edge.

    Horizontal: rays through the left and right image borders (u = -0.5 and width - 0.5 at the principal point's
    row); vertical: through the top and bottom borders (v = -0.5 and height - 0.5 at its column). Undistorted, they
    go from the camera frame to the world by ``X = R.T @ (x_cam - t)``.
    """
    cx, cy = cam.K[0, 2], cam.K[1, 2]
    border = np.array([[cx, -0.5], [cx, cam.height - 0.5]]) if vertical else \
        np.array([[-0.5, cy], [cam.width - 0.5, cy]])
    xn = cam.normalised(border)
    rays = np.hstack([xn, np.ones((2, 1))]) * depth_m
    world = (rays - cam.t) @ cam.R
    return np.vstack([cam.centre, world])


def frustum_xz(cam, depth_m: float) -> np.ndarray:
    """World (x, z) of the camera centre and its horizontal field of view's edges at `depth_m` (`frustum`):
    (3, 2), centre, left edge, right edge."""
    return frustum(cam, depth_m)[:, [0, 2]]


def _square_limits(centres: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of a square view (two axes, metres) around the cameras' centres (M, 2) and the robust box of the
    points (N, 2), with a margin."""
    box = robust_box(np.column_stack([points, np.zeros(len(points))]))
    span = centres if box is None else np.vstack([centres, box.min_m[:2], box.max_m[:2]])
    lo, hi = span.min(axis=0), span.max(axis=0)
    side = max(float(np.max(hi - lo)), 1e-3)
    mid = (lo + hi) / 2  # square, so that the equal aspect keeps these limits
    return plot_limits(mid - side / 2, mid + side / 2)


def layout_limits(cal: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) in world (x, z), metres, of the view from above: the cameras and the robust box of the points."""
    centres = np.array([cam.centre for cam in cal.cameras])
    return _square_limits(centres[:, [0, 2]], cal.points.reshape(-1, 3)[:, [0, 2]])


LABEL_STEP_PT = 11.0  # a label's height, in points: labels closer than this in both directions are moved


def label_offsets_pt(anchors_pt: np.ndarray, widths_pt: np.ndarray) -> np.ndarray:
    """(M, 2) offsets in points for labels at anchors (M, 2) (display points), none of them overlapping.

    Each label sits right of and below its anchor; one that would overlap a label
    already placed moves a line up or down, alternately and ever farther, until it does not.
    """
    placed: list[tuple[float, float, float]] = []  # x, y, width of each placed label's corner
    offsets = []
    for (x, y), width in zip(anchors_pt, widths_pt, strict=True):
        for k in range(len(anchors_pt) * 2 + 1):  # below, above, two below, two above, ...
            dy = -LABEL_STEP_PT * (1 + (k + 1) // 2) if k % 2 == 0 else LABEL_STEP_PT * ((k + 1) // 2) - 3.0
            if not any(abs(y + dy - py) < LABEL_STEP_PT and x < px + pw and px < x + width for px, py, pw in placed):
                break
        placed.append((x, y + dy, width))
        offsets.append((4.0, dy))
    return np.array(offsets).reshape(-1, 2)


def plot_layout(cal: Calibration) -> str:
    """Cameras (frusta) and points seen from above, to scale: with a floor frame, its floor plan (X-Y, Z up) and a
    side view (X-Z, the floor at z = 0); without one, the left camera's X-Z plane (X right, Z forward).

    The views end near the cameras and the robust box of the points; points beyond are drawn on the edge. Camera
    labels are moved apart where they would overlap.
    """
    return _svg(layout_figure(cal))


FLOOR_TITLE = "floor frame: Z up, origin on the floor"


def layout_figure(cal: Calibration):
    """The figure of `plot_layout`: one axes without a floor frame, two with one (the floor plan, the side view)."""
    if cal.floor_frame is None:
        return _left_layout_figure(cal)
    return _floor_layout_figure(cal)


def _left_layout_figure(cal: Calibration):
    fig, axes = _figure(1, columns=1, panel_in=(7.0, 6.0))
    ax = axes[0]
    lo, hi = layout_limits(cal)
    _draw_view(ax, cal.cameras, cal.points, (0, 2), lo, hi)
    fig.draw_without_rendering()  # the constrained layout's final axes, so that the anchors are where they end up
    _label_cameras(fig, ax, cal.cameras, (0, 2))
    ax.set_title(f"left camera's frame (camera {cal.world_frame}): X right, Z forward, from above", fontsize=10)
    return fig


def _floor_layout_figure(cal: Calibration):
    from matplotlib.figure import Figure

    from camnet.model.calibration import in_world_frame

    world = in_world_frame(cal)
    centres = np.array([cam.centre for cam in world.cameras])
    lo, hi = _square_limits(centres[:, :2], world.points[:, :2])
    box = robust_box(world.points)
    heights = np.r_[0.0, centres[:, 2]] if box is None else np.r_[0.0, centres[:, 2], box.min_m[2], box.max_m[2]]
    z_lo, z_hi = plot_limits(np.array([heights.min()]), np.array([heights.max()]))
    side_lo, side_hi = np.array([lo[0], z_lo[0]]), np.array([hi[0], z_hi[0]])
    ratio = float(np.clip((z_hi[0] - z_lo[0]) / (hi[0] - lo[0]), 0.25, 1.0))
    fig = Figure(figsize=(7.0, 6.0 * (1.0 + ratio)), layout="constrained")
    top, side = fig.subplots(2, 1, height_ratios=[1.0, ratio])
    _draw_view(top, world.cameras, world.points, (0, 1), lo, hi)
    _draw_view(side, world.cameras, world.points, (0, 2), side_lo, side_hi, vertical=True)
    side.axhline(0.0, color="0.2", linewidth=1.5, label="floor (z = 0)")
    fig.draw_without_rendering()
    for ax, axes in ((top, (0, 1)), (side, (0, 2))):
        _label_cameras(fig, ax, world.cameras, axes)
    top.set_title(f"floor plan (X-Y, from above); {FLOOR_TITLE}", fontsize=10)
    side.set_title(f"side view (X-Z); {FLOOR_TITLE}", fontsize=10)
    return fig


def _draw_view(ax, cameras, points: np.ndarray, axes: tuple[int, int], lo: np.ndarray, hi: np.ndarray, *,
               vertical: bool = False) -> None:
    """The points and the cameras' frusta (horizontal, or `vertical`) on the world `axes` (two of 0, 1, 2), to
    scale within [lo, hi] (metres)."""
    i, j = axes
    depth = 0.25 * float(np.max(hi - lo)) / 1.16  # a quarter of the view (the limits carry an 8% margin)
    if len(points):
        _clipped(ax, points[:, i], points[:, j], (lo[0], hi[0]), (lo[1], hi[1]), colour="0.4", label="points")
    for m, cam in enumerate(cameras):
        c, first, second = frustum(cam, depth, vertical=vertical)[:, [i, j]]
        ax.fill([c[0], first[0], second[0]], [c[1], first[1], second[1]], color=camera_colour(m), alpha=0.25)
        ax.plot([first[0], c[0], second[0]], [first[1], c[1], second[1]], color=camera_colour(m), linewidth=1.5)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel(f"{'XYZ'[i]} (m)")
    ax.set_ylabel(f"{'XYZ'[j]} (m)")
    ax.grid(alpha=0.3)


def _label_cameras(fig, ax, cameras, axes: tuple[int, int]) -> None:
    """Each camera's id beside its centre, none overlapping; after the figure's layout is drawn."""
    # Anchors in points of the figure: data to pixels, then 72 points to the inch.
    centres = np.array([cam.centre[list(axes)] for cam in cameras])
    anchors = ax.transData.transform(centres) * 72.0 / fig.dpi
    widths = np.array([6.0 * len(cam.id) + 4.0 for cam in cameras])  # 9 pt text: about 6 pt a character
    for m, (cam, offset) in enumerate(zip(cameras, label_offsets_pt(anchors, widths), strict=True)):
        ax.annotate(cam.id, centres[m], textcoords="offset points", xytext=offset, fontsize=9,
                    color=camera_colour(m))
    ax.legend(fontsize=7, loc="upper right")
