"""Two calibrated sites placed in one metric space: floors coinciding, each site's front facing the other's."""

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from camnet.io.formats import calibration_to_doc
from camnet.io.meeting import parse_meeting
from camnet.model.calibration import in_world_frame
from camnet.solve.world_frame import floor_frame, world_frame
from tests.test_viz import read_rrd
from tests.test_world_frame import calibration, room


def site(seed: int):
    cameras, points, _ = room(seed)
    cal = calibration(cameras, points)
    return replace(cal, floor_frame=floor_frame(world_frame(cal, x_toward=("cam1", "cam2"))))


def camnet(*args, cwd):
    return subprocess.run([sys.executable, "-m", "camnet.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=120)


@pytest.fixture(scope="module")
def sites(tmp_path_factory):
    work = tmp_path_factory.mktemp("sites")
    a, b = site(1), site(2)
    for name, cal in (("studio.json", a), ("office.json", b)):
        (work / name).write_text(json.dumps(calibration_to_doc(cal)))
    return work, a, b


def test_two_sites_face_each_other_on_one_floor_at_the_distance_asked(sites):
    work, a, b = sites

    done = camnet("fuse", "studio.json", "office.json", "--layout", "facing:2.5m", "-o", "meeting.json",
                  "--rerun", "save=meeting.rrd", cwd=work)

    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    assert json.loads(done.stdout)["sites"] == ["studio", "office"]
    meeting = parse_meeting(json.loads((work / "meeting.json").read_text()))
    studio, office = meeting.sites
    assert (studio.name, office.name) == ("studio", "office")
    # Site A stands where its floor frame puts it: the meeting frame is its floor frame.
    np.testing.assert_allclose(studio.points(), in_world_frame(a).points, atol=1e-9)
    # Both floors at z = 0, every height kept: what stood 1.5 m over a floor still does.
    np.testing.assert_allclose(office.points()[:, 2], in_world_frame(b).points[:, 2], atol=1e-9)
    for here, there, cal in ((studio, office, a), (office, studio, b)):
        posed = in_world_frame(cal)
        # A person at the site's origin looking toward its rig's front (+X of its floor frame) looks at the other
        # site's origin, 2.5 m away on the floor.
        origin = here.placement.t
        front = here.placement.R @ np.array([1.0, 0.0, 0.0])
        np.testing.assert_allclose(origin + 2.5 * front, there.placement.t, atol=1e-9)
        # Each camera keeps its pose relative to its own site: distances between its cameras are unchanged.
        centres = np.array([c.centre for c in here.cameras()])
        own = np.array([c.centre for c in posed.cameras])
        np.testing.assert_allclose(np.linalg.norm(centres - centres[0], axis=1),
                                   np.linalg.norm(own - own[0], axis=1), atol=1e-9)
    # Each site's cameras stand at its front, so the office's stand on the studio's side of the office's origin.
    assert all(c.centre[0] > 0.0 for c in studio.cameras()) and all(c.centre[0] < 2.5 for c in office.cameras())
    # Rerun: both rigs and clouds, to scale, Z up over one floor.
    data = read_rrd(work / "meeting.rrd")
    for s in (studio, office):
        for cam in s.cameras():
            np.testing.assert_allclose(data[f"/world/sites/{s.name}/cameras/{cam.id}"]["Transform3D:translation"][-1][0],
                                       cam.centre, atol=1e-5)
        np.testing.assert_allclose(data[f"/world/sites/{s.name}/points"]["Points3D:positions"][-1], s.points(),
                                   atol=1e-5)
    strips = np.array(data["/world/floor"]["LineStrips3D:strips"][-1])
    assert np.all(strips[..., 2] == 0.0) and strips[..., 0].max() > 2.5 + 1.0 and strips[..., 0].min() < -1.0


@pytest.mark.parametrize(("args", "said"), [
    (("--layout", "facing"), "--layout facing: expected facing:DISTANCE"),
    (("--layout", "facing:two"), "--layout facing:two: 'two' is not a distance in metres"),
    (("--layout", "facing:-1m"), "the distance must be positive"),
    (("--layout", "round:2m"), "--layout round:2m: expected facing:DISTANCE"),
    (("--layout", "facing:2m", "--names", "a,a"), "--names a,a: two different names are needed"),
])
def test_a_bad_layout_or_names_is_one_line_and_writes_nothing(sites, args, said):
    work, _, _ = sites

    done = camnet("fuse", "studio.json", "office.json", "-o", "bad.json", *args, cwd=work)

    assert done.returncode == 2 and said in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not (work / "bad.json").exists()


def test_a_site_without_a_floor_is_refused_saying_how_to_get_one(sites, tmp_path):
    _, a, b = sites
    (tmp_path / "left.json").write_text(json.dumps(calibration_to_doc(replace(a, floor_frame=None))))
    unfound = replace(b.floor_frame, normal_sigma_deg=None, height_sigma_m=None, reason="no plane below the cameras")
    (tmp_path / "unfound.json").write_text(json.dumps(calibration_to_doc(replace(b, floor_frame=unfound))))
    (tmp_path / "ok.json").write_text(json.dumps(calibration_to_doc(a)))

    for bad, said in (("left.json", "left.json: written in the left camera's frame, not a floor's: calibrate the "
                                    "site with `world: floor`"),
                      ("unfound.json", "unfound.json: its scene showed no floor (no plane below the cameras)")):
        done = camnet("fuse", "ok.json", bad, "--layout", "facing:2m", "-o", "out.json", cwd=tmp_path)
        assert done.returncode == 2 and said in done.stderr, done.stderr
        assert len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert not (tmp_path / "out.json").exists()
