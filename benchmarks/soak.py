#!/usr/bin/env python3
"""Soak: a 16-camera simulated rig left running; does any node grow?

Every node's resident memory is sampled every `--sample-s` (10 s), with the
matcher's dropped frames and the calibrations published. At the end, each
node's RSS floor (the least sample) minute by minute, its growth from the
first minute after the first to the last minute (must be under 5%), and a
plot of RSS against time (matplotlib) into `--plot`.

    python benchmarks/soak.py                          # 30 minutes
    python benchmarks/soak.py --minutes 5 --plot docs/soak.png
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench_faults import Network, rig_document, rss_mb

from camnet.bus import keys
from camnet.bus.stats import NodeStats

GROWTH_LIMIT = 0.05
SETTLE_S = 60.0  # growth is measured from the first sample after this
LEVEL_S = 60.0  # a node's RSS floor: the least of its samples over this long


class MatcherStats:
    """The matcher's latest statistics (dropped frames, frame sets)."""

    def __init__(self) -> None:
        self.latest: NodeStats | None = None
        self._lock = threading.Lock()

    def __call__(self, sample) -> None:
        try:
            stats = NodeStats.from_json(sample.payload.to_bytes())
        except Exception:  # noqa: BLE001 (an observer of a benchmark: skip what it cannot read)
            return
        with self._lock:
            self.latest = stats


def soak(work: Path, *, minutes: float, sample_s: float, n_cameras: int, fps: float) -> dict:
    rig = rig_document("soak", n_cameras=n_cameras, fps=fps, side_px=320)
    samples: list[dict] = []
    matcher = MatcherStats()
    with Network(work, rig) as net:
        net.session.declare_subscriber(keys.node_stats(net.rig_name, "matcher", "matcher"), matcher)
        start_s = time.monotonic()
        while time.monotonic() - start_s < 60 * minutes:
            net.launch.check()
            stats = matcher.latest
            samples.append({
                "t_s": round(time.monotonic() - start_s, 1),
                "rss_mb": {c.name: round(rss_mb(c.process.pid), 1) for c in net.launch.children},
                "dropped": stats.dropped if stats else 0, "frame_sets": stats.frames if stats else 0,
                "calibrations": len(net.calibrations)})
            print(json.dumps(samples[-1]), flush=True)
            time.sleep(sample_s)
    return {"samples": samples, "growth": growth(samples)}


def growth(samples: list[dict], settle_s: float = SETTLE_S) -> dict[str, float]:
    """Per node: relative growth of its RSS floor from the first minute after `settle_s` to the last minute.

    A floor is the least of a minute's samples, not one sample: the calibrator's RSS rises by up to a
    quarter while it solves (its working memory, given back after each solve) and the matcher's by a
    tenth while glibc holds freed blocks, so one sample caught at either end can make a node whose floor
    is flat look a quarter larger or smaller. A leak raises the floor.
    """
    settled = [s for s in samples if s["t_s"] >= settle_s] or samples[-1:]
    first_s, last_s = settled[0]["t_s"], samples[-1]["t_s"]
    first = rss_floor([s for s in settled if s["t_s"] < first_s + LEVEL_S])
    last = rss_floor([s for s in settled if s["t_s"] > last_s - LEVEL_S])
    return {name: (last[name] - mb) / mb for name, mb in first.items() if mb > 0 and name in last}


def rss_floor(samples: list[dict], pick=min) -> dict[str, float]:
    """Per node: the least of its RSS over `samples` (MB; `pick=max`: the peak), leaving out samples taken
    after it was gone (0)."""
    names = {name for s in samples for name in s["rss_mb"]}
    values = {name: [s["rss_mb"][name] for s in samples if s["rss_mb"].get(name, 0) > 0] for name in names}
    return {name: pick(v) for name, v in values.items() if v}


def curve(samples: list[dict], settle_s: float = SETTLE_S) -> list[str]:
    """Each node's RSS floor (MB) minute by minute from `settle_s`, as Markdown rows: growth that stops
    (a pool filling to its cap) levels off, a leak keeps climbing."""
    minutes = int((samples[-1]["t_s"] - settle_s) // LEVEL_S) + 1
    levels = [rss_floor([s for s in samples if 0 <= s["t_s"] - settle_s - m * LEVEL_S < LEVEL_S])
              for m in range(minutes)]
    spans = [f"{(settle_s + m * LEVEL_S) / 60:.1f}-{(settle_s + (m + 1) * LEVEL_S) / 60:.1f} min"
             for m in range(minutes)]
    header = "| node | " + " | ".join(spans) + " |"
    rows = [header, "|---" * (minutes + 1) + "|"]
    for name in samples[0]["rss_mb"]:
        rows.append(f"| {name} | " + " | ".join(f"{level[name]:.0f}" if name in level else "-" for level in levels)
                    + " |")
    return rows


def plot(samples: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5))
    for name in samples[0]["rss_mb"]:
        ax.plot([s["t_s"] / 60 for s in samples], [s["rss_mb"].get(name, 0) for s in samples], label=name,
                lw=1.2 if name in ("matcher", "calibrator") else 0.6)
    ax.set_xlabel("minutes")
    ax.set_ylabel("RSS (MB)")
    ax.set_title(title)
    ax.legend(fontsize=6, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--sample-s", type=float, default=10.0)
    parser.add_argument("--cameras", type=int, default=16)
    parser.add_argument("--fps", type=float, default=5.0, help="of every camera (default 5: 16 of them on 2 cores)")
    parser.add_argument("--plot", type=Path, help="where to draw RSS against time (PNG)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="camnet-soak-") as tmp:
        result = soak(Path(tmp), minutes=args.minutes, sample_s=args.sample_s, n_cameras=args.cameras, fps=args.fps)
    samples, grown = result["samples"], result["growth"]
    last = samples[-1]
    print(f"{args.cameras} cameras at {args.fps:g} fps for {args.minutes:g} min: {last['calibrations']} calibrations, "
          f"{last['frame_sets']} frame sets matched, {last['dropped']} frames dropped by the matcher")
    for name, g in sorted(grown.items(), key=lambda item: -item[1]):
        print(f"  {name:<16}{last['rss_mb'][name]:>8.0f} MB  floor growth after the first minute {100 * g:+.1f}%")
    print("\n".join(curve(samples)))
    if args.plot is not None:
        plot(samples, args.plot, f"{args.cameras}-camera sim rig, {args.minutes:g} min: RSS of every node")
    worst = max(grown.values(), default=0.0)
    print(f"largest growth {100 * worst:+.1f}% ({'under' if worst < GROWTH_LIMIT else 'OVER'} "
          f"{100 * GROWTH_LIMIT:.0f}%)")
    return 0 if worst < GROWTH_LIMIT else 1


if __name__ == "__main__":
    sys.exit(main())
