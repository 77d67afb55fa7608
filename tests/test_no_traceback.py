"""No traceback on any input: observations a solve cannot use are refused in one line, never by an exception.

Each defect first, as the inputs that showed it (an empty file, a stereo pair
that shares no track within the newest ones a long pool starts on, a camera
with a given K and no observation, a ring whose scale is undetermined), then
generated observations: 3 to 8 cameras of random sizes, a random stereo pair
and distance, any number of tracks (none too), cameras without views, given
K and fisheye lenses on some, tracks from one consistent scene mixed with
random pixels, duplicated and degenerate pixels. Each gives a calibration or
a one-line refusal with no Python repr in it, and no library warning.
Hypothesis runs derandomised and bounded, so that CI stays fast and a
failure reproduces.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camnet.errors import InputError, SolveError
from camnet.io.formats import observations_to_doc, parse_observations
from camnet.live.newest_first import solve_newest_first
from camnet.live.policy import soundness_check
from camnet.model.calibration import Calibration, CameraSigmas, Sigma, SolveReport, Uncertainty
from camnet.model.methods import Method
from camnet.model.projection import look_at, normalised, project
from camnet.model.two_view import row_and_epipolar_errors
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate
from camnet.solve.report.assemble import UNDETERMINED_SCALE, refuse_undetermined, refuse_wrong_start
from camnet.solve.uncertainty import scale_gradient
from tests._groundtruth import DATA_ROOT, require

REPR_FRAGMENTS = ("['", "[\"", "np.float64", "array(", "None", "{'", "Traceback")
SOLVE_EXAMPLES = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow])


def assert_one_line(message: str) -> None:
    """A message as the user reads it: one line, no Python repr."""
    assert message and "\n" not in message, message
    for fragment in REPR_FRAGMENTS:
        assert fragment not in message, (fragment, message)


def solved_or_refused(obs) -> Calibration | str:
    """The calibration of `obs`, or the message it is refused with; fails the test on any other exception or on
    a warning."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            outcome = calibrate(obs).calibration
        except (SolveError, InputError) as exc:
            outcome = str(exc)
    assert not caught, [f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})" for w in caught]
    if isinstance(outcome, str):
        assert_one_line(outcome)
    else:
        assert isinstance(outcome, Calibration)
    return outcome


def run_calibrate(path: Path, tmp_path: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet", "calibrate", str(path), "-o", str(tmp_path / "cal.json")],
                          capture_output=True, text=True, timeout=300)


def assert_clean_exit(done: subprocess.CompletedProcess) -> None:
    """`camnet calibrate` solved (0) or refused in one line (2); never a traceback nor a library warning."""
    assert done.returncode in (0, 2), done.stderr
    assert "Traceback" not in done.stderr and "Warning:" not in done.stderr, done.stderr
    if done.returncode == 2:
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("camnet calibrate: error: "), done.stderr
        assert_one_line(lines[0])


# ---------------------------------------------------------------- each defect


def three_cameras_doc(tracks: list) -> dict:
    return {"format": "camnet.observations/1",
            "cameras": [{"id": c, "width": 640, "height": 480} for c in ("a", "b", "c")],
            "stereo": {"left": "a", "right": "b", "baseline_m": 0.2},
            "tracks": tracks}


def test_empty_tracks_are_refused_in_one_line(tmp_path):
    path = tmp_path / "obs.json"
    path.write_text(json.dumps(three_cameras_doc([])))

    done = run_calibrate(path, tmp_path)

    assert done.returncode == 2, done.stderr
    assert_clean_exit(done)
    assert "shares only 0 tracks" in done.stderr
    assert not (tmp_path / "cal.json").exists()


