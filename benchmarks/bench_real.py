"""Every real data set in ../shared/data through the user's commands, against its reference: right, refused,
poor and wrong, or wrong in silence.

Each frame set of a scene (one image per camera taken at one instant: a
KITTI trigger, the temple ring's sixteen views, one instant of the webcams
recording) goes through `camnet match IMAGES --rig RIG.yaml -o obs.json`
then `camnet calibrate obs.json -o cal.json --json`, run as the commands
themselves, twice: `none`, nothing known but the known pair's distance,
and `K`, the known pair's K (and distortion where the reference has any
other than none) in the rig file's `intrinsics`. A recording (KITTI's four
triggers, the webcams' 48 frames, the fisheye rig's three instants) also
goes through `camnet up RIG.yaml --until-frame-sets N`: one v4l2 driver per
camera replays its frames with their capture times, the matcher pools the
frame sets, and the run ends at the first calibration from N of them.

Each calibration is compared with the reference (`camnet.datasets.sigma_check`):
the scale (the similarity of the camera centres), every focal length and
every rotation beside its reported 1 sigma, and the verdict; a run is
`right` (within 3 sigma everywhere), `refused` (exit 2 with a reason),
`poor and wrong`, `WRONG IN SILENCE` (good or usable, yet beyond 3 sigma) or
`CRASH` (a traceback). Every calibration is written in the floor's frame
(`world: floor`), and where the scene showed a floor its normal counts among
what must lie within 3 sigma: against the normal of the plane the
reference's camera centres lie in, where they lie in one. Progress goes to stderr; the tables, Markdown, to
stdout.

    python benchmarks/bench_real.py [--scenes kitti,temple,fountain,castle,webcams4,fisheye] [--known none,K]
        [--up-runs N] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

from camnet.datasets import kitti, strecha, temple
from camnet.datasets.caliscope import read_frame_times, read_video
from camnet.datasets.sigma_check import (
    K_SIGMAS,
    TRACEBACK,
    Check,
    Outcome,
    check_calibration,
    classify,
    error_line,
)
from camnet.datasets.truth_json import read_truth
from camnet.io.formats import load_json, parse_calibration
from camnet.io.image_sequence import TIMESTAMPS, kitti_stamp
from camnet.model.camera import Camera, LensModel
from camnet.testing.ports import free_port

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
KNOWN = ("none", "K")
COMMAND_TIMEOUT_S = 3600.0  # a command that has not ended by then is taken for hung


@dataclass(frozen=True)
class Recording:
    """How `camnet up` replays a scene: each camera's v4l2 section (written by `drivers` into a work folder),
    the rig's `sync` section, and when the run ends."""

    drivers: Callable[[Path], dict[str, dict]]
    sync: dict
    until_frame_sets: int
    duration_s: float
    how: str  # in words, for the tables


@dataclass(frozen=True)
class Scene:
    name: str
    reference: dict[str, Camera]  # the data set's world frame
    left: str  # the known pair
    right: str
    frame_sets: dict[str, dict[str, Path]]  # name -> camera id -> image: one `camnet match` each
    parallel: bool = False  # the known pair is a parallel head
    recording: Recording | None = None
    note: str = ""  # what the reference is good to, what is hard

    @property
    def baseline_m(self) -> float:
        """The known distance: the reference's centre distance of the pair."""
        return float(np.linalg.norm(self.reference[self.right].centre - self.reference[self.left].centre))


# --- The scenes -------------------------------------------------------------------------------------------------

def kitti_scene(root: Path) -> Scene:
    extract = kitti.KittiExtract.open(root)

    def drivers(_: Path) -> dict[str, dict]:
        # As config/kitti.yaml: cam 2 has no timestamps of its own and fired at cam 0's trigger.
        return {c: {"source": str(root / f"image_0{c}" / "data" / "*.png"),
                    "timestamps": str(root / f"image_0{'0' if c == '2' else c}" / "timestamps.txt"),
                    "frame_range": [1, 16], "speed": 0.15, "loop": True,
                    "encoding": "mono8" if c in ("0", "1") else "bgr8"} for c in extract.cameras}

    return Scene(
        "kitti", extract.cameras, kitti.STEREO_LEFT, kitti.STEREO_RIGHT,
        {f.name: f.images for f in extract.frames()}, parallel=True,
        recording=Recording(drivers, {"tolerance_ms": 10, "max_wait_s": 2}, until_frame_sets=4, duration_s=300,
                            how="the 4 triggers' images with their timestamps, 0.15x their pace, looped"),
        note="the car moves 3-5 cm between cam 0's and the colour cameras' exposures (their translation "
             "direction off by about 5 degrees); all cameras look the same way")


