"""The verdict on a calibration: good, usable or poor, per camera and for the rig, with why and what to do.

A solve cannot know how far it is from the truth: a scale or a focal length
off by many sigmas looks, from inside, like a well determined one. The
verdict therefore judges only what the solve knows (its SolveReport): the
reprojection RMS against the noise of feature positions, each camera's RMS
against the rig's, the 1-sigma of focal lengths, rotations, centres and the
scale, the median parallax against what it has to determine, and the
inliers. Each measure is good, usable or poor by the thresholds of
`Thresholds` (docs/calibration-keys.md, "The verdict"); a camera's verdict
is its worst measure, the rig's the worst of its own measures and its
cameras'. Every measure short of good says its likely cause and the one
thing to do about it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np

from camnet.errors import in_words
from camnet.model.calibration import Calibration, CameraSigmas, SolveReport
from camnet.solve.report.lens_shifts import biased
from camnet.solve.report.lens_shifts import describe as lens_move
from camnet.solve.report.pair_poses import describe, judge_pairs
from camnet.solve.report.rivals import TO_DECIDE, named_parameter
from camnet.solve.report.scale_cause import GIVE_STEREO_K, pair_rotation_todo, scale_cause


class Level(StrEnum):
    """How far a calibration, or one of its cameras, can be trusted."""

    GOOD = "good"  # use it
    USABLE = "usable"  # use it, knowing the limit its findings name
    POOR = "poor"  # do not rely on it: do what its findings say and solve again

    @property
    def rank(self) -> int:
        return (Level.GOOD, Level.USABLE, Level.POOR).index(self)


class Action(StrEnum):
    """The one thing to do about a finding."""

    GIVE_K = "give K"  # give what the scene cannot determine: K, dist, the stereo pair's pose
    ADD_TEXTURE = "add texture"  # more and more distinct features where the cameras look
    MOVE_CAMERA = "move a camera"  # more overlap with the others, or wider angles between views
    ADD_FRAME_SET = "add a frame set"  # more observations of the same rig: let it run longer


@dataclass(frozen=True)
class Finding:
    """One measure short of good: what it is, its likely cause, and what to do."""

    level: Level
    what: str  # the measure against its threshold, in words and units
    cause: str  # the likely cause
    action: Action
    todo: str  # the action, said for this case


@dataclass(frozen=True)
class CameraVerdict:
    camera: str
    level: Level
    findings: tuple[Finding, ...]


@dataclass(frozen=True)
class Verdict:
    """The rig's level and findings (its own measures), and one verdict per camera."""

    level: Level
    findings: tuple[Finding, ...]
    cameras: tuple[CameraVerdict, ...]

    def all_findings(self) -> list[tuple[str | None, Finding]]:
        """(camera id or None for the rig, finding), worst first."""
        pairs = [(None, f) for f in self.findings] + [(c.camera, f) for c in self.cameras for f in c.findings]
        return sorted(pairs, key=lambda p: -p[1].level.rank)


@dataclass(frozen=True)
class Thresholds:
    """Where good ends and where poor begins, for each measure (docs/calibration-keys.md).

    Each pair is (good up to, poor beyond); between them a measure is usable.
    """

    noise_px: float = 0.5  # what feature positions are expected to be good to (SIFT on real images)
    rms_noise: tuple[float, float] = (2.0, 6.0)  # the rig's RMS over noise_px (6: the live calibrator's 3 px)
    camera_rms_ratio: tuple[float, float] = (1.5, 3.0)  # a camera's RMS over the rig's sigma_px
    focal_rel: tuple[float, float] = (0.02, 0.05)  # sigma f / f
    scale_rel: tuple[float, float] = (0.02, 0.05)  # sigma of the scale, relative (0.05: the live limit)
    # The largest axis' sigma as the image shift it makes, f * sigma (px: the same at every depth),
    # less what guessed principal points explain (see _sigma_findings). Good up to 4 feature
    # noises, poor beyond 10; at the ring's f of 950 px, 0.12 and 0.30 degrees.
    rotation_px: tuple[float, float] = (2.0, 5.0)
    # |sigma centre| over the camera's distance from the world origin (the left stereo camera):
    # the scale's sigma is part of it.
    centre_rel: tuple[float, float] = (0.03, 0.1)
    inliers: tuple[int, int] = (100, 12)  # a camera's inlier observations: good from, poor below
    inlier_share: tuple[float, float] = (0.8, 0.5)  # inliers / observations: good from, poor below
    # Median parallax below this: the depths are weakly determined (usable), and what the solve
    # estimated from them (the pair's relative pose, focal lengths) may be off by more than its
    # sigma (poor; docs/benchmarks.md, "Evidence behind the solver's thresholds").
    parallax_deg: float = 2.0