@pytest.mark.parametrize("rows", [
    np.zeros((0, 2, 2)),  # no match
    np.array([[[10.0, 5.0], [30.0, 7.0]]]),  # one
    np.array([[[10.0, 5.0], [30.0, 7.0]]] * 12),  # one, twelve times: a single row
    np.array([[[10.0 + k, 5.0], [30.0, 7.0 + k]] for k in range(12)]),  # all on one row of the first view
    np.array([[[np.nan, np.nan], [30.0, 7.0 + k]] for k in range(12)]),  # undistorted beyond a fisheye's field
])
def test_the_row_fit_of_matches_that_fix_no_line_says_so(rows):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows_px, epipolar_px = row_and_epipolar_errors(rows[:, 0], rows[:, 1], threshold_px=8.0)
    assert not caught, [str(w.message) for w in caught]
    assert rows_px == np.inf and epipolar_px == np.inf


def test_the_undistortion_of_no_pixel_is_no_pixel():
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    for fisheye, dist in ((False, [0.1, -0.05, 0, 0, 0]), (True, [0.1, 0.01, 0.0, 0.0])):
        assert normalised(np.zeros((0, 2)), K=K, dist=np.array(dist), fisheye=fisheye).shape == (0, 2)


def sim_observations(seed: int = 5, n_points: int = 80):
    return observe(make_rig(n_cameras=5, n_points=n_points, seed=seed), noise_px=0.3, seed=seed).observations


def test_a_long_pool_whose_newest_tracks_the_stereo_pair_does_not_share_is_solved_whole():
    """A long pool starts on its newest tracks: where the stereo pair sees none of those together, that start is
    refused and the whole pool solved (a courtyard's 5 m pair, matched over 19 views, showed it)."""
    obs = sim_observations(n_points=120)
    newest = obs.track_ids[obs.track_index] >= 60
    by_pair = np.isin(obs.cam_index, [obs.index_of(obs.stereo.left), obs.index_of(obs.stereo.right)])
    keep = ~(newest & by_pair)
    obs = replace(obs, cam_index=obs.cam_index[keep], track_index=obs.track_index[keep], uv=obs.uv[keep])

    judged = solve_newest_first(obs, Options(), soundness_check, start_tracks=60)

    assert judged.calibration is not None, judged.reason
    assert {c.id for c in judged.calibration.cameras} == set(obs.camera_ids)


def test_a_camera_with_a_given_k_and_no_observation_is_left_out_by_name():
    rig = make_rig(n_cameras=5, n_points=80, seed=3)
    obs = observe(rig, noise_px=0.3, seed=3, with_intrinsics=True).observations
    doc = observations_to_doc(obs)
    for camera in doc["cameras"]:
        camera["fixed"] = ["K", "dist"]
    lonely = doc["cameras"][4]["id"]
    for track in doc["tracks"]:
        track["observations"].pop(lonely, None)

    outcome = solved_or_refused(parse_observations(doc))

    assert isinstance(outcome, Calibration), outcome
    assert lonely not in {c.id for c in outcome.cameras}
    assert "no observations" in outcome.report.cameras_left_out[lonely]
    assert any(w.startswith(f"camera {lonely} left out: it has no observations") for w in outcome.report.warnings)


def test_too_few_cameras_with_observations_are_refused_naming_those_without():
    obs = sim_observations()
    pair = [obs.index_of(obs.stereo.left), obs.index_of(obs.stereo.right)]
    keep = np.isin(obs.cam_index, pair)
    obs = replace(obs, cam_index=obs.cam_index[keep], track_index=obs.track_index[keep], uv=obs.uv[keep])
    others = [c.id for i, c in enumerate(obs.cameras) if i not in pair]

    message = solved_or_refused(obs)

    assert message == (f"cameras: {', '.join(others[:-1])} and {others[-1]} have no observations, which leaves 2; "
                       "a metric solve needs at least 3 (eq. 15): give every camera a view of what the others see")


