"""Accuracy and cost of the calibration engine on simulated rigs like the paper's.

Prints, per scenario and method, the median scale error and shape error beside
their Cramer-Rao bounds (computed at the ground truth with the same free
parameters), over seeded trials; then solve times as the network grows, a
warm-started re-solve after 5% new tracks, and a re-solve after one camera moved
(warm, with that camera reset); beside them, in the same run, COLMAP's bundle
adjustment (pycolmap, benchmarks/colmap_anchor.py) of the same tracks from the
same start with the same free parameters.

    python benchmarks/bench_engine.py [--seeds 20] [--repeats 3] [--only accuracy|timing] [--sizes 16x1000,...]
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from dataclasses import replace

import numpy as np
from colmap_anchor import AnchorSolver, camnet_start, colmap_adjust

from camnet.model.accuracy import point_weights, scale_error, shape_rms_m
from camnet.sim.bounds import cramer_rao
from camnet.sim.simulate import make_rig, move_camera, observe
from camnet.solve import Options, calibrate

SCENARIOS = [
    ("paper rig", dict(), dict(), frozenset({"f"})),
    ("15% outliers", dict(), dict(outlier_fraction=0.15), frozenset({"f"})),
    ("partial visibility 60%", dict(), dict(visibility=0.6), frozenset({"f"})),
    # With every pose free, four cameras and 57 points do not determine free principal points.
    (
        "principal points <=25 px off, free, M=8 N=200",
        dict(pp_offset_px=25.0, n_cameras=8, n_points=200),
        dict(),
        frozenset({"f", "pp"}),
    ),
]


def accuracy(seeds: int, noise_px: float) -> None:
    print(f"accuracy over {seeds} seeds, M = 4, N = 57 unless named, l = 0.125 m, noise {noise_px} px")
    print(
        f"{'scenario':<48} {'method':<14} {'|scale err| med %':>18} {'CRB %':>8} {'ratio':>6} "
        f"{'shape med mm':>13} {'bound mm':>9} {'ratio':>6} {'fails':>6}"
    )
    for name, rig_args, obs_args, free in SCENARIOS:
        rows = {m: [] for m in ("paper", "refined", "unconstrained")}
        crb = []
        for seed in range(seeds):
            rig = make_rig(seed=seed, **rig_args)
            sim = observe(rig, noise_px=noise_px, seed=seed, **obs_args)
            for method in rows:
                try:
                    result = calibrate(sim.observations, Options(method=method, free=free))
                except Exception as exc:  # a failed solve is counted, not hidden
                    rows[method].append((np.nan, np.nan))
                    print(f"  {name} / {method} / seed {seed}: {exc}", file=sys.stderr)
                    continue
                cal = result.calibration
                X_true = rig.points[cal.point_ids]
                scale = scale_error(cal.points, X_true, point_weights(cal))
                rows[method].append((abs(scale), shape_rms_m(cal.points, X_true)))
                if method == "refined":
                    bound = cramer_rao(rig, result, noise_px)
                    crb.append((bound.scale_rel, bound.shape_m))
            print(".", end="", file=sys.stderr, flush=True)
        print(file=sys.stderr)
        crb_scale, crb_shape = np.nanmedian(np.array(crb), axis=0)
        for method, values in rows.items():
            v = np.array(values)
            fails = int(np.isnan(v[:, 0]).sum())
            s, sh = np.nanmedian(v[:, 0]), np.nanmedian(v[:, 1])
            print(
                f"{name:<48} {method:<14} {100 * s:>18.4f} {100 * crb_scale:>8.4f} {s / crb_scale:>6.2f} "
                f"{1e3 * sh:>13.3f} {1e3 * crb_shape:>9.3f} {sh / crb_shape:>6.2f} {fails:>6}"
            )


# COLMAP with camnet's parameters for the comparison: the focal length alone per camera, the stereo
# pair held (camnet's ideal pair), every other pose and every point free; Ceres's stopping rule
# as COLMAP sets it (no test on the cost's change, gradient tolerance 1e-4, at most 100 iterations).
ANCHOR = AnchorSolver(camera_model="SIMPLE_PINHOLE", hold_stereo_pair=True)
SAME_FREE = Options(free=frozenset({"f"}), halves=False)
# The timings are the solve's: its second opinion (two cold solves of half the tracks) is measured apart, by
# bench_second_opinion.py.
SOLVE_ONLY = Options(halves=False)


SIZES = ((4, 250), (8, 250), (16, 250), (4, 1000), (8, 1000), (16, 1000))  # (M, N)


def timing(repeats: int, sizes=SIZES) -> None:
    print("\nrefined solve time (median of repeats), 0.5 px noise, 60% visibility for non-stereo cameras")
    print("warm: after 5% new tracks (wall and CPU seconds, minor page faults); reset: after the last camera moved")
    print("  5 cm and 3 deg, with it reset")
    print("camnet vs COLMAP: the same tracks, start and free parameters (f; the stereo pair held); camnet's")
    print("  refined solve from the start with its covariance and report, COLMAP's bundle adjustment")
    print(f"  (pycolmap, Ceres: function tolerance {ANCHOR.function_tolerance:g}, gradient tolerance "
          f"{ANCHOR.gradient_tolerance:g}, at most {ANCHOR.max_num_iterations} iterations), no covariance;")
    print("  wall and CPU seconds (both solvers run on this one thread; CPU time is steadier on a shared machine)")
    print(f"{'M':>4} {'N':>6} {'observations':>13} {'cold s':>8} {'warm +5% s':>11} {'warm CPU s':>11} "
          f"{'warm faults':>12} {'reset s':>8} "
          f"{'camnet s':>9} {'COLMAP s':>9} {'ratio':>6} {'camnet CPU':>11} {'COLMAP CPU':>11} {'ratio':>6} "
          f"{'COLMAP its':>11}")
    for M, N in sizes:
        times: dict[str, list[float]] = {}
        for seed in range(repeats):
            rig = make_rig(n_cameras=M, n_points=N, seed=seed)
            obs = observe(rig, noise_px=0.5, seed=seed, visibility=0.6).observations
            measured = {**_network_times(rig, obs, N, seed), **_beside_colmap(obs, seed)}
            for name, seconds in measured.items():
                times.setdefault(name, []).append(seconds)
        med = {k: float(np.median(v)) for k, v in times.items()}
        print(
            f"{M:>4} {N:>6} {len(obs.uv):>13} {med['cold']:>8.3f} {med['warm']:>11.3f} {med['warm_cpu']:>11.3f} "
            f"{med['warm_faults']:>12.0f} {med['reset']:>8.3f} "
            f"{med['camnet']:>9.3f} {med['colmap']:>9.3f} {med['camnet'] / med['colmap']:>6.2f} "
            f"{med['camnet_cpu']:>11.3f} {med['colmap_cpu']:>11.3f} {med['camnet_cpu'] / med['colmap_cpu']:>6.2f} "
            f"{med['its']:>11.0f}",
            flush=True,
        )


def _beside_colmap(obs, seed: int) -> dict[str, float]:
    """camnet's solve from the start (wall, CPU) and COLMAP's bundle adjustment of the same, one after the other."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):  # as calibrate runs it
        cpu0 = time.thread_time()
        camnet_start(obs, seed)
        start_cpu = time.thread_time() - cpu0
    t0, cpu0 = time.perf_counter(), time.thread_time()
    result = calibrate(obs, replace(SAME_FREE, seed=seed))
    wall, cpu = time.perf_counter() - t0, time.thread_time() - cpu0
    assert result.covariance is not None
    anchor = colmap_adjust(obs, seed, ANCHOR)
    return {"camnet": wall - result.timings_s["initialise"], "camnet_cpu": cpu - start_cpu,
            "colmap": anchor.seconds, "colmap_cpu": anchor.cpu_seconds, "its": anchor.iterations}