THRESHOLDS = Thresholds()


def _level(value: float, good_up_to: float, poor_beyond: float) -> Level:
    """Level of a measure that is better small; NaN or infinite is poor."""
    if not np.isfinite(value) or value > poor_beyond:
        return Level.POOR
    return Level.GOOD if value <= good_up_to else Level.USABLE


def _level_from(value: float, good_from: float, poor_below: float) -> Level:
    """Level of a measure that is better large."""
    if value < poor_below:
        return Level.POOR
    return Level.GOOD if value >= good_from else Level.USABLE


def judge(cal: Calibration, thresholds: Thresholds = THRESHOLDS) -> Verdict | None:
    """The verdict on `cal` from its report; None without a report (a factory head: nothing was solved)."""
    report = cal.report
    if report is None:
        return None
    origin = next((c.centre for c in cal.cameras if c.id == cal.world_frame), cal.cameras[0].centre)
    # A camera's own measures are its sigmas: where the rig's findings doubt every sigma, none of them makes it
    # better than those findings say.
    ceiling = _worst(_sigma_doubts(report, thresholds))
    cameras = []
    for cam in cal.cameras:
        lever_m = float(np.linalg.norm(cam.centre - origin))  # 0 for the camera that fixes the frame
        findings = _camera_findings(cam.id, float(cam.K[0, 0]), report, lever_m, thresholds)
        cameras.append(CameraVerdict(cam.id, max(_worst(findings), ceiling, key=lambda lv: lv.rank), tuple(findings)))
    rig = _rig_findings(cal, report, thresholds)
    level = max([_worst(rig), *(c.level for c in cameras)], key=lambda lv: lv.rank)
    return Verdict(level, tuple(rig), tuple(cameras))


def _worst(findings: list[Finding]) -> Level:
    return max((f.level for f in findings), key=lambda lv: lv.rank, default=Level.GOOD)


