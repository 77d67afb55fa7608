"""Where capture-to-calibration latency goes: stage times carried in the nodes' messages.

The matcher stamps the newest frame set it pooled as it goes through it and
sends the stamps in its observations message (`StageStamps`, its
``latency_ns``, beside ``latest_capture_ns`` and ``published_ns``); the
calibrator adds its own to those of the message it solved and publishes them
in the calibration (``latency_ns``, beside ``solved_ns``). The messages are
`camnet.io.messages`'. All are Unix-epoch nanoseconds of the hosts' wall
clocks, so a stage across hosts includes their clock offset.

The stages, in order (each one's duration runs from the previous stamp):

- ``capture``: the newest pooled frame set's capture time (``latest_capture_ns``);
- ``taken``: the matcher took that frame set (rendering or exposure, transport,
  waiting for late cameras and for the matcher to finish the set before);
- ``detected``: its features are detected (or decoded, from a feature stage);
- ``matched``: its pairs are matched;
- ``pooled``: its tracks are built and pooled;
- ``published``: the observations message is built and sent (``published_ns``);
- ``received``: the calibrator received it;
- ``solving``: the calibrator took it (waiting for the solve before to end);
- ``solved``: solved, judged and stamped for publication (``solved_ns``).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, fields

MATCHER_STAGES = ("capture", "taken", "detected", "matched", "pooled")
STAGES = (*MATCHER_STAGES, "published", "received", "solving", "solved")
MAX_NS = 2**63  # a stamp is an int64 of nanoseconds


def now_ns() -> int:
    """The wall clock as the messages carry it: Unix epoch, ns."""
    return time.time_ns()


@dataclass(frozen=True)
class StageStamps:
    """A message's ``latency_ns`` object: when the newest pooled frame set passed each stage (Unix epoch, ns;
    None where not stamped). An observations message stamps the matcher's stages (taken to pooled); a
    calibration adds ``published`` (the observations' ``published_ns``) and the calibrator's own. The fields
    are in the order the object lists them; `STAGES` is their order in time."""

    taken_ns: int | None = None
    detected_ns: int | None = None
    matched_ns: int | None = None
    pooled_ns: int | None = None
    published_ns: int | None = None
    solving_ns: int | None = None
    received_ns: int | None = None

    @classmethod
    def from_stages(cls, stages: Mapping[str, int]) -> StageStamps:
        """The stamps of `stages` (stage name -> Unix epoch, ns), stages of `STAMPED` only."""
        return cls(**{f"{stage}_ns": stages[stage] for stage in STAMPED if stage in stages})

    def by_stage(self) -> dict[str, int]:
        """The stamps given, by stage name, in the object's order."""
        return {stage: ns for stage in STAMPED if (ns := getattr(self, f"{stage}_ns")) is not None}


STAMPED = tuple(f.name.removesuffix("_ns") for f in fields(StageStamps))  # the stages a latency_ns object holds


def stage_durations_s(stamps: StageStamps, *, capture_ns: int | None, solved_ns: int | None) -> dict[str, float]:
    """Seconds spent in each stage of a calibration (its `stamps`, its ``latest_capture_ns`` and ``solved_ns``),
    for the stages whose both ends are stamped, in `STAGES` order."""
    found = {**stamps.by_stage(), "capture": capture_ns, "solved": solved_ns}
    return {stage: (found[stage] - found[before]) / 1e9 for before, stage in zip(STAGES, STAGES[1:], strict=False)
            if found.get(stage) is not None and found.get(before) is not None}
