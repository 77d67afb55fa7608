"""The HTML report: its numbers against independent computations, its sections, and a
screenshot of it rendered by headless Chromium."""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
from dataclasses import replace

import cv2
import numpy as np
import pytest

from camnet.errors import InputError
from camnet.io.formats import calibration_to_doc, observations_to_doc, parse_calibration
from camnet.io.report import SECTIONS, render_report
from camnet.io.report_plots import bounding_box, frustum_xz
from camnet.model.accuracy import compare_cameras
from camnet.model.camera import CameraInfo
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate
from camnet.solve.report.reprojection import reprojection_residuals
from camnet.solve.report.verdict import judge

# matplotlib's tab10 colours of cameras 0..3 (BGR, as cv2 reads the screenshot).
CAMERA_BGR = [(0xB4, 0x77, 0x1F), (0x0E, 0x7F, 0xFF), (0x2C, 0xA0, 0x2C), (0x28, 0x27, 0xD6)]


@pytest.fixture(scope="module")
def solved():
    """A refined solve of the paper's simulated rig with a few outliers: (calibration, observations)."""
    rig = make_rig(seed=2)
    obs = observe(rig, noise_px=0.5, seed=2, outlier_fraction=0.05).observations
    cal = calibrate(obs, Options()).calibration
    report = replace(cal.report, warnings=(*cal.report.warnings, "camera mono_b: a test warning <with markup>"))
    return replace(cal, report=report), obs


def test_bounding_box_is_the_extent_in_mm():
    points = np.random.default_rng(0).normal(size=(200, 3)) * [0.05, 0.08, 0.04] + [0.06, 0.0, 0.65]
    box = bounding_box(points)
    np.testing.assert_allclose(box.size_mm, 1e3 * (points.max(axis=0) - points.min(axis=0)))
    np.testing.assert_array_equal(box.min_m, points.min(axis=0))
    assert bounding_box(np.zeros((0, 3))) is None


def test_per_point_errors_match_opencv(solved):
    cal, obs = solved
    dropped = set(obs.track_ids.tolist()) - set(cal.point_ids.tolist())
    res = reprojection_residuals(cal, obs)
    assert res.dropped_observations == int(np.isin(obs.track_ids[obs.track_index], list(dropped)).sum())
    assert len(res.obs_row) + res.dropped_observations == len(obs.uv)
    for m, cam in enumerate(cal.cameras):
        mine = res.cam_index == m
        rvec, _ = cv2.Rodrigues(cam.R)
        X = cal.points[res.point_index[mine]]
        uv, _ = cv2.projectPoints(X.reshape(-1, 1, 3), rvec, cam.t, cam.K, cam.dist)
        expected = np.linalg.norm(uv.reshape(-1, 2) - obs.uv[res.obs_row[mine]], axis=1)
        np.testing.assert_allclose(res.error_px[mine], expected, atol=1e-6)
        # The rows pair each observation with its own track's point and its own camera.
        assert np.all(obs.cameras[obs.cam_index[res.obs_row[mine]][0]].id == cam.id)
        tracks = obs.track_ids[obs.track_index[res.obs_row[mine]]]
        np.testing.assert_array_equal(cal.point_ids[res.point_index[mine]], tracks)
    # The inliers' RMS is the calibration's.
    inl = res.error_px[res.error_px < 4.0]
    assert np.sqrt(np.mean(inl**2)) == pytest.approx(cal.rms_reprojection_px, rel=0.05)


def test_residuals_reject_a_camera_the_calibration_lacks(solved):
    cal, obs = solved
    ghost = replace(obs, cameras=(*obs.cameras[:-1], CameraInfo("ghost", 1280, 1024)))
    with pytest.raises(InputError, match="camera 'ghost' is not in the calibration"):
        reprojection_residuals(cal, ghost)