def _camera_findings(cam_id: str, f_px: float, report: SolveReport, lever_m: float,
                     t: Thresholds) -> list[Finding]:
    """What of one camera falls short of good."""
    out = []
    stats = report.cameras.get(cam_id)
    sigma_px = report.uncertainty.sigma_px if report.uncertainty is not None else None
    if stats is not None:
        level = _level_from(stats.inliers, *t.inliers)
        if level != Level.GOOD:
            out.append(Finding(
                level, f"{stats.inliers} inlier observations (good from {t.inliers[0]})",
                "it shares few points with the other cameras", Action.MOVE_CAMERA,
                f"turn camera {cam_id} so that it sees more of what the others see, or add a frame set"))
        if stats.rms_px is not None and sigma_px:
            ratio = stats.rms_px / sigma_px
            level = _level(ratio, *t.camera_rms_ratio)
            if level != Level.GOOD:
                out.append(Finding(
                    level, f"RMS {stats.rms_px:.2f} px, {ratio:.1f}x the rig's {sigma_px:.2f} px",
                    "its images fit worse than the others': a lens distortion the model does not have, "
                    "a frame out of sync, or false matches", Action.GIVE_K,
                    f"give camera {cam_id}'s K and dist, and check its sync"))
    far = report.far_principal_points.get(cam_id)
    if far is not None:
        # Its sigmas are the curvature of a valley no lens lies in: they do not bound its error.
        out.append(Finding(
            Level.POOR, f"principal point moved {100 * far:.0f}% of the image from where it started",
            "no lens's is that far off: the data trade it with the focal length and rotation, which may be wrong "
            "by several of their sigmas", Action.GIVE_K, f"give camera {cam_id}'s K"))
    sigmas = report.uncertainty.cameras.get(cam_id) if report.uncertainty is not None else None
    if sigmas is not None:
        # Not known exactly: held at a guess (its sigma the guess's prior) or estimated.
        pp_loose = sigmas.cx_px > 0 or sigmas.cy_px > 0
        out += _sigma_findings(cam_id, f_px, sigmas, lever_m, pp_loose, t)
    out += _pair_findings(cam_id, report)
    out += _lens_findings(cam_id, report)
    disputed = set(report.halves.widened) if report.halves is not None else set()
    return [_disputed(f, cam_id) if _measure(f) and f"{_measure(f)} {cam_id}" in disputed else f for f in out]


def _pair_findings(cam_id: str, report: SolveReport) -> list[Finding]:
    """A camera whose pose disagrees with most of its neighbours' two views is poor; one of a disagreeing pair
    neither of whose cameras is to blame is usable."""
    if not report.pair_checks:
        return []
    pairs = judge_pairs(report.pair_checks)
    if cam_id in pairs.named:
        mine = pairs.named[cam_id]
        return [Finding(Level.POOR, f"pose disagrees with its own two views with {len(mine)} of its neighbours "
                        f"({describe(mine)})", "it settled in a wrong place that the other cameras' tracks still "
                        "fit, or its lens is not the one solved", Action.ADD_FRAME_SET,
                        f"add a frame set, or give camera {cam_id}'s K")]
    mine = tuple(c for c in pairs.unexplained if cam_id in (c.first, c.second))
    if mine:
        others = in_words([c.second if c.first == cam_id else c.first for c in mine], noun="camera")
        return [Finding(Level.USABLE, f"relative pose with {others} disagrees with their own two views "
                        f"({describe(mine)})", "one of the two is placed wrong", Action.ADD_FRAME_SET,
                        f"add a frame set, or give camera {cam_id}'s K")]
    return []


def _lens_findings(cam_id: str, report: SolveReport) -> list[Finding]:
    """A camera whose focal length moves beyond its sigmas once its lens, held straight, is freed, is poor: its
    sigmas were those of a lens it does not have (camnet.solve.lens_check)."""
    shift = biased(report.lens_shifts).get(cam_id)
    if shift is None:
        return []
    return [Finding(Level.POOR, lens_move(shift), "its lens bends the image, which the solve held straight as nobody "
                    "gave its dist: its focal length and distance took the bend up", Action.GIVE_K,
                    f"give camera {cam_id}'s K and dist, or free its distortion (--free with k1)")]


def _measure(finding: Finding) -> str:
    """The parameter a sigma finding is about, as camnet.solve.report.halves names it ("f", "rotation", "centre")."""
    for prefix, name in (("focal length", "f"), ("rotation", "rotation"), ("centre", "centre")):
        if finding.what.startswith(prefix):
            return name
    return ""


def _disputed(finding: Finding, cam_id: str) -> Finding:
    """A sigma finding whose sigma the scene's halves widened: that, not the curvature, is its cause."""
    return replace(finding, cause="the two halves of the scene, solved apart, disagree on it: the model does not fit "
                   "every part of the scene alike (a lens the model lacks, false matches in one part, or a second "
                   "solution as good)", action=Action.GIVE_K,
                   todo=f"give camera {cam_id}'s K and dist, or add frame sets that show more of the scene")