def temple_scene(root: Path) -> Scene:
    views = temple.read_cameras(root)
    return Scene("temple", views, "templeSR0007", "templeSR0008",
                 {"all": {v: temple.image_path(root, v) for v in views}},
                 note="one camera on a gantry; templeSR0001 and templeSR0011 are one viewpoint (no baseline)")


def fountain_scene(root: Path) -> Scene:
    views = strecha.read_cameras(root)
    return Scene("fountain", views, "0004", "0005", {"all": {v: strecha.image_path(root, v) for v in views}},
                 note="LIDAR reference, 0.3-0.5 px at full size")


def truth_scene(name: str, root: Path, **kwargs) -> Scene:
    truth = read_truth(root)
    return Scene(name, truth.cameras, truth.pair.left, truth.pair.right, truth.frames, **kwargs)


def castle_scene(root: Path) -> Scene:
    return truth_scene("castle", root, note="LIDAR reference, 0.2-0.3 px; a distant scene (37-44 m) seen from "
                                            "4.8-9.3 m baselines")


def webcams4_scene(root: Path) -> Scene:
    def drivers(work: Path) -> dict[str, dict]:
        return write_recording(root, work / "webcams4-recording")

    return truth_scene(
        "webcams4", root,
        recording=Recording(drivers, {"tolerance_ms": 50, "max_wait_s": 2}, until_frame_sets=40, duration_s=600,
                            how="the 48 frames of each video as images with their recorded capture times, 0.1x "
                                "their pace, looped; frame sets within 50 ms"),
        note="board-based reference, good to 1-2 px (a third camera's median 1.43 px)")


def fisheye_scene(root: Path) -> Scene:
    def drivers(work: Path) -> dict[str, dict]:
        # A synchronised rig: frame n of every camera at one instant, 1 s apart (lines 0-3: frames 1-3).
        stamps = work / "fisheye220-timestamps.txt"
        stamps.parent.mkdir(parents=True, exist_ok=True)
        stamps.write_text("".join(f"{kitti_stamp(n * 1_000_000_000)}\n" for n in range(4)))
        return {c: {"source": str(root / "images" / c / "*.png"), "timestamps": str(stamps),
                    "frame_range": [1, 3], "speed": 0.25, "loop": True, "encoding": "mono8"}
                for c in ("cam1", "cam2", "cam3", "cam4")}

    return truth_scene(
        "fisheye", root,
        recording=Recording(drivers, {}, until_frame_sets=3, duration_s=300,
                            how="the 3 instants' images, one every 4 s, looped"),
        note="reference K+dist: an OpenCV fisheye fit to the ocam model for rays up to 88 degrees (0.06-0.21 px "
             "RMS); the cameras overlap near the edges of their fields, where that model does not reach")


SCENES: dict[str, tuple[str, Callable[[Path], Scene]]] = {
    "kitti": ("kitti_raw_2011_09_26_extract_3cam", kitti_scene),
    "temple": ("middlebury_temple_sparse_ring", temple_scene),
    "fountain": ("strecha_fountain_p11", fountain_scene),
    "castle": ("strecha_castle_p19", castle_scene),
    "webcams4": ("webcams4_person_board", webcams4_scene),
    "fisheye": ("fisheye220_rig4", fisheye_scene),
}


