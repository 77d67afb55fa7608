"""Rerun visualization: real solves logged to an .rrd file and read back with Rerun's own reader."""

import argparse
import logging
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from camnet import viz, viz_sinks
from camnet.errors import InputError
from camnet.model.calibration import Calibration
from camnet.model.camera import Camera
from camnet.sim.simulate import make_rig, observe
from camnet.solve import calibrate

T0_NS = 1_700_000_000_000_000_000


def read_rrd(path) -> dict[str, dict[str, list]]:
    """entity path -> column -> values in solve order: one value per log call that logged the column."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    calls: dict[tuple, dict] = defaultdict(dict)
    for chunk in RrdReader(path).stream().collect().stream():
        batch = chunk.to_record_batch()
        # Times as integer nanoseconds: Python's datetime stops at microseconds.
        batch = {field.name: (column.cast(pa.int64()) if pa.types.is_timestamp(field.type) else column).to_pylist()
                 for field, column in zip(batch.schema, batch.columns, strict=True)}
        for i in range(chunk.num_rows):
            row = {name: values[i] for name, values in batch.items() if not name.startswith("rerun.controls")}
            # One log call can be split over chunks; its rows share every time.
            key = (chunk.entity_path, row.get("solve", -1), row.get("capture_time", 0), row.get("log_time", 0))
            calls[key].update({name: value for name, value in row.items() if value is not None})
    out: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for key in sorted(calls):
        for name, value in calls[key].items():
            out[key[0]][name].append(value)
    return out


@pytest.fixture(scope="module")
def solves():
    """Three real solves of one simulated rig (different noise), with observations and truth."""
    rig = make_rig(n_cameras=4, n_points=120, seed=5)
    runs = []
    for seed in range(3):
        obs = observe(rig, noise_px=0.5, seed=seed, visibility=0.7, outlier_fraction=0.05).observations
        runs.append((calibrate(obs).calibration, obs))
    truth = Calibration(tuple(rig.cameras), np.arange(len(rig.points)), rig.points, 0.0, "left")
    return rig, truth, runs


@pytest.fixture
def recording(tmp_path):
    path = tmp_path / "run.rrd"
    rec = viz.open_recording(rig="sim", sinks=[viz_sinks.parse_sink(f"save={path}")])
    try:
        yield rec, path
    finally:
        viz.close_recording(rec)


def test_saved_recording_holds_cameras_cloud_and_series(recording, solves):
    rec, path = recording
    rig, truth, runs = solves
    for k, (cal, obs) in enumerate(runs):
        viz.log_calibration(rec, cal, time_ns=T0_NS + k * 10**9, observations=obs, truth=truth)
    viz.close_recording(rec)
    data = read_rrd(path)

    n = len(runs)
    last_cal, last_obs = runs[-1]
    for cam in last_cal.cameras:
        entity = data[f"/world/cameras/{cam.id}"]
        assert entity["solve"] == list(range(n))
        assert len(entity["Transform3D:translation"]) == n and len(entity["Pinhole:image_from_camera"]) == n
        # world_from_cam: translation is the centre, rotation R^T; Rerun's matrices are column-major.
        np.testing.assert_allclose(entity["Transform3D:translation"][-1][0], cam.centre, atol=1e-6)
        np.testing.assert_allclose(np.reshape(entity["Transform3D:mat3x3"][-1][0], (3, 3)).T, cam.R.T, atol=1e-6)
        K_rerun = np.reshape(entity["Pinhole:image_from_camera"][-1][0], (3, 3)).T
        np.testing.assert_allclose(K_rerun, cam.K + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]], rtol=1e-6)
        np.testing.assert_allclose(entity["Pinhole:resolution"][-1][0], [cam.width, cam.height])
        observed = data[f"/world/cameras/{cam.id}/image/observations"]["Points2D:positions"]
        seen = last_obs.cam_index == last_obs.index_of(cam.id)
        np.testing.assert_allclose(observed[-1], last_obs.uv[seen] + 0.5, atol=1e-4)

    points = data["/world/points"]
    assert [len(p) for p in points["Points3D:positions"]] == [len(cal.points) for cal, _ in runs]
    assert len(points["Points3D:colors"][-1]) == len(last_cal.points)
    np.testing.assert_allclose(points["Points3D:positions"][-1], last_cal.points, atol=1e-6)

    series = data["/series/network/rms_px"]
    assert series["solve"] == list(range(n))
    np.testing.assert_allclose(np.ravel(series["Scalars:scalars"]), [cal.rms_reprojection_px for cal, _ in runs],
                               rtol=1e-6)
    assert series["capture_time"] == [T0_NS + k * 10**9 for k in range(n)]
    for name in ("rms_px", "sigma_f_px", "sigma_centre_mm", "focal_error_pct", "centre_error_mm"):
        for cam in last_cal.cameras:
            assert len(data[f"/series/{name}/{cam.id}"]["Scalars:scalars"]) == n, (name, cam.id)
    for name in ("points", "scale_sigma_pct", "scale_error_pct"):
        assert len(data[f"/series/network/{name}"]["Scalars:scalars"]) == n, name
    assert np.ravel(data["/series/network/points"]["Scalars:scalars"]).tolist() == [len(c.points) for c, _ in runs]
    assert "/world" in data  # the RDF view coordinates
    assert len(data["/log"]["TextLog:text"]) >= n


def test_residuals_and_colours_follow_the_observations(solves):
    _, _, runs = solves
    cal, obs = runs[0]
    residuals = viz.reprojection_errors(cal, obs)
    kept = np.isin(obs.track_ids[obs.track_index], cal.point_ids)
    assert np.all(np.isfinite(residuals.obs_error_px[kept])) and np.all(np.isnan(residuals.obs_error_px[~kept]))
    assert np.median(residuals.obs_error_px[kept]) < 1.5  # 0.5 px noise per axis
    assert len(residuals.point_rms_px) == len(cal.points)

    moved = obs.uv.copy()
    k = int(np.flatnonzero(kept)[0])
    moved[k, 0] += 30.0
    shifted = viz.reprojection_errors(cal, type(obs)(**{**obs.__dict__, "uv": moved}))
    assert shifted.obs_error_px[k] == pytest.approx(30.0, abs=2.0)

    colors = viz.error_colors(np.array([0.0, 1.0, 2.0, 50.0, np.nan]))
    assert colors.shape == (5, 3) and colors.dtype == np.uint8
    assert colors[0, 2] > colors[0, 0]  # low error: blue
    assert colors[2, 0] > colors[2, 2] and np.array_equal(colors[2], colors[3])  # range ends at 2 px
    assert tuple(colors[4]) == viz.REJECTED_RGB


def test_degenerate_and_failed_solves_are_text_not_cameras(recording, solves):
    rec, path = recording
    rig, _, runs = solves
    cal = runs[0][0]
    broken = Camera("left", 1280, 1024, np.full((3, 3), np.nan))
    bad = Calibration((broken, *cal.cameras[1:]), cal.point_ids, cal.points, 0.5, "left")
    viz.log_calibration(rec, bad, time_ns=T0_NS)
    viz.log_solve_failure(rec, "too few tracks", time_ns=T0_NS + 1)
    viz.log_calibration(rec, cal, time_ns=T0_NS + 2, truth=rig.cameras)
    viz.close_recording(rec)
    data = read_rrd(path)
    texts = [text for cell in data["/log"]["TextLog:text"] for text in cell]
    assert any("degenerate" in t and "'left'" in t for t in texts)
    assert any("solve 1 failed: too few tracks" in t for t in texts)
    assert data["/world/cameras/left"]["solve"] == [2]  # only the good solve shows cameras
    assert data["/series/network/scale_error_pct"]["solve"] == [2]  # truth as cameras alone
    assert data["/series/centre_error_mm/mono_a"]["solve"] == [2]


@pytest.mark.parametrize(
    "encoding, make",
    [
        ("mono8", lambda: np.tile(np.linspace(0, 255, 160).astype(np.uint8), (120, 1))),
        ("mono16", lambda: np.tile(np.arange(0, 4000, 25, dtype=np.uint16), (120, 1))),
        ("rgb8", lambda: np.dstack([np.full((120, 160), 220, np.uint8), np.zeros((120, 160, 2), np.uint8)])),
        ("bgr8", lambda: np.dstack([np.zeros((120, 160, 2), np.uint8), np.full((120, 160), 220, np.uint8)])),
        ("bayer_rggb8", lambda: np.tile(np.array([[220, 0], [0, 0]], np.uint8), (60, 80))),
    ],
)
def test_frames_arrive_as_jpeg_at_full_size(recording, encoding, make):
    import cv2

    rec, path = recording
    image = make()
    viz.log_frame(rec, "cam 1", image, time_ns=T0_NS, encoding=encoding)
    viz.close_recording(rec)
    blob = read_rrd(path)["/world/cameras/cam\\ 1/image"]["EncodedImage:blob"][-1]
    decoded = cv2.imdecode(np.asarray(blob[0], np.uint8), cv2.IMREAD_UNCHANGED)  # one blob: a list of bytes
    assert decoded.shape[:2] == image.shape[:2]
    if encoding in ("rgb8", "bgr8", "bayer_rggb8"):
        b, g, r = decoded[40:80, 40:120].reshape(-1, 3).mean(axis=0)
        assert r > 100 and r > 2 * g and r > 2 * b  # red stays red
    else:
        assert decoded[:, -1].mean() > 200 > 50 > decoded[:, 0].mean()  # mono16 stretched to 8 bits


def test_logging_failures_warn_once_and_never_raise(recording, caplog):
    rec, _ = recording
    viz._warned.clear()
    with caplog.at_level(logging.WARNING, logger="camnet.viz"):
        for _ in range(3):
            viz.log_frame(rec, "left", np.zeros((4, 4, 7), np.uint8), time_ns=T0_NS, encoding="rgb8")
    warnings = [r for r in caplog.records if "log_frame failed" in r.getMessage()]
    assert len(warnings) == 1


def test_no_sink_means_no_recording_and_no_rerun_import():
    code = (
        "import sys, numpy as np\n"
        "from camnet import viz\n"
        "rec = viz.open_recording(rig='sim', sinks=())\n"
        "viz.log_frame(rec, 'left', np.zeros((4, 4), np.uint8), time_ns=0)\n"
        "viz.close_recording(rec)\n"
        "assert rec is None and 'rerun' not in sys.modules, sorted(m for m in sys.modules if 'rerun' in m)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


@pytest.mark.parametrize(
    "value, expected",
    [
        ("spawn", viz_sinks.RerunSink("spawn")),
        ("connect", viz_sinks.RerunSink("connect", url="rerun+http://127.0.0.1:9876/proxy")),
        ("connect=rerun+http://10.0.0.5:9877/proxy", viz_sinks.RerunSink("connect", url="rerun+http://10.0.0.5:9877/proxy")),
        ("serve", viz_sinks.RerunSink("serve", web_port=9090, grpc_port=9876)),
        ("serve=8080", viz_sinks.RerunSink("serve", web_port=8080, grpc_port=9876)),
        ("serve=8080,8081", viz_sinks.RerunSink("serve", web_port=8080, grpc_port=8081)),
        ("save=run.rrd", viz_sinks.RerunSink("save", path="run.rrd")),
    ],
)
def test_sink_values_parse(value, expected):
    assert viz_sinks.parse_sink(value) == expected


@pytest.mark.parametrize(
    "value",
    ["", "show", "spawn=1", "connect=http://x:1/proxy", "connect=rerun+http://x:1", "serve=abc", "serve=0",
     "serve=70000", "serve=1,2,3", "serve=9000,9000", "save", "save=", "save=run.txt", "save=/no/such/dir/run.rrd"],
)
def test_bad_sink_values_name_the_flag(value):
    with pytest.raises(InputError, match="^--rerun"):
        viz_sinks.parse_sink(value)


def test_rerun_flag_is_repeatable_and_off_by_default(tmp_path):
    parser = argparse.ArgumentParser()
    viz_sinks.add_rerun_arguments(parser)
    assert viz_sinks.sinks_from_args(parser.parse_args([])) == ()
    args = parser.parse_args(["--rerun", "serve=8000,8001", "--rerun", f"save={tmp_path / 'a.rrd'}"])
    assert [s.kind for s in viz_sinks.sinks_from_args(args)] == ["serve", "save"]
    for clash in (["serve=8000,9876", "spawn"], [f"save={tmp_path / 'a.rrd'}"] * 2):
        with pytest.raises(InputError, match="same port or file"):
            viz_sinks.sinks_from_args(parser.parse_args([x for v in clash for x in ("--rerun", v)]))


def test_web_viewer_url_points_the_viewer_at_the_grpc_server():
    url = viz_sinks.web_viewer_url(host="rig-host", web_port=9090, grpc_port=9876)
    assert url == "http://rig-host:9090/?url=rerun%2Bhttp%3A%2F%2Frig-host%3A9876%2Fproxy"
    assert "rig-host:9090" in viz_sinks.RerunSink("serve").describe(host="rig-host")


def test_a_sink_that_cannot_open_is_a_clear_error():
    import socket

    from camnet.errors import CamnetError
    from tests.conftest import free_port

    with socket.socket() as busy:
        busy.bind(("0.0.0.0", 0))
        busy.listen()
        with pytest.raises(CamnetError, match="^--rerun serve: cannot open"):
            viz.open_recording(rig="sim", sinks=[viz_sinks.parse_sink(f"serve={free_port()},{busy.getsockname()[1]}")])


def test_the_solve_timeline_takes_the_calibrators_numbers(recording, solves):
    """Rerun's timeline carries the calibrator's solve numbers: numbered on its own from 0, skipping the failed
    solves, its 'solve 0' would be the calibrator's (and camnet up's) solve 1, drifting with every failure."""
    rec, path = recording
    rig, _, runs = solves
    viz.log_calibration(rec, runs[0][0], time_ns=T0_NS, solve_index=1)
    viz.log_solve_failure(rec, "rejected: too uncertain", time_ns=T0_NS + 1, solve_index=3)
    viz.log_calibration(rec, runs[1][0], time_ns=T0_NS + 2, truth=rig.cameras, solve_index=4)
    viz.close_recording(rec)
    data = read_rrd(path)
    assert data["/world/cameras/left"]["solve"] == [1, 4]
    texts = [text for cell in data["/log"]["TextLog:text"] for text in cell]
    assert any(t.startswith("solve 3 failed: rejected") for t in texts)
    assert any(t.startswith("solve 4: 4 cameras") for t in texts)


SERVE_SCRIPT = """
import sys
import numpy as np
import rerun as rr
from camnet import viz, viz_sinks