def test_frustum_edges_follow_the_field_of_view():
    rig = make_rig(seed=0)
    left = rig.cameras[0]
    depth = 0.3
    c, edge_l, edge_r = frustum_xz(left, depth)
    np.testing.assert_allclose(c, [0.0, 0.0], atol=1e-12)
    f, cx = left.K[0, 0], left.K[0, 2]
    np.testing.assert_allclose(edge_l, [(-0.5 - cx) / f * depth, depth], atol=1e-9)
    np.testing.assert_allclose(edge_r, [(left.width - 0.5 - cx) / f * depth, depth], atol=1e-9)
    # A turned camera: its frustum's axis points where its optical axis does, from its centre.
    mono = rig.cameras[2]
    c, edge_l, edge_r = frustum_xz(mono, depth)
    np.testing.assert_allclose(c, mono.centre[[0, 2]], atol=1e-12)
    axis = (edge_l + edge_r) / 2 - c
    optical = mono.R[2, [0, 2]]
    assert np.dot(axis, optical) / np.linalg.norm(axis) / np.linalg.norm(optical) > 0.999


def test_html_holds_every_section_and_the_numbers(solved):
    cal, obs = solved
    page = render_report(cal, obs)
    for key, title in SECTIONS.items():
        assert (f'<section id="{key}"><h2>{title}</h2>' in page) == (key != "truth")  # no truth given
    assert page.count("<svg") == 5  # per-point errors, histograms, uncertainty, bounding box, layout
    assert not re.search(r'(src|href)="(?!#)|<link|<script|@import', page)  # self-contained: nothing to fetch
    for cam in cal.cameras:
        assert f"<td>{cam.id}</td>" in page
        assert f'<td class="num">{cam.K[0, 0]:.1f}</td>' in page
        assert f'<td class="num">{cal.uncertainty.cameras[cam.id].f_px:.2f}</td>' in page
        kept = np.isin(obs.track_ids[obs.track_index], cal.point_ids)
        assert f"{cam.id}: {int(np.sum(kept & (obs.cam_index == obs.index_of(cam.id))))} observations" in page
    sx, sy, sz = 1e3 * np.subtract(*np.percentile(cal.points, [99, 1], axis=0))  # the cloud's body
    assert f"{sx:.1f} mm x {sy:.1f} mm x {sz:.1f} mm" in page
    for size in 1e3 * np.ptp(cal.points, axis=0):  # and every point's extent beside it
        assert f'<td class="num">{size:.1f}</td>' in page
    assert f'<td class="num">{cal.rms_reprojection_px:.3f}</td>' in page
    assert f'<td class="num">{100 * cal.uncertainty.scale_rel.value:.4f}</td>' in page
    assert "a test warning &lt;with markup&gt;" in page

    without = render_report(cal)
    assert without.count("<svg") == 3 and without.count("--observations OBS.json") == 2
    bare = replace(cal, report=None)
    assert "holds no uncertainty" in render_report(bare) and '<p class="note">None.</p>' in render_report(bare)


def test_the_verdict_is_a_banner_first_and_the_convergence_plain_words(solved):
    cal, obs = solved
    page = render_report(cal, obs)
    body = page[page.index("</h1>") + len("</h1>"):].lstrip()
    level = judge(cal).level.value
    assert body.startswith(f'<div id="banner" class="banner banner-{level}"><p><span class="level">Verdict: {level}.'
                           "</span> "), body[:300]
    banner = body[:body.index("</div>")]
    assert "<section" not in banner and page.index("</div>") < page.index("<section")
    assert "<p>The solve converged: another step would lower the cost by less than 1e-06 of it.</p>" in banner
    for jargon in ("ftol", "Gauss-Newton"):
        assert jargon not in page
    stopped = replace(cal, report=replace(cal.report, converged=False, reason="reached the iteration limit"))
    assert "<p>The solve did not converge: reached the iteration limit.</p>" in render_report(stopped)
    bare = render_report(replace(cal, report=None))
    assert '<div id="banner" class="banner banner-none"><p>Nothing was solved: no verdict.</p>' in bare


def test_a_simulated_rigs_report_holds_its_errors_against_the_truth(solved):
    cal, obs = solved
    truth = list(make_rig(seed=2).cameras)  # the rig the fixture solved, in the left camera's frame
    page = render_report(cal, obs, truth=truth)
    c = compare_cameras(cal, truth)
    section = page[page.index('<section id="truth">'):]
    section = section[:section.index("</section>")]
    for e in c.cameras:
        assert (f'<tr><td>{e.id}</td><td class="num">{100 * e.focal_rel:.3f}</td><td class="num">'
                f'{100 * e.focal_sigma_rel:.3f}</td><td class="num">{e.centre_mm:.2f}</td>') in section
    assert f"The scale is off by <b>{100 * c.scale_rel:+.4f}%</b>" in section
    banner = page[page.index('<div id="banner"'):page.index("</div>")]
    assert f"Against the simulation's ground truth: the scale is off by {100 * c.scale_rel:+.3f}%" in banner
    assert f"camera centres by at most {max(e.centre_mm for e in c.cameras):.1f} mm" in banner
    other = [replace(cam, id=f"other_{cam.id}") for cam in truth]
    with pytest.raises(InputError, match="the ground truth has no camera left, mono_a, mono_b, right of the calib"):
        render_report(cal, truth=other)