def _sigma_findings(cam_id: str, f_px: float, s: CameraSigmas, lever_m: float, pp_loose: bool,
                    t: Thresholds) -> list[Finding]:
    out = []
    if s.f_px != 0.0:  # 0: held (given)
        rel = s.f_px / f_px
        level = _level(rel, *t.focal_rel)
        if level != Level.GOOD:
            what = "focal length not determined" if not np.isfinite(rel) else f"focal length sigma {100 * rel:.1f}%"
            out.append(Finding(level, what, "the scene does not fix its focal length: little depth or parallax "
                               "in its view, or a guessed principal point", Action.GIVE_K,
                               f"give camera {cam_id}'s K"))
    out += _rotation_findings(cam_id, f_px, s, lever_m, pp_loose, t)
    centre = float(np.linalg.norm(s.centre_m))
    level = _level(centre / lever_m, *t.centre_rel) if lever_m > 0 else Level.GOOD
    if level != Level.GOOD:
        what = ("centre not determined" if not np.isfinite(centre)
                else f"centre sigma {1e3 * centre:.1f} mm, {100 * centre / lever_m:.1f}% of its distance from "
                "the world origin")
        out.append(Finding(level, what, "its position is weakly determined: few points shared with the others, or "
                           "views along one line", Action.MOVE_CAMERA,
                           f"move camera {cam_id} to see more of what the stereo pair sees, from a wider angle"))
    return out


def _rotation_findings(cam_id: str, f_px: float, s: CameraSigmas, lever_m: float, pp_loose: bool,
                       t: Thresholds) -> list[Finding]:
    """The rotation's sigma as the image shift it makes (px), and whether the principal points' sigmas explain it."""
    rotation = max(s.rotation_deg)
    pp_deg = 0.0
    if pp_loose and lever_m > 0:
        # A principal point and a rotation move the image alike: the sigma of each holds what the
        # other's may cost (a guess's or an estimate's), while the camera's rays, their sum, are what
        # the data fix. A rotation is relative to the left camera's, so both cameras' principal points
        # enter it (and, round a ring, those of the cameras between, which this leaves in: the
        # subtraction brings the sigma towards the true errors, not down to them; docs/benchmarks.md,
        # "Evidence behind the solver's thresholds").
        pp_deg = float(np.degrees(np.sqrt(2.0) * max(s.cx_px, s.cy_px) / f_px))
    data_deg = float(np.sqrt(max(rotation**2 - pp_deg**2, 0.0))) if np.isfinite(rotation) else rotation
    shift_px = f_px * np.radians(data_deg)
    level = _level(shift_px, *t.rotation_px)
    if level == Level.GOOD:
        return []
    if not np.isfinite(rotation):
        return [Finding(level, "rotation not determined", "few points tie its orientation to the others",
                        Action.ADD_TEXTURE, f"add texture where camera {cam_id} and its neighbours look")]
    what = f"rotation sigma {rotation:.2f} deg ({f_px * np.radians(rotation):.1f} px at f {f_px:.0f} px)"
    if pp_deg**2 >= rotation**2 / 2:
        # Most of the variance is the guess's: K and R together still put the scene where the data
        # put it, but R alone (a mount's angle, an export that takes another K) is known only to
        # this. What the data leave cannot be told apart here, so it is a caveat, as for the scale.
        return [Finding(Level.USABLE, f"{what}, most of it what the principal points' sigmas may cost",
                        f"camera {cam_id}'s and the left camera's principal points are not known exactly (guessed or "
                        "estimated): a rotation and a principal point move the image alike, so its K and R hold "
                        "together but R alone is loose",
                        Action.GIVE_K, f"give camera {cam_id}'s K and the left camera's to pin its rotation")]
    return [Finding(level, what, "few points tie its orientation to the others", Action.ADD_TEXTURE,
                    f"add texture where camera {cam_id} and its neighbours look")]