def write_recording(root: Path, folder: Path) -> dict[str, dict]:
    """The webcams session's videos as image sequences with their capture times (camnet's v4l2 driver's
    recorded-sequence mode), in `folder` (a camera whose timestamps are there is written already); each
    camera's v4l2 section."""
    times = read_frame_times(root / "source" / "timestamps.csv")
    sections = {}
    for camera, stamps_ns in times.items():
        out = folder / camera
        if not (out / TIMESTAMPS).is_file():
            frames = read_video(root / "videos" / f"{camera}.mp4")
            if len(frames) != len(stamps_ns):
                raise SystemExit(f"{camera}: {len(frames)} video frames, {len(stamps_ns)} capture times")
            out.mkdir(parents=True, exist_ok=True)
            for k, frame in enumerate(frames):
                cv2.imwrite(str(out / f"{k:06d}.png"), frame)
            (out / TIMESTAMPS).write_text("".join(f"{kitti_stamp(int(t))}\n" for t in stamps_ns))
        sections[camera] = {"source": str(out / "*.png"), "timestamps": str(out / TIMESTAMPS),
                            "frame_range": [0, len(stamps_ns) - 1], "speed": 0.1, "loop": True, "encoding": "bgr8"}
    return sections


# --- Rig files and commands -------------------------------------------------------------------------------------

def rig_document(scene: Scene, cameras: list[str], known: str, drivers: dict[str, dict] | None = None) -> dict:
    """The rig file of `cameras`: the known pair with its distance; with `known` K, the pair's K, and its dist
    where the reference's is not none; with `drivers`, each camera's v4l2 section."""
    stereo = {"left": scene.left, "right": scene.right, "baseline_m": scene.baseline_m}
    if scene.parallel:
        stereo["parallel"] = True
    entries = []
    for camera_id in cameras:
        ref = scene.reference[camera_id]
        entry: dict = {"id": camera_id}
        if ref.model != LensModel.PINHOLE:
            entry["model"] = ref.model.value  # the lens type is known, not calibrated
        if drivers is not None:
            entry["driver"] = "v4l2"
            entry["v4l2"] = drivers[camera_id]
        if known == "K" and camera_id in (scene.left, scene.right):
            entry["intrinsics"] = {"K": ref.K.tolist()}
            if np.any(ref.dist):
                entry["intrinsics"]["dist"] = ref.dist.tolist()
        entries.append(entry)
    # In the floor's frame: its up is checked against the reference's where its camera centres give one.
    return {"rig": f"bench-{scene.name}", "stereo": stereo, "world": "floor", "cameras": entries}


@dataclass
class Step:
    """One command run: its exit status, its stderr and stdout, and seconds."""

    name: str
    returncode: int
    stdout: str
    stderr: str
    seconds: float


def run_command(name: str, args: list[str], log_dir: Path, timeout_s: float = COMMAND_TIMEOUT_S) -> Step:
    """`camnet ARGS` as its own process, as a user types it; stdout and stderr kept in `log_dir`."""
    start = time.perf_counter()
    try:
        done = subprocess.run([sys.executable, "-m", "camnet", *args], capture_output=True, text=True,
                              timeout=timeout_s, cwd=log_dir)
        step = Step(name, done.returncode, done.stdout, done.stderr, time.perf_counter() - start)
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else exc.stdout or ""
        err = exc.stderr.decode() if isinstance(exc.stderr, bytes) else exc.stderr or ""
        step = Step(name, -1, out, err + f"\nno exit within {timeout_s:.0f} s", time.perf_counter() - start)
    (log_dir / f"{name}.stdout").write_text(step.stdout)
    (log_dir / f"{name}.stderr").write_text(step.stderr)
    return step


@dataclass
class Run:
    """One scene's frame set (or recording) through the commands, with one thing known, and what came of it."""

    scene: str
    frame_set: str
    known: str
    cameras: list[str]
    steps: list[Step] = field(default_factory=list)
    outcome: Outcome | None = None
    error: str = ""
    check: Check | None = None
    frame_sets_pooled: int | None = None  # camnet up's calibration: from how many frame sets
    node_errors: list[str] = field(default_factory=list)  # camnet up: the exceptions its nodes' logs hold
    summary_verdict: str | None = None  # what `camnet calibrate --json` printed

    @property
    def seconds(self) -> float:
        return sum(s.seconds for s in self.steps)


def judged(run: Run, scene: Scene, last: Step, cal_path: Path) -> Run:
    """`run`, its last command `last` having ended: its outcome, and its calibration against the reference."""
    if last.returncode == 0:
        cal = parse_calibration(load_json(cal_path))
        run.check = check_calibration(cal, scene.reference, scene.left)
        run.frame_sets_pooled = load_json(cal_path).get("frame_sets")
    run.outcome = classify(last.returncode, last.stderr, run.check)
    if run.outcome in (Outcome.REFUSED, Outcome.CRASH):
        run.error = f"{last.name}: {error_line(last.stderr)}"
    return run


