"""The observations format's known distances: `stereo.sigma_m` and the `baselines` list, read and written."""

import copy

import numpy as np
import pytest

from camnet.errors import InputError
from camnet.io.formats import observations_to_doc, parse_observations
from camnet.io.messages import observations_message_to_doc
from camnet.io.rig import parse_rig
from camnet.sim.simulate import make_rig, observe


@pytest.fixture()
def doc() -> dict:
    doc = observations_to_doc(observe(make_rig(n_points=8, seed=1), seed=1).observations)
    doc["stereo"]["sigma_m"] = 0.0005
    doc["baselines"] = [
        {"cameras": ["mono_a", "mono_b"], "baseline_m": 0.731, "sigma_m": 0.002},
        {"cameras": ["left", "mono_a"], "baseline_m": 0.304},
    ]
    return doc


def test_distances_are_read_as_given(doc):
    obs = parse_observations(doc)
    assert obs.stereo.sigma_m == 0.0005
    assert [(b.a, b.b, b.baseline_m, b.sigma_m) for b in obs.baselines] == [
        ("mono_a", "mono_b", 0.731, 0.002),
        ("left", "mono_a", 0.304, 0.0),
    ]


def test_round_trip_keeps_every_distance_and_writes_exact_ones_without_sigma(doc):
    written = observations_to_doc(parse_observations(doc))
    assert written["stereo"] == doc["stereo"]
    assert written["baselines"] == doc["baselines"]
    assert "sigma_m" not in written["baselines"][1]
    again = parse_observations(written)
    assert again.baselines == parse_observations(doc).baselines
    np.testing.assert_array_equal(again.uv, parse_observations(doc).uv)


def test_without_distances_nothing_new_is_written(doc):
    del doc["baselines"], doc["stereo"]["sigma_m"]
    obs = parse_observations(doc)
    assert obs.baselines == () and obs.stereo.sigma_m == 0.0
    written = observations_to_doc(obs)
    assert "baselines" not in written and "sigma_m" not in written["stereo"]


def test_null_sigma_is_exact(doc):
    doc["baselines"][0]["sigma_m"] = None
    assert parse_observations(doc).baselines[0].sigma_m == 0.0


@pytest.mark.parametrize(
    ("where", "value", "message"),
    [
        ("baselines", {"cameras": ["mono_a"]}, "baselines: expected a list"),
        ("cameras", ["mono_a"], "baselines[1].cameras: expected [a, b], two camera ids"),
        ("cameras", ["mono_a", "x"], "baselines[1].cameras: unknown camera 'x'"),
        ("cameras", ["mono_a", 3], 'baselines[1].cameras[1]: ids are strings, got the number 3; quote it: "3"'),
        ("cameras", ["mono_b", "mono_b"], "baselines[1].cameras: the same camera 'mono_b' twice"),
        ("cameras", ["right", "left"], "baselines[1].cameras: the distance of 'right' and 'left' is already given "
                                       "by stereo.baseline_m"),
        ("cameras", ["mono_b", "mono_a"], "baselines[1].cameras: the distance of 'mono_b' and 'mono_a' is already "
                                          "given by baselines[0]"),
        ("baseline_m", 0.0, "baselines[1].baseline_m: must be positive"),
        ("baseline_m", -0.2, "baselines[1].baseline_m: must be positive"),
        ("baseline_m", float("inf"), "baselines[1].baseline_m: expected a finite number"),
        ("baseline_m", "0.3", "baselines[1].baseline_m: expected a finite number"),
        ("baseline_m", None, "baselines[1].baseline_m: expected a finite number"),
        ("sigma_m", -0.001, "baselines[1].sigma_m: must be at least 0"),
        ("sigma_m", float("nan"), "baselines[1].sigma_m: expected a finite number"),
        ("stereo.sigma_m", -0.001, "stereo.sigma_m: must be at least 0"),
        ("stereo.sigma_m", True, "stereo.sigma_m: expected a finite number"),
    ],
)
def test_bad_distances_get_one_line_naming_the_path(doc, where, value, message):
    bad = copy.deepcopy(doc)
    if where == "baselines":
        bad["baselines"] = value
    elif where == "stereo.sigma_m":
        bad["stereo"]["sigma_m"] = value
    else:
        bad["baselines"][1][where] = value
    with pytest.raises(InputError) as err:
        parse_observations(bad)
    assert str(err.value).startswith(message), str(err.value)
    assert "\n" not in str(err.value)


