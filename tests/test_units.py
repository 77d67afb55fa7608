"""Known distances in the wrong unit are refused with the range and the unit; a deliberate giant is kept."""

import json

import pytest

from camnet.errors import InputError
from camnet.io.formats import observations_to_doc, parse_observations
from camnet.io.rig import parse_rig
from camnet.sim.simulate import make_rig, observe
from camnet.solve import calibrate
from camnet.solve.report.assemble import far_scene_warning
from tests.test_cli_calibrate import run_camnet


@pytest.fixture(scope="module")
def doc() -> dict:
    return observations_to_doc(observe(make_rig(seed=2), noise_px=0.3, seed=2).observations)


def test_millimetres_for_metres_are_refused_with_the_unit(doc):
    doc = json.loads(json.dumps(doc))
    doc["stereo"]["baseline_m"] = 125
    expected = (r"stereo.baseline_m: 125 m is not a distance between cameras \(expected 0.005 to 50 m\); "
                r"distances are given in metres \(125 mm = 0.125\)")
    with pytest.raises(InputError, match=expected):
        parse_observations(doc)
    assert parse_observations(doc, any_distance=True).stereo.baseline_m == 125


def test_kilometres_for_metres_and_further_distances_too(doc):
    doc = json.loads(json.dumps(doc))
    doc["stereo"]["baseline_m"] = 0.000125
    with pytest.raises(InputError, match=r"0.000125 km = 0.125"):
        parse_observations(doc)
    doc["stereo"]["baseline_m"] = 0.125
    doc["baselines"] = [{"cameras": ["mono_a", "mono_b"], "baseline_m": 731}]
    with pytest.raises(InputError, match=r"baselines\[0\].baseline_m: 731 m"):
        parse_observations(doc)


def test_a_rig_file_in_millimetres_is_refused_unless_it_says_so():
    rig = {"rig": "units", "stereo": {"left": "a", "right": "b", "baseline_m": 537.2},
           "cameras": [{"id": "a"}, {"id": "b"}]}  # cameras known from their images only
    with pytest.raises(InputError, match=r"stereo.baseline_m: 537.2 m is not a distance.*accept_any_distance"):
        parse_rig(rig)
    assert parse_rig({**rig, "accept_any_distance": True}).stereo.baseline_m == 537.2


def test_calibrate_refuses_in_one_line_and_accepts_on_request(tmp_path, doc):
    doc = json.loads(json.dumps(doc))
    doc["stereo"]["baseline_m"] = 125
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(json.dumps(doc))
    proc = run_camnet("calibrate", str(src), "-o", str(out))
    assert proc.returncode != 0 and len(proc.stderr.strip().splitlines()) == 1 and not out.exists()
    assert "125 mm = 0.125" in proc.stderr
    proc = run_camnet("calibrate", str(src), "-o", str(out), "--accept-any-distance")
    assert proc.returncode == 0 and json.loads(out.read_text())["cameras"][1]["t"][0] == pytest.approx(-125, rel=1e-3)


def test_a_scene_a_thousand_baselines_away_is_warned_of():
    near = calibrate(observe(make_rig(seed=3), noise_px=0.3, seed=3).observations).calibration
    assert not any("baselines away" in w for w in near.warnings)  # 0.6 m for 0.125 m
    assert not far_scene_warning(21.0, 0.54)  # KITTI: the median point 40 baselines away
    (warning,) = far_scene_warning(608.0, 0.125)  # 125 mm taken for 125 m, the scene solved as before
    assert warning.startswith("the median point is 4864 baselines away (608 m for 0.125 m)")
