"""The PLY point cloud, read back by plyfile: the calibration's points, ids and per-point sigmas."""

from __future__ import annotations

import io
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from camnet.errors import InputError
from camnet.io.export_ply import ply_points
from camnet.io.formats import parse_calibration
from camnet.sim.simulate import make_rig, observe
from camnet.solve import calibrate
from tests.test_export import rig_calibration

plyfile = pytest.importorskip("plyfile", reason="plyfile (the test extra) is not installed")
GOLDEN = Path(__file__).parent / "golden" / "sim-refined.json"


def read_ply(data: bytes):
    return plyfile.PlyData.read(io.BytesIO(data))


def test_ply_holds_the_documents_points_and_sigmas():
    doc = json.loads(GOLDEN.read_text())
    ply = read_ply(ply_points(parse_calibration(doc)))
    assert ply.text is False and ply.byte_order == "<"
    vertex = ply["vertex"]
    assert [p.name for p in vertex.properties] == ["x", "y", "z", "point_id", "sigma_m"]
    assert [p.val_dtype for p in vertex.properties] == ["f8", "f8", "f8", "i4", "f8"]
    # Every number exactly as the document has it (doubles), in its order.
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    np.testing.assert_array_equal(xyz, [p["xyz"] for p in doc["points"]])
    np.testing.assert_array_equal(vertex["point_id"], [p["id"] for p in doc["points"]])
    np.testing.assert_array_equal(vertex["sigma_m"], doc["uncertainty"]["point_sigma_m"])
    assert any("metres" in c for c in ply.comments)


def test_ply_without_uncertainty_has_no_sigma():
    cal, _ = rig_calibration()  # no report: nothing says how well the points are known
    ply = read_ply(ply_points(cal))
    assert [p.name for p in ply["vertex"].properties] == ["x", "y", "z", "point_id"]
    assert ply["vertex"].count == len(cal.points)
    np.testing.assert_array_equal(ply["vertex"]["z"], cal.points[:, 2])
    assert "no per-point uncertainty in the calibration" in ply.comments


def test_ply_refuses_what_it_cannot_hold():
    cal = parse_calibration(json.loads(GOLDEN.read_text()))
    with pytest.raises(InputError, match=r"point_sigma_m: 56 values for 57 points"):
        sigma = cal.uncertainty.point_sigma_m[:-1]
        ply_points(replace(cal, report=replace(cal.report, uncertainty=replace(cal.uncertainty, point_sigma_m=sigma))))
    with pytest.raises(InputError, match="point_ids: the PLY export needs ids from 0 to 2147483647"):
        ply_points(replace(cal, point_ids=cal.point_ids + 2**31))


def test_the_sigmas_the_ply_carries_are_the_size_of_the_errors():
    """Per point, |error| / (sqrt 3 sigma) has an RMS near 1 over seeded simulated rigs.

    A rig's points err together (its scale and pose), so it takes many rigs:
    10 give 0.80, 30 give 0.83 (the guessed principal points' prior makes the
    sigmas a little wide, as it should).
    """
    ratios = []
    for seed in range(10):
        rig = make_rig(seed=seed)
        cal = calibrate(observe(rig, noise_px=0.5, seed=seed).observations).calibration
        vertex = read_ply(ply_points(cal))["vertex"]
        truth = rig.points[np.asarray(vertex["point_id"])]  # the simulation's track id is its point's index
        error = np.linalg.norm(np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1) - truth, axis=1)
        ratios.append(error / (np.sqrt(3.0) * vertex["sigma_m"]))
    rms = float(np.sqrt(np.mean(np.concatenate(ratios) ** 2)))
    assert 0.6 < rms < 1.4, rms