def test_an_undetermined_scale_is_refused_naming_the_cameras_in_words():
    """The refusal names the cameras whose parameters nothing fixes, and nothing else (the warning that the scale
    is not determined is none of them)."""
    fixed = CameraSigmas(2.0, 1.0, 1.0, 0.0, 0.0, (0.01, 0.01, 0.01), (0.001, 0.001, 0.001))
    loose = replace(fixed, f_px=np.inf)
    uncertainty = Uncertainty(sigma_px=0.5, scale_rel=Sigma.unknown(UNDETERMINED_SCALE),
                              scale_rel_if_pp_exact=Sigma.unknown("no principal point was guessed"),
                              cameras={"a": fixed, "b": loose, "c": loose}, point_weights=None)
    warned = ("camera b: f_px not determined by the observations (sigma null); give them (K, dist) or add views "
              "that share more points with it",
              "camera c: f_px not determined by the observations (sigma null); give them (K, dist) or add views "
              "that share more points with it",
              "the scale is not determined by the observations and the known distances")
    report = SolveReport(Method.REFINED, True, "converged", 3, 100, 90, {}, None, None, (), warned, None, None, {},
                         uncertainty=uncertainty)

    with pytest.raises(SolveError) as refused:
        refuse_undetermined(report)

    assert str(refused.value).startswith("the observations do not determine the scale (nor cameras b and c): ")
    assert_one_line(str(refused.value))


def test_a_start_gone_wrong_asks_for_the_pairs_k_only_where_it_was_not_given():
    report = SolveReport(Method.REFINED, True, "converged", 3, 100, 60, {}, None, None, (), (), None, None, {},
                         cameras_left_out={"d": "no consistent pose", "e": "no consistent pose"})
    for K_given in (False, True):
        with pytest.raises(SolveError) as refused:
            refuse_wrong_start(report, 1.5, pair_K_given=K_given)
        assert str(refused.value).startswith("start: cameras d and e could not be placed"), refused.value
        assert ("give the stereo pair's K" in str(refused.value)) != K_given, refused.value


@pytest.mark.parametrize(("points", "weights"), [
    (np.array([[0.1, 0.2, 1.5]]), None),  # one point
    (np.array([[0.1, 0.2, 1.5]] * 3), None),  # three at one place
    (np.array([[0.1, 0.2, 1.5], [0.3, 0.2, 1.5]]), np.zeros(2)),  # none weighs
])
def test_a_cloud_without_extent_has_no_scale_and_says_so_without_a_warning(points, weights):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gradient = scale_gradient(points, weights)
    assert not caught, [str(w.message) for w in caught]
    assert gradient.shape == points.shape and np.isnan(gradient).all()


@pytest.mark.parametrize("frame", ["f0005", "f0042"])
def test_webcams_with_every_k_given_and_one_camera_unseen_leave_it_out_by_name(frame, tmp_path):
    """Four webcams round a room, every K given: at these instants no match reaches one camera."""
    root = require(DATA_ROOT / "webcams4_person_board")
    truth = json.loads((root / "truth.json").read_text())
    rig = ["rig: webcams", "stereo: {left: cam_0, right: cam_2, baseline_m: 0.485627}", "cameras:"]
    for camera in truth["cameras"]:
        rig += [f"- id: {camera['id']}",
                f"  intrinsics: {{K: {json.dumps(camera['K'])}, dist: {json.dumps(camera['dist'])}}}"]
    (tmp_path / "rig.yaml").write_text("\n".join(rig) + "\n")
    images = sorted(str(p) for p in (root / "frames" / frame).glob("cam_*.png"))
    matched = subprocess.run([sys.executable, "-m", "camnet", "match", "--rig", str(tmp_path / "rig.yaml"),
                              "-o", str(tmp_path / "obs.json"), *images], capture_output=True, text=True, timeout=300)
    assert matched.returncode == 0, matched.stderr
    doc = json.loads((tmp_path / "obs.json").read_text())
    unseen = {c["id"] for c in doc["cameras"]} - {cam for t in doc["tracks"] for cam in t["observations"]}
    assert len(unseen) == 1, unseen

    done = run_calibrate(tmp_path / "obs.json", tmp_path)

    assert_clean_exit(done)
    cam_id = unseen.pop()
    if done.returncode == 0:
        assert f"camera {cam_id} left out: it has no observations" in done.stderr, done.stderr
        cal = json.loads((tmp_path / "cal.json").read_text())
        assert cam_id not in {c["id"] for c in cal["cameras"]}


