#!/usr/bin/env python3
"""16 cameras across hosts, on one machine: four camera hosts, the router, the matcher, the calibrator.

The 16-camera simulated rig of config/hosts16.yaml (640x512 at 10 fps) runs
as four "hosts": four `camnet driver sim --camera A --camera B --camera C
--camera D --features` processes, each with four cameras and their feature
stages, meeting the matcher and the calibrator at `camnet router`, as the
`hosts` profile of docker/compose.yaml runs them on five machines. Every `--sample-s` it samples
each process's CPU time (/proc/PID/stat, utime + stime) and resident memory,
the matcher's frame sets and the good calibrations published, and prints a
progress line. At the end, a table:

- calibrated frame sets per second: frame sets pooled into the good
  calibrations published after the first minute (their `frame_sets`), per
  second of that window (target: at least 1);
- capture->calibration latency: solved_ns - latest_capture_ns of each good
  calibration, median and max (as bench_live.py);
- CPU of each process, in % of one core over the window;
- memory of every node: its RSS floor (the least of a minute's samples)
  minute by minute, and its growth from the window's first minute to the
  run's last (under 5%). The floor, since one sample caught mid-solve
  reads up to a quarter above a calibrator whose floor stays flat.

Rates, CPU and growth are taken from the first sample after the first
minute and after the first good calibration of a full pool (with at least
90% of the most points any calibration of the run held), whichever is
later: a loaded machine calibrates 16 cameras for the first time after
more than a minute, and the calibrator grows with its pool until then.

Then, unless `--compare-minutes 0`, the same with the rig's first four
cameras (the paper's rig) on one host: the matcher's CPU seconds per frame
set matched, 16 cameras against 4 (target: at most 2.5x).

    python benchmarks/bench_hosts.py                          # 10 minutes, then 3 of the 4-camera rig
    python benchmarks/bench_hosts.py --minutes 3 --compare-minutes 2
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import yaml
from bench_faults import Network, rss_mb
from soak import GROWTH_LIMIT, LEVEL_S, SETTLE_S, MatcherStats, curve, growth, rss_floor

from camnet.bus import keys
from camnet.commands.up_console import summarise
from camnet.io.messages import CalibrationMessage
from camnet.io.rig import parse_rig

ROOT = Path(__file__).resolve().parent.parent
CAMERAS_PER_HOST = 4
MIN_FRAME_SETS_PER_S = 1.0
MAX_MATCHER_CPU_RATIO = 2.5
FULL_POOL_SHARE = 0.9  # a calibration with this share of the run's most points is of a full pool
CLOCK_TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """CPU time (user + system) a process has used, in seconds (0 when it is gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0.0
    fields = stat[stat.rindex(")") + 2:].split()  # after the command name, which may hold spaces
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS_PER_S  # utime, stime: fields 14 and 15


def thread_part(name: str) -> str:
    """The part of a camera host a thread belongs to, from its name (as the kernel keeps it: 15 characters)."""
    for prefix, part in (("driver-", "drivers"), ("features-", "features")):
        if name.startswith(prefix):
            return part
    return "zenoh+main"


HOST_PARTS = ("drivers", "features", "zenoh+main")  # drivers: rendering and putting frames


def host_parts_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds of a camera host's live threads, summed by part (`thread_part`)."""
    parts = dict.fromkeys(HOST_PARTS, 0.0)
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return parts
    for task in tasks:
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue  # the thread ended
        fields = stat[stat.rindex(")") + 2:].split()
        name = stat[stat.index("(") + 1:stat.rindex(")")]
        parts[thread_part(name)] += (int(fields[11]) + int(fields[12])) / CLOCK_TICKS_PER_S
    return parts


class HostsNetwork(Network):
    """The rig's cameras in processes of `cameras_per_host` drivers each, with their feature stages."""

    def __init__(self, work: Path, rig: dict, *, cameras_per_host: int, features_period_s: float,
                 matcher_flags: tuple[str, ...] = (), calibrator_flags: tuple[str, ...] = ()) -> None:
        super().__init__(work, rig, matcher_flags=matcher_flags, calibrator_flags=calibrator_flags)
        self.camera_ids = [c["id"] for c in rig["cameras"]]
        self.cameras_per_host = cameras_per_host
        self.features_period_s = features_period_s

    def start_nodes(self, bus: tuple[str, ...], *, drivers: bool = True) -> None:
        ids, n = self.camera_ids, self.cameras_per_host
        for host, first in enumerate(range(0, len(ids), n), start=1):
            cameras = [arg for camera_id in ids[first:first + n] for arg in ("--camera", camera_id)]
            self.launch.start(f"host-{host}", ["driver", "sim", "--rig", str(self.rig_path), *cameras, "--features",
                                               "--features-period-s", str(self.features_period_s), *bus])
        super().start_nodes(bus, drivers=False)


@dataclass(frozen=True)
class Phase:
    n_cameras: int
    minutes: float
    samples: list[dict]  # t_s, cpu_s and rss_mb per process, matcher frame sets
    calibrations: list[tuple[float, CalibrationMessage]]  # (s since the start, message) of every good one
    truth: list  # the simulated cameras (camnet.model.camera.Camera)

    @property
    def window_s(self) -> float:
        """Rates and growth are measured from here on: after the first minute (half the run if shorter)
        and after the first good calibration of a full pool: one with at least `FULL_POOL_SHARE` of the most
        points any calibration of the run held (before it, the calibrator has not grown into its pool)."""
        most = max((len(m.calibration.points) for _, m in self.calibrations), default=0)
        full_s = next((t for t, m in self.calibrations if len(m.calibration.points) >= FULL_POOL_SHARE * most), 0.0)
        return max(min(SETTLE_S, 30 * self.minutes), full_s)

    def growth(self) -> dict[str, float]:
        return growth(self.samples, self.window_s)

    def settled(self) -> dict:
        return next((s for s in self.samples if s["t_s"] >= self.window_s), self.samples[0])

    def frame_sets_per_s(self) -> float | None:
        """Frame sets pooled into good calibrations per second of the window (None: fewer than two)."""
        timed = [(t, m.frame_sets) for t, m in self.calibrations if t >= self.window_s and m.frame_sets is not None]
        if len(timed) < 2 or timed[-1][0] <= timed[0][0]:
            return None
        return (timed[-1][1] - timed[0][1]) / (timed[-1][0] - timed[0][0])

    def latencies_s(self) -> list[float]:
        return sorted((m.solved_ns - m.latest_capture_ns) / 1e9 for _, m in self.calibrations
                      if m.solved_ns is not None and m.latest_capture_ns is not None)

    def cpu_percent(self) -> dict[str, float]:
        """Per process: CPU over the window, in % of one core."""
        first, last = self.settled(), self.samples[-1]
        span_s = max(last["t_s"] - first["t_s"], 1e-9)
        return {name: 100 * (last["cpu_s"][name] - cpu) / span_s for name, cpu in first["cpu_s"].items()
                if name in last["cpu_s"]}

    def host_parts_percent(self) -> dict[str, float]:
        """CPU of the camera hosts' threads over the window, by part, summed over the hosts, in % of one core."""
        first, last = self.settled(), self.samples[-1]
        span_s = max(last["t_s"] - first["t_s"], 1e-9)
        totals = dict.fromkeys(HOST_PARTS, 0.0)
        for name, parts in last["parts_cpu_s"].items():
            for part, cpu in parts.items():
                totals[part] += 100 * (cpu - first["parts_cpu_s"].get(name, {}).get(part, 0.0)) / span_s
        return totals

    def errors(self) -> list[dict]:
        """Against the simulation's truth, each good calibration of the window (`summarise`'s keys)."""
        return [summarise(t, m, self.truth) for t, m in self.calibrations if t >= self.window_s]

    def matcher_cpu_per_set_s(self) -> float | None:
        first, last = self.settled(), self.samples[-1]
        sets = last["frame_sets"] - first["frame_sets"]
        return (last["cpu_s"]["matcher"] - first["cpu_s"]["matcher"]) / sets if sets > 0 else None


def run_phase(work: Path, rig: dict, *, minutes: float, sample_s: float, features_period_s: float,
              matcher_flags: tuple[str, ...], calibrator_flags: tuple[str, ...]) -> Phase:
    samples: list[dict] = []
    matcher = MatcherStats()
    with HostsNetwork(work, rig, cameras_per_host=CAMERAS_PER_HOST, features_period_s=features_period_s,
                      matcher_flags=matcher_flags, calibrator_flags=calibrator_flags) as net:
        net.session.declare_subscriber(keys.node_stats(net.rig_name, "matcher", "matcher"), matcher)
        start_s = time.monotonic()
        while time.monotonic() - start_s < 60 * minutes:
            time.sleep(sample_s)
            net.launch.check()
            stats = matcher.latest
            children = net.launch.children
            samples.append({"t_s": round(time.monotonic() - start_s, 1),
                            "cpu_s": {c.name: cpu_s(c.process.pid) for c in children},
                            "parts_cpu_s": {c.name: host_parts_cpu_s(c.process.pid) for c in children
                                            if c.name.startswith("host-")},
                            "rss_mb": {c.name: round(rss_mb(c.process.pid), 1) for c in children},
                            "frame_sets": stats.frames if stats else 0})
            print(progress(samples, len(net.calibrations)), file=sys.stderr, flush=True)
        calibrations = [(t - start_s, d) for t, d in net.calibrations]
    return Phase(len(rig["cameras"]), minutes, samples, calibrations, parse_rig(rig).simulated_truth())


def progress(samples: list[dict], n_calibrations: int) -> str:
    last = samples[-1]
    previous = samples[-2] if len(samples) > 1 else {"t_s": 0.0, "cpu_s": dict.fromkeys(last["cpu_s"], 0.0)}
    span_s = max(last["t_s"] - previous["t_s"], 1e-9)
    busiest = sorted(last["cpu_s"], key=lambda n: previous["cpu_s"].get(n, 0.0) - last["cpu_s"][n])[:3]
    cpu = ", ".join(f"{n} {100 * (last['cpu_s'][n] - previous['cpu_s'].get(n, 0.0)) / span_s:.0f}%" for n in busiest)
    return (f"  {last['t_s']:6.0f} s: {n_calibrations} good calibrations, {last['frame_sets']} frame sets matched; "
            f"CPU {cpu}; RSS {sum(last['rss_mb'].values()):.0f} MB in all")


def table(phase: Phase) -> list[str]:
    """The phase as a Markdown table: one row per process, then the rates."""
    cpu, grown, last = phase.cpu_percent(), phase.growth(), phase.samples[-1]
    window = [s for s in phase.samples if s["t_s"] >= phase.window_s] or phase.samples[-1:]
    first = rss_floor([s for s in window if s["t_s"] < window[0]["t_s"] + LEVEL_S])
    floor = rss_floor([s for s in window if s["t_s"] > last["t_s"] - LEVEL_S])
    peak = rss_floor(window, pick=max)
    rows = [f"| process | CPU % of a core | RSS floor MB, first minute from {phase.window_s:.0f} s | last minute | "
            "peak MB | floor growth |", "|---|---|---|---|---|---|"]
    for name in last["rss_mb"]:
        g = grown.get(name)
        rows.append(f"| {name} | {cpu.get(name, 0.0):.0f} | {first.get(name, 0.0):.0f} | {floor.get(name, 0.0):.0f} | "
                    f"{peak.get(name, 0.0):.0f} | {'-' if g is None else f'{100 * g:+.1f}%'} |")
    rows.append(f"| all | {sum(cpu.values()):.0f} | {sum(first.values()):.0f} | {sum(floor.values()):.0f} | | |")
    rows += ["", "RSS floor (MB) minute by minute:", *curve(phase.samples, phase.window_s)]
    rate, latencies = phase.frame_sets_per_s(), phase.latencies_s()
    rows.append("")
    first = f"the first after {phase.calibrations[0][0]:.0f} s" if phase.calibrations else "none"
    rows.append(f"{phase.n_cameras} cameras, {phase.minutes:g} min: {len(phase.calibrations)} good calibrations "
                f"({first}); "
                f"calibrated frame sets per second from {phase.window_s:.0f} s: "
                f"{'n/a (fewer than two calibrations)' if rate is None else f'{rate:.2f}'}")
    if latencies:
        rows.append(f"capture->calibration: median {statistics.median(latencies):.1f} s, max {latencies[-1]:.1f} s")
    errors = [e for e in phase.errors() if "scale_error_rel" in e]
    if errors:
        final = errors[-1]
        scale = statistics.median(abs(e["scale_error_rel"]) for e in errors)
        rows.append(f"vs truth, the last of {final['cameras']} cameras: scale {100 * final['scale_error_rel']:+.3f}% "
                    f"(sigma {100 * (final['scale_sigma_rel'] or float('nan')):.3f}%), "
                    f"focal <= {100 * final['max_focal_error_rel']:.3f}%; median of the {len(errors)} from "
                    f"{phase.window_s:.0f} s: |scale| {100 * scale:.3f}%, "
                    f"focal <= {100 * statistics.median(e['max_focal_error_rel'] for e in errors):.3f}%")
    parts = phase.host_parts_percent()
    rows.append("camera hosts' threads, % of a core: "
                + ", ".join(f"{part} {percent:.0f}" for part, percent in parts.items()))
    if rate:
        per_set = {name: percent / 100 / rate for name, percent in cpu.items()}
        hosts = sum(v for name, v in per_set.items() if name.startswith("host-"))
        rows.append(f"CPU s per calibrated frame set: hosts {hosts:.2f} ("
                    + ", ".join(f"{part} {percent / 100 / rate:.2f}" for part, percent in parts.items()) + "), "
                    + ", ".join(f"{name} {v:.2f}" for name, v in per_set.items() if not name.startswith("host-"))
                    + f"; all {sum(per_set.values()):.2f}")
        # The drivers render every frame whatever the matcher takes: a cost per second, not per set
        # (when they had the CPU for every frame; on a loaded machine they skip some).
        fixed = parts["drivers"] / 100 if parts["drivers"] > 0 else 0.0
        rest = sum(per_set.values()) - fixed / rate
        rows.append(f"on 2 free cores at this CPU per set: {2 / sum(per_set.values()):.2f} sets/s; with the drivers "
                    f"as a cost per second ({fixed:.2f} cores): {(2 - fixed) / rest:.2f} sets/s")
    per_set = phase.matcher_cpu_per_set_s()
    rows.append(f"matcher: {last['frame_sets']} frame sets matched, "
                f"{'n/a' if per_set is None else f'{per_set:.3f}'} CPU s per frame set")
    return rows


def verdicts(main: Phase, compare: Phase | None) -> list[tuple[str, bool]]:
    """(target, met) for each target of the run."""
    rate = main.frame_sets_per_s()
    worst = max(main.growth().values(), default=0.0)
    found = [(f"calibrated frame sets per second >= {MIN_FRAME_SETS_PER_S:g}: "
              f"{'n/a' if rate is None else f'{rate:.2f}'}", rate is not None and rate >= MIN_FRAME_SETS_PER_S),
             (f"RSS floor growth after {main.window_s:.0f} s < {100 * GROWTH_LIMIT:.0f}%: largest {100 * worst:+.1f}%",
              worst < GROWTH_LIMIT)]
    if compare is not None:
        many, few = main.matcher_cpu_per_set_s(), compare.matcher_cpu_per_set_s()
        ratio = many / few if many is not None and few else None
        found.append((f"matcher CPU per frame set, {main.n_cameras} vs {compare.n_cameras} cameras <= "
                      f"{MAX_MATCHER_CPU_RATIO:g}x: {'n/a' if ratio is None else f'{ratio:.2f}x'} "
                      f"({'n/a' if many is None else f'{many:.3f}'} s vs {'n/a' if few is None else f'{few:.3f}'} s)",
                      ratio is not None and ratio <= MAX_MATCHER_CPU_RATIO))
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0, help="of the 16-camera run (default: 10)")
    parser.add_argument("--compare-minutes", type=float, default=3.0,
                        help="of the 4-camera run for the matcher's CPU per frame set (0: none; default: 3)")
    parser.add_argument("--rig", type=Path, default=ROOT / "config" / "hosts16.yaml",
                        help="a simulated rig whose first four cameras hold its stereo pair "
                             "(default: config/hosts16.yaml)")
    parser.add_argument("--features-period-s", type=float, default=0.5,
                        help="the feature stages' grid of capture times (default: 0.5, two frame sets a second)")
    parser.add_argument("--sample-s", type=float, default=10.0)
    parser.add_argument("--matcher-args", default="", help="further flags of the matcher, in one string")
    parser.add_argument("--calibrator-args", default="",
                        help="further flags of the calibrator, in one string (--rerun serve: as docker/compose.yaml "
                             "runs it)")
    parser.add_argument("--samples", type=Path, help="write every sample of the main run here (JSON lines)")
    args = parser.parse_args()
    rig = yaml.safe_load(args.rig.read_text())
    options = dict(sample_s=args.sample_s, features_period_s=args.features_period_s,
                   matcher_flags=tuple(shlex.split(args.matcher_args)),
                   calibrator_flags=tuple(shlex.split(args.calibrator_args)))
    phases = [(rig, args.minutes)]
    if args.compare_minutes > 0:
        few = {**rig, "rig": f"{rig['rig']}_first{CAMERAS_PER_HOST}", "cameras": rig["cameras"][:CAMERAS_PER_HOST]}
        phases.append((few, args.compare_minutes))
    results = []
    for phase_rig, minutes in phases:
        n = len(phase_rig["cameras"])
        print(f"{phase_rig['rig']}: {n} cameras on {-(-n // CAMERAS_PER_HOST)} hosts, {minutes:g} min:",
              file=sys.stderr, flush=True)
        with tempfile.TemporaryDirectory(prefix="camnet-bench-hosts-") as tmp:
            results.append(run_phase(Path(tmp), phase_rig, minutes=minutes, **options))
    if args.samples is not None:
        args.samples.write_text("".join(json.dumps(s) + "\n" for s in results[0].samples))
    for phase in results:
        print("\n" + "\n".join(table(phase)))
    found = verdicts(results[0], results[1] if len(results) > 1 else None)
    print()
    for text, met in found:
        print(f"{'met' if met else 'NOT MET'}: {text}")
    return 0 if all(met for _, met in found) else 1


if __name__ == "__main__":
    sys.exit(main())
