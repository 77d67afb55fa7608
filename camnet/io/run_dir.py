"""What a run of the network leaves where its user can see it.

`camnet up` names a run directory (``runs/<rig>-<time>`` under the working
directory unless told otherwise) and leaves in it: the last calibration, the
pooled observations it was solved from, an HTML report and the exports of
`EXPORTS`, beside the nodes' logs (``logs/``); for a simulated rig also its
ground truth (``truth.json``, a calibration file of the true cameras, which
the report compares the calibration with).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from camnet.io.atomic import write_directory_atomic, write_text_atomic
from camnet.io.export import COLMAP_FORMATS, export, is_multi_file
from camnet.io.formats import calibration_to_doc, write_json_atomic
from camnet.io.messages import (
    CalibrationMessage,
    MessageError,
    ObservationsMessage,
    calibration_message_to_doc,
    decode_observations_message,
    observations_message_to_doc,
)
from camnet.io.report import render_report
from camnet.model.calibration import Calibration
from camnet.model.camera import Camera

# (format of `camnet export`, file or directory name in the run directory)
EXPORTS = (("opencv", "calibration.yaml"), ("colmap", "colmap"), ("ply", "points.ply"))


def default_run_dir(rig_name: str, *, now_s: float | None = None) -> Path:
    """``runs/<rig>-<local time to the second>``, relative to the working directory."""
    return Path("runs") / f"{rig_name}-{time.strftime('%Y%m%d-%H%M%S', time.localtime(now_s))}"


SourceKey = tuple[int | None, int | None]


def source_key(message: CalibrationMessage | ObservationsMessage) -> SourceKey:
    """What ties a calibration to the observations it was solved from: both carry their frame sets and latest
    capture time."""
    return message.frame_sets, message.latest_capture_ns


def observations_behind(path: Path, calibration: CalibrationMessage) -> ObservationsMessage | None:
    """The observations `calibration` was solved from, as its calibrator wrote them to `path` when it stopped
    (`camnet calibrator --observations-out`); None where the file is absent, unreadable, or of another solve."""
    try:
        message = decode_observations_message(path.read_bytes())
    except (OSError, MessageError):
        return None
    return message if source_key(message) == source_key(calibration) else None


def truth_document(truth: list[Camera]) -> dict:
    """The ground truth of a simulated rig's cameras as a calibration document (no points): what
    `camnet report --truth` reads, as `camnet simulate --truth` writes it."""
    return calibration_to_doc(Calibration(tuple(truth), np.zeros(0, dtype=np.int64), np.zeros((0, 3)), 0.0,
                                          truth[0].id))


def write_results(run_dir: Path, calibration: CalibrationMessage, observations: ObservationsMessage | None,
                  truth: list[Camera] | None = None) -> list[Path]:
    """Write the calibration, its observations (when known), the ground truth (a simulated rig's), the
    report and the exports; the paths written."""
    run_dir.mkdir(parents=True, exist_ok=True)
    cal = calibration.calibration
    obs = observations.observations if observations is not None else None
    written = [run_dir / "calibration.json"]
    write_json_atomic(written[0], calibration_message_to_doc(calibration))
    if observations is not None:
        written.append(run_dir / "observations.json")
        write_json_atomic(written[-1], observations_message_to_doc(observations))
    if truth:
        written.append(run_dir / "truth.json")
        write_json_atomic(written[-1], truth_document(truth))
    page = render_report(cal, obs, title=f"camnet: {run_dir.name}", truth=truth or None)
    written.append(write_text_atomic(run_dir / "report.html", page))
    for fmt, name in EXPORTS:
        files = export(cal, fmt, observations=obs if fmt in COLMAP_FORMATS else None)
        if is_multi_file(fmt):
            write_directory_atomic(run_dir / name, files)
            written.append(run_dir / name)
        else:
            ((_, content),) = files.items()
            written.append(write_text_atomic(run_dir / name, content))
    return written
