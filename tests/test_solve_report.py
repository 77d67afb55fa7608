"""The solve report's JSON codec: documents read back into the same report and written again unchanged."""

import json
from pathlib import Path

import numpy as np
import pytest

from camnet.errors import InputError
from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.model.calibration import Calibration, StartKind
from camnet.model.camera import Camera
from camnet.model.methods import Method

GOLDEN = Path(__file__).parent / "golden"


@pytest.mark.parametrize("name", ["sim-refined.json", "sim-paper.json", "ring6-warm.json"])
def test_a_calibration_document_reads_back_into_the_same_document(name):
    doc = json.loads((GOLDEN / name).read_text())
    again = calibration_to_doc(parse_calibration(doc))
    assert json.dumps(again) == json.dumps(doc)


def test_the_report_holds_the_documented_keys_as_typed_fields():
    doc = json.loads((GOLDEN / "ring6-warm.json").read_text())
    report = parse_calibration(doc).report
    assert report.method == Method.REFINED and report.start == StartKind.WARM
    assert report.free.stereo_rotation_axes == ("x", "y", "z")
    assert report.cameras["mono_a"].inliers == doc["diagnostics"]["cameras"]["mono_a"]["inliers"]
    assert report.uncertainty.cameras["left"].centre_m == (0.0, 0.0, 0.0)
    assert report.uncertainty.scale_rel.value == doc["uncertainty"]["scale_rel"]


def test_a_sigma_written_as_null_is_not_determined_and_says_so():
    doc = json.loads((GOLDEN / "sim-refined.json").read_text())
    doc["uncertainty"]["scale_rel"] = None
    sigma = parse_calibration(doc).report.uncertainty.scale_rel
    assert sigma.value is None and sigma.reason
    assert calibration_to_doc(parse_calibration(doc))["uncertainty"]["scale_rel"] is None


def test_a_factory_head_has_no_report_and_writes_no_further_keys():
    head = Calibration((Camera("left", 640, 480, np.diag([500.0, 500.0, 1.0])),), np.empty(0, np.int64),
                       np.empty((0, 3)), float("nan"), "left")
    doc = calibration_to_doc(head)
    assert doc["rms_reprojection_px"] is None and "diagnostics" not in doc and "uncertainty" not in doc
    assert parse_calibration(doc).report is None


def test_an_unknown_method_or_start_is_refused_by_path():
    doc = json.loads((GOLDEN / "sim-refined.json").read_text())
    with pytest.raises(InputError, match=r"^method: unknown value 'magic'"):
        parse_calibration({**doc, "method": "magic"})
    doc["diagnostics"]["start"] = "lukewarm"
    with pytest.raises(InputError, match=r"^diagnostics\.start: unknown value"):
        parse_calibration(doc)