# ---------------------------------------------------------------- generated observations


@dataclass(frozen=True)
class Spec:
    """What a generated observations document holds (the numbers come from `seed`)."""

    n_cameras: int
    pair: tuple[int, int]
    parallel_pair: bool  # the right stereo camera beside the left, looking the same way
    baseline_true: bool  # the known distance is the pair's true one (else any)
    geometric_tracks: int  # projections of one scene's points
    random_tracks: int  # random pixels in random cameras
    unseen: frozenset[int]  # cameras without any observation (the stereo pair's have some)
    given_K: frozenset[int]
    fixed_K: bool
    fisheye: frozenset[int]
    duplicates: int  # tracks that repeat another's pixels
    flat_camera: int | None  # a camera all of whose pixels lie on one row
    seed: int


@st.composite
def specs(draw) -> Spec:
    n = draw(st.integers(3, 8))
    cameras = st.frozensets(st.integers(0, n - 1), max_size=n)
    pair = tuple(draw(st.lists(st.integers(0, n - 1), min_size=2, max_size=2, unique=True)))
    return Spec(
        n_cameras=n, pair=pair, parallel_pair=draw(st.booleans()), baseline_true=draw(st.booleans()),
        geometric_tracks=draw(st.sampled_from([0, 4, 12, 40, 80, 80])), random_tracks=draw(st.integers(0, 25)),
        unseen=draw(st.frozensets(st.integers(0, n - 1).filter(lambda i: i not in pair), max_size=2)),
        given_K=draw(cameras),
        fixed_K=draw(st.booleans()), fisheye=draw(st.frozensets(st.integers(0, n - 1), max_size=2)),
        duplicates=draw(st.integers(0, 5)), flat_camera=draw(st.none() | st.integers(0, n - 1)),
        seed=draw(st.integers(0, 2**16)),
    )


