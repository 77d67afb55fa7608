"""NodeStats.to_json, written field by field for speed, says what every field of the dataclass holds."""

from __future__ import annotations

import json
from dataclasses import asdict

from camnet.bus.stats import STATS_FORMAT, CameraSeen, NodeStats


def test_to_json_holds_every_field_as_asdict_does_and_reads_back() -> None:
    stats = NodeStats(rig="sim", kind="matcher", node_id="matcher", fps=9.5, frames=1234, dropped=7,
                      timestamp_ns=1_700_000_000_123_456_789, detail="5000 tracks pooled",
                      faults={"malformed: truncated": 3, "handler: KeyError": 1},
                      cameras={"cam0": CameraSeen(age_s=0.25, fps=10.0, missing=False),
                               "cam1": CameraSeen(age_s=None, fps=0.0, missing=True)})
    doc = json.loads(stats.to_json())
    assert doc == {"format": STATS_FORMAT, **asdict(stats)}
    assert list(doc) == ["format", *asdict(stats)]  # the same order: the same bytes as before
    assert NodeStats.from_json(stats.to_json()) == stats
