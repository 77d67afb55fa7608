"""Where capture-to-calibration latency goes: stage times carried in the nodes' documents.

The matcher stamps the newest frame set it pooled as it goes through it and
sends the stamps in its observations document (``latency_ns``, beside
``latest_capture_ns`` and ``published_ns``); the calibrator adds its own to
those of the document it solved and publishes them in the calibration
(``latency_ns``, beside ``solved_ns``). All are Unix-epoch nanoseconds of the
hosts' wall clocks, so a stage across hosts includes their clock offset.

The stages, in order (each one's duration runs from the previous stamp):

- ``capture``: the newest pooled frame set's capture time (``latest_capture_ns``);
- ``taken``: the matcher took that frame set (rendering or exposure, transport,
  waiting for late cameras and for the matcher to finish the set before);
- ``detected``: its features are detected (or decoded, from a feature stage);
- ``matched``: its pairs are matched;
- ``pooled``: its tracks are built and pooled;
- ``published``: the observations document is built and sent (``published_ns``);
- ``received``: the calibrator received it;
- ``solving``: the calibrator took it (waiting for the solve before to end);
- ``solved``: solved, judged and stamped for publication (``solved_ns``).
"""

from __future__ import annotations

import time

MATCHER_STAGES = ("capture", "taken", "detected", "matched", "pooled")
STAGES = (*MATCHER_STAGES, "published", "received", "solving", "solved")
_MAX_NS = 2**63


def now_ns() -> int:
    """The wall clock as the documents carry it: Unix epoch, ns."""
    return time.time_ns()


def stamps(doc: dict) -> dict[str, int]:
    """The stage stamps of an observations or calibration document that carry integers (others left out)."""
    given = doc.get("latency_ns")
    found = dict(given) if isinstance(given, dict) else {}
    found.update({"capture": doc.get("latest_capture_ns"), "published": found.get("published", doc.get(
        "published_ns")), "solved": doc.get("solved_ns")})
    return {stage: value for stage in STAGES if isinstance(value := found.get(stage), int)
            and not isinstance(value, bool) and 0 <= value < _MAX_NS}


def stage_durations_s(doc: dict) -> dict[str, float]:
    """Seconds spent in each stage of a calibration document, for the stages whose both ends it stamps."""
    found = stamps(doc)
    return {stage: (found[stage] - found[before]) / 1e9 for before, stage in zip(STAGES, STAGES[1:], strict=False)
            if stage in found and before in found}