def test_text_cells_are_left_aligned_and_numbers_right_aligned(solved):
    cal, obs = solved
    page = render_report(cal, obs, truth=list(make_rig(seed=2).cameras))
    cells = re.findall(r'<td( class="num")?>(.*?)</td>', page)
    ids = {cam.id for cam in cal.cameras}
    assert {text for num, text in cells if text in ids and not num} == ids  # camera ids: text, whatever they read
    assert not [text for num, text in cells if text in ids and num]
    number = re.compile(r"[-+]?\d+(\.\d+)?")
    for num, text in cells:
        if number.fullmatch(text):  # a number alone in its cell
            assert num, f"the number {text} is not right-aligned"
        elif re.fullmatch(r"[a-z][a-z ,'()]*", text) and text not in ("given", "n/a", "not determined"):
            assert not num, f"the text {text!r} is right-aligned"


def test_further_keys_are_checked(solved):
    cal, _ = solved
    for keys, value, message in [
        (["uncertainty"], 5, "uncertainty: expected an object"),
        (["uncertainty", "sigma_px"], "0.5", "uncertainty.sigma_px: expected a number"),
        (["diagnostics", "warnings"], "none", "diagnostics.warnings: expected a list"),
        (["uncertainty", "cameras", "left", "f_px"], [1], "uncertainty.cameras.left.f_px"),
    ]:
        doc = calibration_to_doc(cal)
        inner = doc
        for key in keys[:-1]:
            inner = inner[key]
        inner[keys[-1]] = value
        with pytest.raises(InputError, match=re.escape(message)):
            render_report(parse_calibration(doc))
    doc = calibration_to_doc(cal)
    fk = parse_calibration(doc).report
    assert fk.uncertainty.sigma_px == doc["uncertainty"]["sigma_px"] and fk.method == "refined"
    assert list(fk.uncertainty.cameras["mono_a"].centre_m) == doc["uncertainty"]["cameras"]["mono_a"]["centre_m"]


def run_camnet(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet", *args], capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def report_files(solved, tmp_path_factory):
    cal, obs = solved
    root = tmp_path_factory.mktemp("report")
    (root / "cal.json").write_text(json.dumps(calibration_to_doc(cal)))
    (root / "obs.json").write_text(json.dumps(observations_to_doc(obs)))
    proc = run_camnet("report", str(root / "cal.json"), "--observations", str(root / "obs.json"), "-o", str(root))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["output"] == str(root / "report.html")
    return root


def test_report_command_bad_input_is_one_line_and_writes_nothing(tmp_path, report_files):
    doc = json.loads((report_files / "cal.json").read_text())
    doc["cameras"][1]["R"][0][0] = 5.0
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps(doc))
    obs_doc = json.loads((report_files / "obs.json").read_text())
    obs_doc["cameras"][3]["id"] = "ghost"
    obs_doc["tracks"] = [
        {"id": t["id"], "observations": {("ghost" if k == "mono_b" else k): v for k, v in t["observations"].items()}}
        for t in obs_doc["tracks"]
    ]
    ghost = tmp_path / "ghost.json"
    ghost.write_text(json.dumps(obs_doc))
    doc = json.loads((report_files / "cal.json").read_text())
    doc["uncertainty"]["cameras"]["mono_a"]["centre_m"] = [0.1, 0.2]
    short = tmp_path / "short.json"
    short.write_text(json.dumps(doc))
    doc = json.loads((report_files / "cal.json").read_text())
    doc["cameras"] = doc["cameras"][:3]  # the truth of a rig without mono_b
    other = tmp_path / "other.json"
    other.write_text(json.dumps(doc))
    out = tmp_path / "report.html"
    for args, message in [
        ([str(report_files / "cal.json"), "--truth", str(other)], "the ground truth has no camera mono_b of the "),
        ([str(broken)], "cameras[1].R: not a rotation matrix"),
        ([str(report_files / "cal.json"), "--observations", str(ghost)], "camera 'ghost' is not in the calibration"),
        ([str(tmp_path / "absent.json")], "cannot read"),
        ([str(short)], "uncertainty.cameras.mono_a.centre_m: expected 3 numbers"),
    ]:
        proc = run_camnet("report", *args, "-o", str(out))
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.count("\n") == 1 and message in proc.stderr, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.json", "ghost.json", "other.json", "short.json"]


