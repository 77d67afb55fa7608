"""The README stays a short user guide whose Python example runs; its links, and the guides', lead somewhere."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from camnet.io.formats import load_json, parse_calibration

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
MAX_LINES = 250  # a user guide; measurements and how-tos go to docs/

FENCE = re.compile(r"^```(\w*)\n(.*?)^```$", re.MULTILINE | re.DOTALL)
# [text](target) and ![alt](target); a target ends at whitespace or the closing parenthesis.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def code_blocks(text: str, language: str) -> list[str]:
    return [body for lang, body in FENCE.findall(text) if lang == language]


def prose(text: str) -> str:
    """The text outside fenced blocks: links inside code are not links."""
    return FENCE.sub("", text)


def heading_anchors(text: str) -> set[str]:
    """GitHub's anchor of every heading: lower case, punctuation dropped, spaces to hyphens."""
    anchors = set()
    for line in prose(text).splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            anchors.add(re.sub(r"\s", "-", re.sub(r"[^\w\s-]", "", title)))
    return anchors


def test_the_readme_is_short():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) < MAX_LINES, f"README.md has {len(lines)} lines; move detail into docs/ (at most {MAX_LINES - 1})"


@pytest.mark.parametrize("page", [README, *sorted((ROOT / "docs").glob("*.md"))], ids=lambda p: p.name)
def test_every_relative_link_leads_somewhere(page):
    text = page.read_text(encoding="utf-8")
    anchors = heading_anchors(text)
    broken = []
    for target in LINK.findall(prose(text)):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto: ...
            continue
        path, _, anchor = target.partition("#")
        leads_somewhere = (page.parent / path).exists() if path else anchor in anchors
        if not leads_somewhere:
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)} links to what does not exist: {broken}"


def test_the_readme_python_example_calibrates_a_simulated_rig(tmp_path):
    blocks = code_blocks(README.read_text(encoding="utf-8"), "python")
    assert blocks, "README.md has no ```python example of the engine"
    simulate = subprocess.run(
        [sys.executable, "-m", "camnet", "simulate", "-o", "observations.json", "--truth", "truth.json"],
        cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert simulate.returncode == 0, simulate.stderr
    for block in blocks:
        run = subprocess.run([sys.executable, "-c", block], cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, f"the README's example failed:\n{run.stderr}"

    # What it printed names every camera of the rig, and the verdict.
    truth = parse_calibration(load_json(tmp_path / "truth.json"))
    for cam in truth.cameras:
        assert re.search(rf"^{re.escape(cam.id)}\s", run.stdout, re.MULTILINE), run.stdout
    assert re.search(r"^verdict: (good|usable|poor)  \(", run.stdout, re.MULTILINE), run.stdout

    # What it wrote is the rig's calibration: the same cameras, the scale of the known baseline.
    cal = parse_calibration(load_json(tmp_path / "calibration.json"))
    assert [c.id for c in cal.cameras] == [c.id for c in truth.cameras]
    for solved, true in zip(cal.cameras, truth.cameras, strict=True):
        assert abs(solved.K[0, 0] / true.K[0, 0] - 1) < 0.1, (solved.id, solved.K[0, 0], true.K[0, 0])
        assert np.linalg.norm(solved.centre - true.centre) < 0.05, (solved.id, solved.centre, true.centre)