def _network_times(rig, obs, N: int, seed: int) -> dict[str, float]:
    """Seconds of a cold solve (automatic free set) without the last 5% of tracks, a warm re-solve with
    them, and a re-solve after the last camera moved, with it reset."""
    n_old = int(0.95 * N)
    first = obs.track_index < n_old
    old = replace(
        obs,
        cam_index=obs.cam_index[first],
        track_index=obs.track_index[first],
        uv=obs.uv[first],
        track_ids=obs.track_ids[:n_old],
    )
    t0 = time.perf_counter()
    previous = calibrate(old, SOLVE_ONLY).calibration
    cold = time.perf_counter() - t0
    t0, cpu0, faults0 = time.perf_counter(), time.thread_time(), _minor_faults()
    now = calibrate(obs, SOLVE_ONLY, initial=previous).calibration
    warm, warm_cpu, warm_faults = time.perf_counter() - t0, time.thread_time() - cpu0, _minor_faults() - faults0
    bumped = rig.cameras[-1].id
    moved = move_camera(rig, bumped, shift_m=0.05, angle_deg=3.0, seed=seed)
    after = observe(moved, noise_px=0.5, seed=seed + 1, visibility=0.6).observations
    t0 = time.perf_counter()
    calibrate(after, SOLVE_ONLY, initial=now, reset_cameras={bumped})
    return {"cold": cold, "warm": warm, "warm_cpu": warm_cpu, "warm_faults": warm_faults,
            "reset": time.perf_counter() - t0}


def _minor_faults() -> int:
    """This thread's minor page faults so far: fresh memory the kernel maps and zeroes page by page."""
    return resource.getrusage(resource.RUSAGE_THREAD).ru_minflt


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--noise-px", type=float, default=0.5)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--only", choices=("accuracy", "timing"), help="run one of the two tables")
    parser.add_argument("--sizes", help="the timing table's networks, as MxN,... (default: all six)")
    args = parser.parse_args()
    sizes = SIZES if not args.sizes else tuple(tuple(int(v) for v in size.split("x")) for size in args.sizes.split(","))
    if args.only != "timing":
        accuracy(args.seeds, args.noise_px)
    if args.only != "accuracy":
        timing(args.repeats, sizes)


if __name__ == "__main__":
    main()