def generated_doc(spec: Spec) -> dict:
    """A camnet.observations/1 document as `spec` says: cameras round a scene of points, some of them a
    parallel stereo head, their projections mixed with random pixels."""
    rng = np.random.default_rng(spec.seed)
    n = spec.n_cameras
    sizes = [(int(rng.integers(160, 4096)), int(rng.integers(120, 3072))) for _ in range(n)]
    focal = [w * rng.uniform(0.5, 1.6) for w, _ in sizes]
    scene_m = rng.uniform(0.3, 30.0)  # the scene's distance from the cameras
    points = rng.normal(scale=0.2 * scene_m, size=(max(spec.geometric_tracks, 1), 3))
    poses = []
    for _ in range(n):
        angle = rng.uniform(-0.9, 0.9)
        centre = scene_m * np.array([np.sin(angle), rng.uniform(-0.2, 0.2), -np.cos(angle)])
        poses.append(look_at(centre, rng.normal(scale=0.05 * scene_m, size=3)))
    left, right = spec.pair
    true_baseline = rng.uniform(0.02, 0.5) * scene_m
    if spec.parallel_pair:
        R, t = poses[left]
        poses[right] = (R, t - np.array([true_baseline, 0.0, 0.0]))
    else:
        true_baseline = float(np.linalg.norm(-poses[left][0].T @ poses[left][1] + poses[right][0].T @ poses[right][1]))
    cameras, pixels = [], np.full((len(points), n, 2), np.nan)
    for i, ((w, h), f, (R, t)) in enumerate(zip(sizes, focal, poses, strict=True)):
        K = np.array([[f, 0.0, (w - 1) / 2 + rng.normal(scale=0.02 * w)],
                      [0.0, f * rng.uniform(0.98, 1.02), (h - 1) / 2 + rng.normal(scale=0.02 * h)], [0.0, 0.0, 1.0]])
        camera = {"id": f"cam{i}", "width": w, "height": h}
        fish = i in spec.fisheye
        dist = rng.normal(scale=0.02, size=4) if fish else np.zeros(5)
        if fish:
            camera["model"] = "fisheye"
        if i in spec.given_K:
            camera["K"] = K.tolist()
            if fish:
                camera["dist"] = dist.tolist()
            if spec.fixed_K:
                camera["fixed"] = ["K", "dist"] if fish else ["K"]
        cameras.append(camera)
        uv = project(points, K=K, dist=dist, R=R, t=t, fisheye=fish)
        inside = np.all(np.isfinite(uv), axis=1) & np.all((uv > -0.5) & (uv < np.array([w, h]) - 0.5), axis=1)
        pixels[inside, i] = uv[inside] + rng.normal(scale=0.5, size=(int(inside.sum()), 2))
        pixels[inside, i] = np.clip(pixels[inside, i], -0.5, np.array([w, h]) - 0.5)
    pixels = pixels[: spec.geometric_tracks]
    noise = np.full((spec.random_tracks, n, 2), np.nan)
    for track in noise:
        seen = rng.choice(n, int(rng.integers(1, n + 1)), replace=False)
        track[seen] = rng.uniform(0, 1, size=(len(seen), 2)) * (np.array(sizes)[seen] - 1)
    pixels = np.concatenate([pixels, noise])
    if len(pixels) and spec.duplicates:
        pixels = np.concatenate([pixels, pixels[rng.integers(0, len(pixels), spec.duplicates)]])
    if spec.flat_camera is not None:
        pixels[:, spec.flat_camera, 1] = np.where(np.isfinite(pixels[:, spec.flat_camera, 1]),
                                                  sizes[spec.flat_camera][1] / 2, np.nan)
    for i in spec.unseen:
        pixels[:, i] = np.nan
    tracks = []
    for k, track in enumerate(pixels):
        seen = np.flatnonzero(np.isfinite(track[:, 0]))
        tracks.append({"id": k, "observations": {f"cam{i}": track[i].tolist() for i in seen}})
    baseline_m = true_baseline if spec.baseline_true else float(rng.uniform(0.01, 20.0))
    return {"format": "camnet.observations/1", "cameras": cameras,
            "stereo": {"left": f"cam{left}", "right": f"cam{right}", "baseline_m": baseline_m}, "tracks": tracks}


@SOLVE_EXAMPLES
@given(specs())
def test_generated_observations_are_solved_or_refused_in_one_line(spec):
    try:
        obs = parse_observations(generated_doc(spec))
    except InputError as exc:
        assert_one_line(str(exc))
        return
    solved_or_refused(obs)


# Fixed specs the command line runs: no track; a parallel pair with K given and a fisheye camera, its K and
# lens given, never seen (solved); two fisheye cameras among six, K nowhere given, random pixels mixed in (refused).
CLI_SPECS = (
    Spec(3, (0, 1), True, True, 0, 0, frozenset(), frozenset(), False, frozenset(), 0, None, 1),
    Spec(5, (1, 3), True, True, 80, 5, frozenset({4}), frozenset({1, 3, 4}), True, frozenset({4}), 2, None, 1),
    Spec(6, (2, 5), False, True, 40, 10, frozenset(), frozenset(), False, frozenset({0, 1}), 0, None, 5),
)


@pytest.mark.parametrize("spec", CLI_SPECS, ids=["no_track", "unseen_fisheye", "fisheyes_and_noise"])
def test_camnet_calibrate_on_generated_files_exits_cleanly(spec, tmp_path):
    path = tmp_path / "obs.json"
    path.write_text(json.dumps(generated_doc(spec)))

    done = run_calibrate(path, tmp_path)

    assert_clean_exit(done)
    assert (tmp_path / "cal.json").exists() == (done.returncode == 0)