def test_an_integer_beyond_any_float_is_refused_as_no_number(doc):
    bad = copy.deepcopy(doc)
    bad["tracks"][0]["observations"]["left"] = [10**400, 1]
    with pytest.raises(InputError, match=r"^tracks\[0\]\.observations\.left\[0\]: expected a finite number"):
        parse_observations(bad)
    doc["baselines"][1]["baseline_m"] = 10**400
    with pytest.raises(InputError, match=r"^baselines\[1\]\.baseline_m: expected a finite number"):
        parse_observations(doc, any_distance=True)


def test_a_missing_distance_is_named(doc):
    del doc["baselines"][0]["baseline_m"]
    with pytest.raises(InputError, match=r"^baselines\[0\]\.baseline_m: missing$"):
        parse_observations(doc)


# ---------------------------------------------------------------- rig files and the matcher's observations


def rig_doc() -> dict:
    sim = {"width": 64, "height": 48, "f_px": 50}
    return {
        "rig": "r",
        "stereo": {"left": "a", "right": "b", "baseline_m": 0.1, "sigma_m": 0.001},
        "baselines": [{"cameras": ["c", "d"], "baseline_m": 0.12}, {"cameras": ["a", "c"], "baseline_m": 1.5,
                                                                     "sigma_m": 0.002}],
        "cameras": [{"id": name, "driver": "sim", "sim": sim} for name in "abcd"],
    }


def test_a_rig_file_names_its_distances_as_the_observations_do():
    rig = parse_rig(rig_doc(), source="rig.yaml")
    assert rig.stereo.sigma_m == 0.001
    assert [(b.a, b.b, b.baseline_m, b.sigma_m) for b in rig.baselines] == [("c", "d", 0.12, 0.0),
                                                                            ("a", "c", 1.5, 0.002)]
    plain = rig_doc()
    del plain["baselines"], plain["stereo"]["sigma_m"]
    rig = parse_rig(plain)
    assert rig.baselines == () and rig.stereo.sigma_m == 0.0


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d["baselines"][1].update(cameras=["a", "x"]), "rig.yaml: baselines[1].cameras: unknown camera 'x'"),
        (lambda d: d["baselines"][1].update(cameras=["b", "a"]), "rig.yaml: baselines[1].cameras: the distance of "
                                                                 "'b' and 'a' is already given by stereo.baseline_m"),
        (lambda d: d["baselines"][0].update(sigma=0.1),
         "rig.yaml: unknown key 'sigma' in baselines[0] (did you mean 'sigma_m'?)"),
        (lambda d: d["baselines"][0].update(baseline_m=-1), "rig.yaml: baselines[0].baseline_m: must be positive"),
        (lambda d: d["stereo"].update(sigma_m=-1), "rig.yaml: stereo.sigma_m: must be at least 0"),
        (lambda d: d.update(baselines={"c": "d"}), "rig.yaml: baselines: expected a list"),
    ],
)
def test_bad_distances_in_a_rig_file_are_named(change, message):
    data = rig_doc()
    change(data)
    with pytest.raises(InputError) as err:
        parse_rig(data, source="rig.yaml")
    assert str(err.value).startswith(message), str(err.value)


def test_the_matchers_observations_carry_the_rigs_distances():
    from camnet.services.matcher import MatcherNode, MatcherNodeConfig

    doc = observations_message_to_doc(MatcherNode(None, parse_rig(rig_doc()), config=MatcherNodeConfig()).message())
    assert doc["stereo"] == rig_doc()["stereo"]
    assert doc["baselines"] == rig_doc()["baselines"]
    obs = parse_observations(doc)
    assert [b.a for b in obs.baselines] == ["c", "a"]


def test_a_distance_to_a_camera_not_yet_pooled_waits_for_it():
    from camnet.services.matcher import MatcherNode, MatcherNodeConfig

    data = rig_doc()
    data["cameras"][3] = {"id": "d", "driver": "v4l2", "v4l2": {"source": "unused.mp4"}}  # size known when it sends
    doc = observations_message_to_doc(MatcherNode(None, parse_rig(data), config=MatcherNodeConfig()).message())
    assert [c["id"] for c in doc["cameras"]] == ["a", "b", "c"]
    assert doc["baselines"] == [rig_doc()["baselines"][1]]
    parse_observations(doc)
