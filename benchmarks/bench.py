"""Benchmarks: ``python -m benchmarks.bench {solvers,estimate,ml}``.

Timings pin BLAS to one thread (threadpoolctl and the usual environment variables) and report
medians over repeated runs on data from :mod:`rs_localizer.sim.synthetic`. Numbers depend on the
machine; docs/accuracy.md quotes the ones measured on a 2-core machine.

``solvers``: median microseconds per call of every solver, per linear iteration, and the
amortized time per hypothesis when K minimal problems are solved at once (the batched kernels
RANSAC uses). ``estimate``: one interleaved run (see :func:`bench_estimate`) of the full robust
estimator for every solver on rolling-shutter frames, ``r6p_1lin`` on global-shutter frames, and
PoseLib's ``estimate_absolute_pose`` on the global-shutter frames at matched settings and at its
defaults (and, for accuracy, PoseLib and OpenCV's ``solvePnPRansac`` on the RS frames):
wall-clock and CPU milliseconds per frame, accuracy, the ratios of ours to PoseLib's global-shutter
time, and our stage medians. ``ml``: our estimate against the maximum-likelihood fit (SciPy on the
true inliers) at RS speed 1.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from rs_localizer.estimation.estimate import (
    SOLVERS,
    EstimateOptions,
    RansacOptions,
    estimate_rs_pose,
)
from rs_localizer.experiments.references import (
    ml_fit,
    opencv_estimate,
    poselib_estimate,
    poselib_matched_options,
)
from rs_localizer.experiments.timing import bench_solvers, one_thread
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.synthetic import make_frame, paper_camera, protocol_options
from rs_localizer.solvers.registry import SOLVERS as SOLVER_TABLE

#: paper Table 1 (2.5 GHz i7, C++/Matlab-MEX), microseconds per iteration (from the registry)
PAPER_US = {s.name: s.paper_us for s in SOLVER_TABLE.values() if s.paper_us is not None}


#: methods of ``bench estimate`` whose per-frame time ratios it prints (numerator, denominator)
OURS_RS, OURS_GS = "r6p_1lin, RS frames", "r6p_1lin, GS frames"
PL_MATCHED_GS = "PoseLib matched, GS frames"
PL_DEFAULT_GS = "PoseLib defaults, GS frames"
RATIOS = (
    (OURS_RS, PL_MATCHED_GS),
    (OURS_RS, PL_DEFAULT_GS),
    (OURS_GS, PL_MATCHED_GS),
    (OURS_GS, PL_DEFAULT_GS),
)


def bench_estimate(
    frames: int = 50,
    n_points: int = 500,
    rs_speed: float = 0.5,
    noise_px: float = 1.0,
    outlier_ratio: float = 0.3,
    solvers=None,
    baselines: bool = True,
    seed: int = 0,
) -> list[dict]:
    """Time the full estimator per solver and the global-shutter baselines in ONE interleaved
    run: frame k of every method runs before frame k + 1 of any (the order of the methods
    rotates from frame to frame), so machine load affects all methods alike.

    Methods: our estimator with every solver on RS frames (``rs_speed``), ``r6p_1lin`` on
    global-shutter frames of the same protocol (``rs_speed = 0``), PoseLib's
    ``estimate_absolute_pose`` on the global-shutter frames with matched settings
    (:func:`poselib_matched_options`) and with its default ``RansacOptions`` (our threshold),
    and PoseLib (matched) and OpenCV's ``solvePnPRansac`` on the RS frames (accuracy next to
    ours). Each frame is estimated from scratch (a cold frame: no prior from a previous one).

    Returns rows with the wall-clock (``ms_median``, ``ms_p95``) and CPU time of the calling
    thread (``cpu_ms_median``, ``time.thread_time``, which a busy machine inflates less),
    median rotation error (deg), position error (% of the scene distance), angular velocity
    error (% of the true one; RS frames, our solvers), inliers, and our stage medians.
    """
    cam = paper_camera()
    rs = [
        make_frame(
            seed * 100003 + k,
            n_points,
            rs_speed=rs_speed,
            noise_px=noise_px,
            outlier_ratio=outlier_ratio,
        )
        for k in range(frames)
    ]
    gs = [
        make_frame(
            seed * 100003 + 50000 + k,
            n_points,
            rs_speed=0.0,
            noise_px=noise_px,
            outlier_ratio=outlier_ratio,
        )
        for k in range(frames)
    ]
    opts = EstimateOptions()
    matched = poselib_matched_options(opts)
    methods = {}  # name -> (frames, fn)
    for s in solvers or SOLVERS:
        o = (
            EstimateOptions(ransac=RansacOptions(max_iterations=100)) if s == "r6p" else opts
        )  # 20 roots per sample
        name = OURS_RS if s == "r6p_1lin" else f"{s}, RS frames"
        methods[name] = (rs, lambda f, s=s, o=o: _ours(f, cam, s, o))
    methods[OURS_GS] = (gs, lambda f: _ours(f, cam, "r6p_1lin", opts))
    methods[PL_MATCHED_GS] = (
        gs,
        lambda f: poselib_estimate(f, cam, opts.ransac.threshold_px, matched),
    )
    methods[PL_DEFAULT_GS] = (gs, lambda f: poselib_estimate(f, cam, opts.ransac.threshold_px))
    if baselines:
        methods["PoseLib matched, RS frames"] = (
            rs,
            lambda f: poselib_estimate(f, cam, opts.ransac.threshold_px, matched),
        )
        methods["OpenCV solvePnPRansac P3P, RS frames"] = (
            rs,
            lambda f: opencv_estimate(f, cam, opts.ransac.threshold_px),
        )
    names = list(methods)
    for name in names:  # warm-up (numba compilation, caches)
        data, fn = methods[name]
        fn(data[0])
    acc = {name: dict(wall=[], cpu=[], rot=[], pos=[], om=[], inl=[], stages=[]) for name in names}
    for k in range(frames):
        for name in names[k % len(names) :] + names[: k % len(names)]:
            data, fn = methods[name]
            f = data[k]
            c0, t0 = time.thread_time(), time.perf_counter()
            R, C, n, *extra = fn(f)
            t1, c1 = time.perf_counter(), time.thread_time()
            a = acc[name]
            a["wall"].append(t1 - t0)
            a["cpu"].append(c1 - c0)
            if R is None:
                a["rot"].append(180.0)
                a["pos"].append(100.0)
            else:
                a["rot"].append(rotation_angle_deg(R, f.R))
                a["pos"].append(
                    100 * np.linalg.norm(-R.T @ C - f.position) / np.linalg.norm(f.position)
                )
            a["inl"].append(n)
            if extra:
                timings, om = extra
                a["stages"].append(timings)
                if om is not None and np.linalg.norm(f.angular_velocity) > 0:
                    a["om"].append(
                        100
                        * np.linalg.norm(om - f.angular_velocity)
                        / np.linalg.norm(f.angular_velocity)
                    )
    rows = []
    for name in names:
        a = acc[name]
        rows.append(
            dict(
                method=name,
                ms_median=1e3 * np.median(a["wall"]),
                ms_p95=1e3 * np.percentile(a["wall"], 95),
                cpu_ms_median=1e3 * np.median(a["cpu"]),
                rot_deg=np.median(a["rot"]),
                pos_pct=np.median(a["pos"]),
                om_pct=np.median(a["om"]) if a["om"] else None,
                inliers=np.median(a["inl"]),
                stages_ms={s: 1e3 * np.median([d.get(s, 0.0) for d in a["stages"]]) for s in STAGES}
                if a["stages"]
                else None,
            )
        )
    return rows


#: stages of :attr:`RSPoseEstimate.timings` reported by ``bench estimate``
STAGES = ("prepare", "ransac", "local_optimization", "refine")


def _ours(f, cam, solver, opts):
    e = estimate_rs_pose(f.points_px, f.X, cam, solver, opts)
    if not e.success:
        return None, None, 0, e.timings, None
    return e.model.R, e.model.C, e.num_inliers, e.timings, e.pose.angular_velocity


def bench_ml(
    frames: int = 40,
    n_points: int = 500,
    rs_speed: float = 1.0,
    noise_px: float = 1.0,
    outlier_ratio: float = 0.3,
    seed: int = 0,
) -> dict:
    """Our ``r6p_1lin`` estimate against the maximum-likelihood fit (:func:`ml_fit`) on the same
    frames: median angular velocity error of both (% of the true |omega|), the median and
    largest distance between the two (% of |omega|), and the median rotation errors (deg).
    The estimator runs with :func:`protocol_options` (no motion-plausibility bounds)."""
    from rs_localizer.estimation.estimate import physical_velocities

    opts = protocol_options()

    cam = paper_camera()
    ours, ml, apart, rot_ours, rot_ml = [], [], [], [], []
    for k in range(frames):
        f = make_frame(
            seed * 100003 + k,
            n_points,
            rs_speed=rs_speed,
            noise_px=noise_px,
            outlier_ratio=outlier_ratio,
        )
        e = estimate_rs_pose(f.points_px, f.X, cam, "r6p_1lin", opts)
        R, C, w, t = ml_fit(f)
        om = physical_velocities(R, C, w, t, cam.seconds_per_unit_r)[0]
        n = np.linalg.norm(f.angular_velocity)
        ours.append(100 * np.linalg.norm(e.pose.angular_velocity - f.angular_velocity) / n)
        ml.append(100 * np.linalg.norm(om - f.angular_velocity) / n)
        apart.append(100 * np.linalg.norm(e.pose.angular_velocity - om) / n)
        rot_ours.append(rotation_angle_deg(e.model.R, f.R))
        rot_ml.append(rotation_angle_deg(R, f.R))
    return dict(
        frames=frames,
        rs_speed=rs_speed,
        omega_pct_ours=float(np.median(ours)),
        omega_pct_ml=float(np.median(ml)),
        apart_pct_median=float(np.median(apart)),
        apart_pct_max=float(np.max(apart)),
        rot_deg_ours=float(np.median(rot_ours)),
        rot_deg_ml=float(np.median(rot_ml)),
    )


def _fmt(v, spec):
    width = int(spec.split(".")[0].rstrip("dfs") or 0)
    return format(v, spec) if isinstance(v, (int, float, np.floating)) else "-".rjust(width)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.bench", description=__doc__.split("\n")[0]
    )
    sub = p.add_subparsers(dest="what", required=True)
    ps = sub.add_parser("solvers", help="per-solver microseconds (single and batched)")
    ps.add_argument("--repeat", type=int, default=200)
    ps.add_argument("--batch", type=int, default=1000)
    pe = sub.add_parser("estimate", help="per-frame milliseconds of the robust estimator")
    pe.add_argument("--frames", type=int, default=50)
    pe.add_argument("--points", type=int, default=500)
    pe.add_argument("--speed", type=float, default=0.5, help="RS speed (1 = 30 deg, 0.3 per frame)")
    pe.add_argument("--noise", type=float, default=1.0)
    pe.add_argument("--outliers", type=float, default=0.3)
    pe.add_argument("--solvers", nargs="*", default=None)
    pe.add_argument(
        "--no-baselines",
        action="store_true",
        help="skip PoseLib and OpenCV on the RS frames (the global-shutter "
        "references of the ratios always run)",
    )
    pm = sub.add_parser("ml", help="our estimate against the maximum-likelihood fit")
    pm.add_argument("--frames", type=int, default=40)
    pm.add_argument("--speed", type=float, default=1.0, help="RS speed")
    a = p.parse_args(argv)
    with one_thread():
        if a.what == "solvers":
            rows = bench_solvers(a.repeat, a.batch)
            print(
                f"{'solver':<16}{'us/call':>10}{'us/iter':>10}{'batched us/hyp':>16}"
                f"{'batched us/iter':>17}{'paper us/iter':>15}"
            )
            for r in rows:
                print(
                    f"{r['solver']:<16}{_fmt(r.get('us_call'), '10.1f')}"
                    f"{_fmt(r.get('us_per_iteration'), '10.2f')}"
                    f"{_fmt(r.get('us_batched'), '16.2f')}"
                    f"{_fmt(r.get('us_batched_per_iteration'), '17.2f')}"
                    f"{_fmt(PAPER_US.get(r['solver']), '15d')}"
                )
        elif a.what == "ml":
            r = bench_ml(a.frames, rs_speed=a.speed)
            print(
                f"{r['frames']} frames at RS speed {r['rs_speed']} (500 correspondences, 1 px "
                f"noise, 30% outliers): median angular velocity error, % of |omega|: ours "
                f"{r['omega_pct_ours']:.3f}, maximum-likelihood fit on the true inliers "
                f"{r['omega_pct_ml']:.3f}; ours - ML: median {r['apart_pct_median']:.3f}, max "
                f"{r['apart_pct_max']:.3f}; median rotation error: ours "
                f"{r['rot_deg_ours']:.4f} deg, ML {r['rot_deg_ml']:.4f} deg"
            )
        else:
            load0 = os.getloadavg()
            rows = bench_estimate(
                a.frames, a.points, a.speed, a.noise, a.outliers, a.solvers, not a.no_baselines
            )
            load1 = os.getloadavg()
            by = {r["method"]: r for r in rows}
            print(
                f"{a.frames} frames per method, interleaved; {a.points} correspondences, "
                f"{a.noise} px noise, {100 * a.outliers:.0f}% outliers; RS frames at RS speed "
                f"{a.speed} ({30 * a.speed:.0f} deg, {0.3 * a.speed:.2f} per frame), GS frames "
                f"at 0; one BLAS/numba thread; 1-min load average {load0[0]:.2f} -> "
                f"{load1[0]:.2f} on {os.cpu_count()} CPUs"
            )
            print(
                f"{'method':<38}{'ms median':>10}{'ms p95':>9}{'CPU ms':>9}"
                f"{'rot deg':>10}{'pos %':>8}{'omega %':>9}{'inliers':>9}"
            )
            for r in rows:
                print(
                    f"{r['method']:<38}{r['ms_median']:10.2f}{r['ms_p95']:9.2f}"
                    f"{r['cpu_ms_median']:9.2f}{r['rot_deg']:10.3f}{r['pos_pct']:8.2f}"
                    f"{_fmt(r['om_pct'], '9.2f')}{r['inliers']:9.0f}"
                )
            print("\nratios of median times (wall-clock, CPU):")
            for num, den in RATIOS:
                if num in by and den in by:
                    print(
                        f"  {num} / {den}: {by[num]['ms_median'] / by[den]['ms_median']:.2f}, "
                        f"{by[num]['cpu_ms_median'] / by[den]['cpu_ms_median']:.2f}"
                    )
            print("\nmedian ms per stage (ours, wall-clock): " + ", ".join(STAGES))
            for r in rows:
                if r["stages_ms"]:
                    print(
                        f"{r['method']:<38}" + "".join(f"{r['stages_ms'][k]:10.2f}" for k in STAGES)
                    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