rec = viz.open_recording(rig="sim", sinks=[viz_sinks.parse_sink(sys.argv[1])])
rng = np.random.default_rng(0)
for i in range(int(sys.argv[2])):
    rec.set_time("solve", sequence=i)
    rec.log("blob", rr.Tensor(rng.integers(0, 256, 2**20, dtype=np.uint8)))  # 1 MiB that compresses to no less
rec.set_time("solve", sequence=int(sys.argv[2]))
rec.log("end", rr.TextLog("all logged"))  # the newest: a late viewer that holds it holds all it will get
rec.flush()
print("logged", flush=True)
sys.stdin.readline()
"""


def file_size(path: Path) -> int:
    return path.stat().st_size if path.exists() else 0


def entity_rows(path: Path, entity: str) -> int:
    """Rows of `entity` in the .rrd at `path` so far, while another process writes it (0 where it cannot be
    read yet). Entity paths and row counts only: decoding 16 MiB of tensors to Python takes half a minute
    on a loaded machine, this under a second."""
    import warnings

    from rerun.chunk import RrdReader

    if file_size(path) == 0:
        return 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no footer yet: the writer is still running
        try:
            return sum(chunk.num_rows for chunk in RrdReader(path).stream() if chunk.entity_path == entity)
        except Exception:  # noqa: BLE001  (a chunk half written: read again once it has grown)
            return 0


def test_a_served_recording_keeps_a_bounded_history_for_late_viewers(tmp_path):
    """Rerun's server keeps up to 1 GiB for viewers that connect later by default, and a served calibrator
    would grow by every solve into it (docs/benchmarks.md, "Sixteen cameras across hosts"). A late viewer
    (`rerun URL --save`) of 48 MiB logged
    gets the newest part of it: at most `SERVE_MEMORY_LIMIT` (16 MiB), and more than half of that."""
    from tests.conftest import free_port, wait_for

    logged_mib, grpc_port = 48, free_port()
    server = viewer = None
    saved = tmp_path / "late.rrd"
    try:
        server = subprocess.Popen([sys.executable, "-c", SERVE_SCRIPT, f"serve={free_port()},{grpc_port}",
                                   str(logged_mib)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert server.stdout.readline().strip() == "logged", "the serving process did not log its data"
        rerun = str(Path(sys.executable).with_name("rerun"))
        viewer = subprocess.Popen([rerun, f"rerun+http://127.0.0.1:{grpc_port}/proxy", "--save", str(saved)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # Done when the file holds the newest message logged; waited for while it grows.
        assert wait_for(lambda: entity_rows(saved, "/end") > 0, 60.0, 0.5, progress=lambda: file_size(saved),
                        limit_s=300.0), f"the late viewer's file never held the last message ({file_size(saved)} bytes)"
        size = file_size(saved)
    finally:
        for process in (viewer, server):
            if process is not None and process.poll() is None:
                process.kill()
                process.wait(10)
    mib, limit_mib = size / 2**20, int(viz.SERVE_MEMORY_LIMIT.removesuffix("MiB"))
    # The server drops whole messages, oldest first, and may hold one (1 MiB here) over its limit: a late
    # viewer got 14.1-17.1 MiB in 6 runs on a loaded machine. The file adds its own framing (about 1%).
    assert limit_mib / 2 < mib <= 1.05 * (limit_mib + 1), \
        f"a late viewer got {mib:.1f} MiB of the {logged_mib} MiB logged"