def screenshot(html_path, png_path, profile_dir, *, timeout_s: float = 120.0) -> None:
    """Render `html_path` with headless Chromium; its whole process group is stopped whatever happens."""
    chromium = shutil.which("chromium")
    args = [
        chromium,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        f"--user-data-dir={profile_dir}",
        "--window-size=1280,3600",
        f"--screenshot={png_path}",
        f"file://{html_path}",
    ]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout_s)
        assert proc.returncode == 0, out.decode(errors="replace")[-2000:]
    finally:
        # Chromium leaves helper processes behind its main one: stop the whole group.
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.mark.skipif(
    shutil.which("chromium") is None, reason="chromium is not installed (Debian: apt-get install chromium)"
)
def test_screenshot_in_headless_chromium_shows_the_plots(report_files, tmp_path):
    png = tmp_path / "report.png"
    screenshot(report_files / "report.html", png, tmp_path / "profile")
    image = cv2.imread(str(png))
    assert image is not None and image.shape[:2] == (3600, 1280)
    ink = np.any(image < 200, axis=2)
    rows = np.flatnonzero(ink.any(axis=1))
    assert rows.max() > 2500, "the page is shorter than its sections and plots"
    assert image.std() > 20 and 0.02 < ink.mean() < 0.6, "the screenshot is blank or flooded"
    colours = np.unique(image.reshape(-1, 3)[ink.ravel()] // 8, axis=0)
    assert len(colours) > 100, f"only {len(colours)} distinct colours"
    for m, bgr in enumerate(CAMERA_BGR):
        near = np.all(np.abs(image.astype(int) - bgr) <= 12, axis=2)
        assert near.sum() > 500, f"camera {m}'s plot colour is missing from the screenshot"
    text = (report_files / "report.html").read_text()
    assert re.search(r'<section id="layout">.*<svg', text, re.S)


def rendered_alignment(page: str, directory, *, timeout_s: float = 120.0) -> list[tuple[str, str]]:
    """(text, CSS text-align as Chromium computes it) of every table cell of `page`, rendered headless."""
    html_path = directory / "aligned.html"
    script = ("<script>for (const cell of document.querySelectorAll('td')) "
              "cell.setAttribute('data-align', getComputedStyle(cell).textAlign);</script>")
    html_path.write_text(page.replace("</body>", script + "</body>"))
    args = [shutil.which("chromium"), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            f"--user-data-dir={directory / 'profile'}", "--dump-dom", f"file://{html_path}"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        dom, _ = proc.communicate(timeout=timeout_s)
        assert proc.returncode == 0
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    cells = re.findall(r'<td[^>]*data-align="([a-z-]+)"[^>]*>(.*?)</td>', dom.decode())
    return [(re.sub(r"<[^>]+>", "", text), align) for align, text in cells]


@pytest.mark.skipif(
    shutil.which("chromium") is None, reason="chromium is not installed (Debian: apt-get install chromium)"
)
def test_chromium_shows_text_left_and_numbers_right(solved, tmp_path):
    cal, obs = solved
    cells = rendered_alignment(render_report(cal, obs, truth=list(make_rig(seed=2).cameras)), tmp_path)
    assert len(cells) > 100
    ids = {cam.id for cam in cal.cameras}
    number = re.compile(r"[-+]?\d+(\.\d+)?( / \d+)?")
    findings = {f.what for _, f in judge(cal).all_findings()}
    for text, align in cells:
        if text in ids or text in findings or text in ("good", "usable", "poor", "rig", "cameras", "X"):
            assert align == "left", (text, align)
        elif number.fullmatch(text):
            assert align == "right", (text, align)
