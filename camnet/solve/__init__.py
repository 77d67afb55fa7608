"""From observations to a metric calibration: `calibrate(observations, Options()) -> Result`.

The front door is `calibrate` (camnet.solve.pipeline: the solve's stages in order), and
`with_second_opinion` for a solve asked none (the halves and pair checks). The bundle
adjustment and its parts sit beside it, the start (cold, warm, the paper's, registration over the
view graph) in camnet.solve.start, and the report (uncertainty per camera, warnings, verdict) in
camnet.solve.report.
"""

from camnet.solve.options import Options
from camnet.solve.pipeline import calibrate, solved_from, with_second_opinion
from camnet.solve.result import Result

__all__ = ["Options", "Result", "calibrate", "solved_from", "with_second_opinion"]