def match_and_calibrate(scene: Scene, frame_set: str, known: str, work: Path) -> Run:
    images = scene.frame_sets[frame_set]
    cameras = list(images)
    run = Run(scene.name, frame_set, known, cameras)
    work.mkdir(parents=True, exist_ok=True)
    (work / "rig.yaml").write_text(yaml.safe_dump(rig_document(scene, cameras, known), sort_keys=False))
    match = run_command("match", ["match", *(f"{c}={p}" for c, p in images.items()), "--rig", "rig.yaml",
                                  "-o", "obs.json"], work)
    run.steps.append(match)
    if match.returncode != 0:
        return judged(run, scene, match, work / "cal.json")
    solve = run_command("calibrate", ["calibrate", "obs.json", "-o", "cal.json", "--json", "--world", "floor"], work)
    run.steps.append(solve)
    if solve.returncode == 0:
        run.summary_verdict = json.loads(solve.stdout.strip().splitlines()[-1]).get("verdict")
    return judged(run, scene, solve, work / "cal.json")


def up(scene: Scene, label: str, known: str, work: Path, recordings: Path) -> Run:
    """The scene's recording through `camnet up` (its frames written under `recordings` where need be)."""
    recording = scene.recording
    cameras = list(scene.reference)
    run = Run(scene.name, label, known, cameras)
    work.mkdir(parents=True, exist_ok=True)
    rig = rig_document(scene, cameras, known, recording.drivers(recordings))
    if recording.sync:
        rig["sync"] = recording.sync
    (work / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    # Its own port: no other rig on this host meets it at the default rendezvous.
    step = run_command("up", ["up", "rig.yaml", "--until-frame-sets", str(recording.until_frame_sets),
                              "--duration-s", str(recording.duration_s), "--out", "run",
                              "--listen", f"tcp/127.0.0.1:{free_port()}", "-o", "cal.json"],
                       work, timeout_s=recording.duration_s + 300)
    run.steps.append(step)
    run.node_errors = logged_exceptions(work / "run" / "logs")
    return judged(run, scene, step, work / "cal.json")


def logged_exceptions(log_dir: Path) -> list[str]:
    """"node: exception line" of every traceback in the nodes' logs: a node that survives one (its guard logs
    it and goes on) says so only there."""
    found = []
    for log in sorted(log_dir.glob("*.log")):
        lines = log.read_text(errors="replace").splitlines()
        for k, line in enumerate(lines):
            if line.startswith(TRACEBACK):
                end = next((text for text in lines[k + 1:] if text and not text[0].isspace()), "?")
                found.append(f"{log.stem}: {end}")
    return found


# --- Tables -----------------------------------------------------------------------------------------------------

def fmt(value: float | None, digits: int, *, sign: bool = False) -> str:
    if value is None or np.isnan(value):
        return "-"
    if not np.isfinite(value):
        return "∞"
    return f"{value:+.{digits}f}" if sign else f"{value:.{digits}f}"


def sigmas(value: float) -> str:
    return "∞" if not np.isfinite(value) else f"{value:.1f}"


def worst_camera(check: Check, attribute: str) -> str:
    """The camera whose `attribute` lies furthest in its sigmas: error (sigma), in sigmas, id."""
    scale = 100.0 if attribute == "focal_rel" else 1.0
    cams = [c for c in check.cameras if getattr(c, attribute).error != 0.0 or attribute == "focal_rel"]
    if not cams:
        return "-"
    c = max(cams, key=lambda c: (getattr(c, attribute).in_sigmas, abs(getattr(c, attribute).error)))
    m = getattr(c, attribute)
    return (f"{fmt(scale * m.error, 2, sign=attribute == 'focal_rel')} ({fmt(scale * m.sigma, 2)}) "
            f"{sigmas(m.in_sigmas)}σ {c.id}")


def within_column(check: Check | None) -> str:
    if check is None:
        return "-"
    beyond = check.beyond()
    if not beyond:
        return "yes"
    shown = ", ".join(f"{what} {sigmas(n)}σ" for what, n in beyond[:3])
    return f"no: {shown}" + (f" (+{len(beyond) - 3})" if len(beyond) > 3 else "")


def error_column(run: Run) -> str:
    """The run's one-line error, and what its nodes' logs hold of tracebacks (counted by kind)."""
    kinds: dict[str, int] = {}
    for error in run.node_errors:
        kinds[error] = kinds.get(error, 0) + 1
    logged = "; ".join(f"{n}x {e}" if n > 1 else e for e, n in kinds.items())
    return "; ".join(part for part in (run.error, f"in the logs: {logged}" if logged else "") if part)


def summary_rows(runs: list[Run]) -> list[str]:
    rows = ["| scene | frame set | known | exit | outcome | verdict | cameras (left out) | scale err % (σ) "
            "| f err % (σ), worst | rotation err ° (σ), worst | right within 3σ? | cameras wrong in silence | error |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        exits = ", ".join(f"{s.name} {s.returncode}" for s in r.steps)
        c = r.check
        if c is None:
            rows.append(f"| {r.scene} | {r.frame_set} | {r.known} | {exits} | {r.outcome} | - | {len(r.cameras)} "
                        f"| - | - | - | - | - | {error_column(r)} |")
            continue
        solved = f"{len(c.cameras)} of {len(r.cameras)}" + (f" ({', '.join(c.left_out)})" if c.left_out else "")
        scale = (f"{fmt(100 * c.scale_rel.error, 2, sign=True)} ({fmt(100 * c.scale_rel.sigma, 2)}) "
                 f"{sigmas(c.scale_rel.in_sigmas)}σ" if c.scale_rel else "- (pair only)")
        pooled = f" ({r.frame_sets_pooled} frame sets)" if r.frame_sets_pooled is not None else ""
        rows.append(f"| {r.scene} | {r.frame_set}{pooled} | {r.known} | {exits} | {r.outcome} | {c.level} | {solved} "
                    f"| {scale} | {worst_camera(c, 'focal_rel')} | {worst_camera(c, 'rotation_deg')} "
                    f"| {within_column(c)} | {', '.join(c.silent()) or '-'} | {error_column(r)} |")
    return rows


def floor_note(check: Check) -> str:
    """The calibration's up against the reference's camera centres' plane, where both are."""
    if check.floor is None:
        return ""
    tilt = check.floor.tilt_deg
    if not check.floor.found:
        return f"; no floor found, up from the cameras' down {tilt.error:.2f} deg off the reference's"
    return f"; floor normal {tilt.error:.2f} deg off the reference's up (σ {tilt.sigma:.2f}, {sigmas(tilt.in_sigmas)}σ)"


def detail_rows(scene: Scene, runs: list[Run]) -> list[str]:
    rows = [f"### {scene.name}", "",
            f"{len(scene.reference)} cameras; known pair {scene.left}-{scene.right}, {scene.baseline_m:.4f} m"
            + (" (a parallel head)" if scene.parallel else "") + f". Reference: {scene.note}.", ""]
    rows += ["| frame set | known | camera | verdict | f err % (σ) | f in σ | rotation err ° (σ) | rotation in σ "
             "| centre err mm (σ) | distance from left err % |", "|---|---|---|---|---|---|---|---|---|---|"]
    notes = []
    for r in runs:
        c = r.check
        if c is None:
            notes.append(f"- {r.frame_set}, {r.known}: {r.outcome}: {error_column(r)}")
            continue
        for cam in c.cameras:
            f, rot, centre = cam.focal_rel, cam.rotation_deg, cam.centre_mm
            rows.append(
                f"| {r.frame_set} | {r.known} | {cam.id} | {cam.level} | {fmt(100 * f.error, 2, sign=True)} "
                f"({fmt(100 * f.sigma, 2)}) | {sigmas(f.in_sigmas)} | {fmt(rot.error, 2)} ({fmt(rot.sigma, 2)}) "
                f"| {sigmas(rot.in_sigmas)} | {fmt(centre.error, 0)} ({fmt(centre.sigma, 0)}) "
                f"| {fmt(100 * cam.distance_rel, 1, sign=True)} |")
        scale = (f"scale {fmt(100 * c.scale_rel.error, 2, sign=True)}% (σ {fmt(100 * c.scale_rel.sigma, 2)}%)"
                 if c.scale_rel else "scale fixed by the pair alone")
        left_out = "; ".join(f"{cam} left out: {why}" for cam, why in c.left_out.items())
        mismatch = (f"; the command printed verdict {r.summary_verdict}" if r.summary_verdict not in (None, c.level)
                    else "")
        findings = f"; the rig's findings: {'; '.join(c.findings)}" if c.findings else ""
        notes.append(f"- {r.frame_set}, {r.known}: {r.outcome} ({c.level}); {scale}; RMS {c.rms_px:.2f} px"
                     + floor_note(c) + findings + (f"; {left_out}" if left_out else "") + mismatch)
    return [*rows, "", *notes, ""]


# --- Main -------------------------------------------------------------------------------------------------------

def progress(start_s: float, message: str) -> None:
    print(f"[{time.monotonic() - start_s:7.1f} s] {message}", file=sys.stderr, flush=True)


def scene_runs(scene: Scene, knowns: list[str], work: Path, *, up_runs: int, start_s: float) -> list[Run]:
    """Every frame set of `scene` through match and calibrate, and its recording `up_runs` times through camnet
    up, with each of `knowns`; files under `work`."""
    runs = []
    for known in knowns:
        repeats = range(1, up_runs + 1) if scene.recording is not None else ()
        labels = list(scene.frame_sets) + [f"camnet up #{n}" if up_runs > 1 else "camnet up" for n in repeats]
        for label in labels:
            progress(start_s, f"{scene.name} {label}, known {known}: running")
            if label.startswith("camnet up"):
                run = up(scene, label, known, work / label.replace("camnet ", "").replace(" #", "-") / known, work)
            else:
                run = match_and_calibrate(scene, label, known, work / label / known)
            runs.append(run)
            progress(start_s, f"{scene.name} {label}, known {known}: {run.outcome} in {run.seconds:.0f} s"
                     + (f" ({run.error})" if run.error else ""))
    return runs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", default=",".join(SCENES), help=f"comma list of {', '.join(SCENES)}")
    parser.add_argument("--known", default=",".join(KNOWN), help="comma list of none (nothing known) and K (the "
                        "known pair's K and dist)")
    parser.add_argument("--up-runs", type=int, default=1, metavar="N",
                        help="run each recording N times through camnet up (0: none; its pooling depends on timing)")
    parser.add_argument("--keep", metavar="DIR", help="keep rig files, observations, calibrations and logs here")
    args = parser.parse_args()
    names = args.scenes.split(",")
    knowns = args.known.split(",")
    unknown = [n for n in names if n not in SCENES] + [k for k in knowns if k not in KNOWN]
    if unknown:
        parser.error(f"unknown {', '.join(unknown)}")
    start_s = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="camnet-bench-real-") as scratch:
        work = Path(args.keep) if args.keep else Path(scratch)
        scenes, runs, skipped = [], {}, []
        for name in names:
            folder = DATA / SCENES[name][0]
            if not folder.exists():
                skipped.append(f"{name}: not found at ../shared/data/{folder.name}")
                progress(start_s, skipped[-1])
                continue
            scene = SCENES[name][1](folder)
            scenes.append(scene)
            runs[name] = scene_runs(scene, knowns, work / name, up_runs=args.up_runs, start_s=start_s)
        all_runs = [r for name in runs for r in runs[name]]
        print(f"Real scenes through the commands; right = scale, every focal length and every rotation within "
              f"{K_SIGMAS:g} of its reported sigma of the reference.\n")
        print("\n".join(summary_rows(all_runs)))
        print()
        for scene in scenes:
            print("\n".join(detail_rows(scene, runs[scene.name])))
            if scene.recording is not None and args.up_runs:
                print(f"camnet up on {scene.name}: {scene.recording.how}; ends at the first calibration from "
                      f"{scene.recording.until_frame_sets} frame sets (at most {scene.recording.duration_s:.0f} s)."
                      "\n")
        for line in skipped:
            print(f"- skipped {line}")
        counts = {o: sum(r.outcome == o for r in all_runs) for o in Outcome}
        print("Outcomes: " + ", ".join(f"{o.value} {n}" for o, n in counts.items()))
        progress(start_s, f"done; files in {work}" if args.keep else "done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
