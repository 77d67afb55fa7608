"""The ``camnet.meeting/1`` document: calibrated sites placed in one metric space (docs/fusing-sites.md).

Each site keeps its calibration whole (a ``camnet.calibration/1`` document in its floor frame) beside its
placement in the meeting frame, ``X_meeting = R @ X_site + t`` (camnet.model.meeting), so that one file is all a
renderer reads and each site's own document stays what its calibrator wrote.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camnet.errors import InputError
from camnet.io import validate as v
from camnet.io.formats import calibration_to_doc, check_format, parse_calibration
from camnet.model.calibration import Calibration, in_world_frame
from camnet.model.camera import Camera, in_frame
from camnet.model.meeting import LAYOUTS, Layout, Placement

MEETING_FORMAT = "camnet.meeting/1"


@dataclass(frozen=True)
class Site:
    """One site: its name, its calibration (with a floor frame) and where its floor frame stands."""

    name: str
    calibration: Calibration
    placement: Placement

    def cameras(self) -> tuple[Camera, ...]:
        """The site's cameras posed in the meeting frame (``x_cam = R @ X_meeting + t``)."""
        return tuple(in_frame(c, self.placement.R, self.placement.t) for c in in_world_frame(self.calibration).cameras)

    def points(self) -> np.ndarray:
        """(N, 3) the site's points in the meeting frame, metres."""
        return in_world_frame(self.calibration).points @ self.placement.R.T + self.placement.t


@dataclass(frozen=True)
class Meeting:
    layout: Layout
    sites: tuple[Site, ...]


def meeting_to_doc(meeting: Meeting) -> dict:
    return {
        "format": MEETING_FORMAT,
        "units": "m",
        "layout": {"kind": meeting.layout.kind, "distance_m": meeting.layout.distance_m},
        "sites": [{"name": s.name,
                   "meeting_from_site": {"R": s.placement.R.tolist(), "t": s.placement.t.tolist()},
                   "calibration": calibration_to_doc(s.calibration)} for s in meeting.sites],
    }


def parse_meeting(doc: Any) -> Meeting:
    """Validate a ``camnet.meeting/1`` document."""
    check_format(doc, MEETING_FORMAT)
    layout_raw = v.mapping(v.require(doc, "layout", ""), "layout")
    layout = Layout(v.string(v.require(layout_raw, "kind", "layout"), "layout.kind", choices=LAYOUTS),
                    v.number(v.require(layout_raw, "distance_m", "layout"), "layout.distance_m", positive=True))
    sites = []
    for i, raw in enumerate(v.non_empty_list(v.require(doc, "sites", ""), "sites")):
        path = f"sites[{i}]"
        where = f"{path}.meeting_from_site"
        pose = v.mapping(v.require(raw, "meeting_from_site", path), where)
        placement = Placement(v.rotation(v.require(pose, "R", where), f"{where}.R"),
                              v.vector(v.require(pose, "t", where), f"{where}.t", size=3))
        try:
            calibration = parse_calibration(v.require(raw, "calibration", path))
        except InputError as exc:
            raise InputError(f"{path}.calibration: {exc}") from None
        sites.append(Site(v.string(v.require(raw, "name", path), f"{path}.name"), calibration, placement))
    return Meeting(layout, tuple(sites))