def _rig_findings(cal: Calibration, report: SolveReport, t: Thresholds) -> list[Finding]:
    """What of the whole rig falls short of good: RMS, inliers, the scale, parallax."""
    out = []
    rms = cal.rms_reprojection_px
    level = _level(rms / t.noise_px, *t.rms_noise)
    if level != Level.GOOD:
        out.append(Finding(level, f"RMS {rms:.2f} px, {rms / t.noise_px:.1f}x a feature's {t.noise_px} px",
                           "the model does not fit the images: lens distortion not given or freed, frames out of "
                           "sync, or a camera that moved", Action.GIVE_K, "give the cameras' K and dist"))
    if report.observations:
        share = report.inliers / report.observations
        level = _level_from(share, *t.inlier_share)
        if level != Level.GOOD:
            out.append(Finding(level, f"{100 * share:.0f}% of the observations are inliers",
                               "many matches are false: repetitive texture, or too little", Action.ADD_TEXTURE,
                               "add distinct texture to the scene"))
    out += _scale_findings(report, t)
    out += _parallax_findings(report, t)
    out += _halves_findings(report)
    out += _rival_findings(report)
    out += _floor_findings(cal)
    return out


def _floor_findings(cal: Calibration) -> list[Finding]:
    """A world frame asked of the scene's floor (camnet.solve.world_frame) that rests on less: no floor in view (up
    from the cameras' down alone), or another plane that could be the floor. The cameras and points are as good
    as their own findings say; the frame they are written in is what falls short."""
    frame = cal.floor_frame
    if frame is None:
        return []
    if not frame.found:
        return [Finding(Level.USABLE, "no floor in view", frame.reason, Action.MOVE_CAMERA,
                        "turn a camera so that it sees the floor, or keep the left camera's frame "
                        "(world: left_camera)")]
    if frame.ambiguity:
        return [Finding(Level.USABLE, "the floor is ambiguous", frame.ambiguity, Action.MOVE_CAMERA,
                        "turn a camera so that it sees more of the floor")]
    return []


def _sigma_doubts(report: SolveReport, t: Thresholds) -> list[Finding]:
    """The rig's findings that doubt every camera's sigmas: no second opinion vouches for them, another solution
    fits as well, or narrow parallax under estimated poses and focal lengths moves them more than they show."""
    parallax = [f for f in _parallax_findings(report, t) if f.level == Level.POOR]
    return _halves_findings(report) + _rival_findings(report) + parallax


def _halves_findings(report: SolveReport) -> list[Finding]:
    """Good means a second opinion agrees: where the scene's halves could not be solved apart, there is none, and
    nothing vouches for the sigmas (a few tracks fit a wrong solution as well as the right one)."""
    halves = report.halves
    if halves is None or halves.splits:
        return []
    weak = ("each half of the scene too weak for a cold solve to find its own best solution" if halves.ruled_out
            else "too few tracks for each half of the scene to place every camera")
    return [Finding(Level.POOR, f"no second opinion: {halves.reason}",
                    f"{weak}, so nothing checks the sigmas beyond the curvature at this one solution",
                    Action.ADD_FRAME_SET,
                    "add frame sets, or texture every camera sees more of")]


def _rival_findings(report: SolveReport) -> list[Finding]:
    """A solution from another start that the data cannot tell from this one (camnet.solve.report.rivals): at
    best usable, whatever the sigmas, which are widened to cover both."""
    if not report.rivals:
        return []
    differing = in_words(sorted({named_parameter(d) for r in report.rivals for d in r.differences},
                                key=lambda name: (name != "the scale", name)))
    n = len(report.rivals)
    return [Finding(Level.USABLE, f"{n} competing solution{'s' if n > 1 else ''} of nearly equal cost, differing in "
                    f"{differing}", "the observations fit two minima nearly equally well: which one is right "
                    "they do not say", Action.ADD_FRAME_SET, f"{TO_DECIDE}, and solve again")]


