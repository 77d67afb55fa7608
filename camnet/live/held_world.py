"""The world frame held from solve to solve: a live rig's floor frame stays put while the floor does.

Each solve finds the floor anew (camnet.solve.world_frame), and its frame
jitters within its sigma; a moved camera, the left stereo camera above all,
moves the left camera's frame in which a calibration is solved. So the
frame of the last calibration is carried into the new one's left camera
frame through the cameras that did not move, and kept where the new floor
lies within HOLD_SIGMAS of its sigmas of it (up and height); only then is it
set anew from the new floor, and said so.

Frames: ``X_world = R @ X_left + t`` (camnet.model.calibration.FloorFrame),
cameras ``x_cam = R X + t``, metres, degrees.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import replace

import numpy as np

from camnet.model.accuracy import angle_between_deg, scale_error
from camnet.model.calibration import Calibration, FloorFrame
from camnet.model.camera import Camera

HOLD_SIGMAS = 3.0  # a new floor within this many of its sigmas of the held one is the same floor
MIN_SCALE_CAMERAS = 3  # a scale between two sets of camera centres needs a triangle


def _stayed(previous: Calibration, new: Calibration, still: Collection[str]) -> list[tuple[Camera, Camera]]:
    """(its camera in `previous`, in `new`) of each camera of `still` that both hold."""
    before = {c.id: c for c in previous.cameras}
    return [(before[c.id], c) for c in new.cameras if c.id in before and c.id in still]


def old_from_new(previous: Calibration, new: Calibration, still: Collection[str]) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) with ``X_previous_left = A @ X_new_left + b``: the rigid motion between the two calibrations' left
    camera frames that the cameras of `still` (in both) agree on. Raises ValueError where none is in both."""
    pairs = _stayed(previous, new, still)
    if not pairs:
        raise ValueError("no camera that stayed is in both calibrations")
    # Each camera's rotation gives A = R_old^T R_new; their chordal mean is the nearest rotation to the sum.
    u, _, vt = np.linalg.svd(sum(old.R.T @ cam.R for old, cam in pairs))
    A = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    b = np.mean([old.centre - A @ cam.centre for old, cam in pairs], axis=0)
    return A, b


def scale_apart(previous: Calibration, new: Calibration, still: Collection[str]) -> str:
    """Why `new`'s scale cannot stand beside `previous`'s ("" where it can): the cameras of `still` (in both,
    three or more) lie further apart or nearer in `new` than in `previous` by more than HOLD_SIGMAS of the two
    scales' sigmas together. A rig solved afresh after a stereo camera moved takes its scale from the stereo
    pair's known distance; where one of the pair moved without the other, that distance no longer holds, while
    the cameras that stayed keep theirs."""
    pairs = _stayed(previous, new, still)
    sigmas = [cal.uncertainty.scale_rel.value if cal.uncertainty is not None else None for cal in (previous, new)]
    if len(pairs) < MIN_SCALE_CAMERAS or None in sigmas:
        return ""
    error = scale_error(np.array([n.centre for _, n in pairs]), np.array([p.centre for p, _ in pairs]))
    sigma = float(np.hypot(*sigmas))
    if abs(error) <= HOLD_SIGMAS * sigma:
        return ""
    return (f"the cameras that stayed lie {100 * abs(error):.1f}% {'further apart' if error > 0 else 'nearer'} "
            f"in the solve after the move than before ({abs(error) / sigma:.1f} sigma): the stereo pair's known "
            "distance no longer holds (one of its cameras moved without the other); measure it again and give "
            "it in the rig file")


def held_floor(previous: Calibration, new: Calibration, still: Collection[str]) -> tuple[FloorFrame, str]:
    """(the floor frame for `new`, "" where the held one was kept, else why it was set anew).

    previous: the last calibration published, its floor frame the one held; new: a solve of the same rig with a
    floor frame of its own; still: the cameras that did not move between them. The held frame keeps its origin
    and heading; it takes the new floor's sigmas, or keeps its own where the new solve found no floor.
    """
    frame = new.floor_frame
    held = previous.floor_frame
    if frame is None or held is None or not held.found:
        return frame, ""
    try:
        A, b = old_from_new(previous, new, still)
    except ValueError:
        return frame, "the world frame was set anew: no camera that stayed is in both calibrations"
    R, t = held.R @ A, held.R @ b + held.t
    if not frame.found:  # the floor is out of this solve's tracks (fresh ones after a move), not out of the room
        return replace(held, R=R, t=t), ""
    tilt_deg = angle_between_deg(R[2], frame.R[2])
    origin = frame.R.T @ -frame.t  # the new frame's origin, on the new floor, in the new left frame
    height_m = abs(float(R[2] @ origin + t[2]))
    if tilt_deg <= HOLD_SIGMAS * frame.normal_sigma_deg and height_m <= HOLD_SIGMAS * frame.height_sigma_m:
        return replace(frame, R=R, t=t), ""
    return frame, (f"the world frame was set anew: the floor moved by {tilt_deg:.2f} deg and {1e3 * height_m:.0f} mm "
                   f"({tilt_deg / frame.normal_sigma_deg:.1f} and {height_m / frame.height_sigma_m:.1f} sigma)")
