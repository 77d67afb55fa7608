"""A solve judged, and solved again without the cameras its check finds placed wrong: the second opinion is
asked once, of the solve kept."""

from camnet.live.judged_solve import Refusal, Status, solve_judged
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options


def test_the_second_opinion_is_asked_of_the_kept_solve_only():
    obs = observe(make_rig(n_points=300, seed=5), noise_px=0.5, seed=5).observations
    wrong = obs.cameras[3].id
    seen = []

    def check(cal, _obs):
        seen.append(cal)
        placed = {c.id for c in cal.cameras}
        return Refusal("placed wrong", {wrong: "its tracks fit no pose"}) if wrong in placed else Refusal()

    judged = solve_judged(obs, None, options=Options(halves=True), check=check)

    assert judged.status == Status.GOOD, judged.reason
    assert len(seen) == 2 and all(c.report.halves is None and c.report.pair_checks is None for c in seen)
    report = judged.calibration.report
    assert report.halves is not None and report.halves.splits >= 1, report.halves
    assert report.pair_checks and all(wrong not in (c.first, c.second) for c in report.pair_checks)
    assert wrong in report.cameras_left_out