def _scale_findings(report: SolveReport, t: Thresholds) -> list[Finding]:
    u = report.uncertainty
    if u is None:
        return []
    scale = u.scale_rel.value
    if scale is None:
        return [Finding(Level.POOR, f"scale not determined: {u.scale_rel.reason}",
                        "the stereo pair's disparities do not fix the scale", Action.GIVE_K,
                        "give the stereo cameras' K")]
    level = _level(scale, *t.scale_rel)
    cause = scale_cause(u)
    if level == Level.USABLE and cause.pp and not cause.pair and cause.if_pp <= t.scale_rel[0]:
        level = Level.GOOD  # the scene fixes the scale: the guess is a caveat, which the report's notes say
    if level == Level.GOOD:
        return []
    what = f"scale sigma {100 * scale:.1f}%"
    if cause.scene:
        return [Finding(level, what, "the scene is far or shallow for the stereo baseline: small disparities",
                        Action.ADD_FRAME_SET, "add frame sets with texture nearer the stereo pair")]
    if not cause.pair:
        return [Finding(level, f"{what} ({100 * cause.if_pp:.2g}% with the principal points known)",
                        "the stereo cameras' principal points are guessed", Action.GIVE_K, GIVE_STEREO_K)]
    # The pair held parallel, or at a rotation given: assumed to its tolerance, not measured (the held-yaw
    # warning says what a tenth of a degree of it moves the scale by).
    known = "the pair's held rotation" if not cause.pp else "the principal points and the pair's held rotation"
    held = "at its given rotation" if report.pair_pose_given else "parallel"
    why = f"the scale rests on the stereo pair held {held}, known only to its tolerance"
    todo = pair_rotation_todo(report.pair_pose_given)
    if cause.pp:
        why += ", and on the stereo cameras' guessed principal points"
        todo = f"{GIVE_STEREO_K}, and {todo}"
    return [Finding(level, f"{what} ({100 * cause.if_named_exact:.2g}% with {known} exact)", why, Action.GIVE_K,
                    todo)]


def _parallax_findings(report: SolveReport, t: Thresholds) -> list[Finding]:
    parallax = report.median_parallax_deg
    if parallax is None or parallax >= t.parallax_deg:
        return []
    free = report.free
    estimated = []
    if free is not None and (free.stereo_rotation_axes or free.stereo_direction):
        estimated.append("the stereo pair's relative pose")
    if free is not None and any("f" in names for names in free.intrinsics.values()):
        estimated.append("focal lengths")
    if estimated:
        return [Finding(Level.POOR, f"median parallax {parallax:.2f} deg with {' and '.join(estimated)} estimated",
                        "narrow angles between the views cannot fix what was estimated from them: a small error "
                        "there moves every depth, more than the sigmas show", Action.GIVE_K,
                        "give the stereo pair's pose (the rig file's stereo R, t) and the cameras' K")]
    return [Finding(Level.USABLE, f"median parallax {parallax:.2f} deg", "the points are far for the distances "
                    "between the cameras: depths are weakly determined", Action.MOVE_CAMERA,
                    "move a camera to see the scene from a wider angle, or bring texture nearer")]


def format_verdict(verdict: Verdict) -> list[str]:
    """Human lines: the rig's level, each camera's, and each finding with its cause and what to do."""
    lines = [f"verdict: {verdict.level.value}  ("
             + ", ".join(f"{c.camera} {c.level.value}" for c in verdict.cameras) + ")"]
    for camera, f in verdict.all_findings():
        where = f"camera {camera}" if camera is not None else "rig"
        cause = f"; likely {f.cause}" if f.level == Level.POOR else ""  # usable: what and what to do suffice
        lines.append(f"  {f.level.value:<6} {where}: {f.what}{cause}; to do: {f.todo}")
    return lines
