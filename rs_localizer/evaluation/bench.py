"""Benchmarks: ``python -m rs_localizer.evaluation.bench {solvers,estimate}``.

Timings pin BLAS to one thread (threadpoolctl and the usual environment variables) and report
medians over repeated runs on data from :mod:`rs_localizer.sim.synthetic`. Numbers depend on the
machine; the README quotes the ones measured on the project's 2-core CI machine.

``solvers``: median microseconds per call of every solver, per linear iteration, and the
amortized time per hypothesis when K minimal problems are solved at once (the batched kernels
RANSAC uses). ``estimate``: median and p95 milliseconds per frame of the full robust estimator
for every solver, next to PoseLib's ``estimate_absolute_pose`` and OpenCV's
``solvePnPRansac`` (global shutter) on the same frames, with their accuracy.
"""

from __future__ import annotations

import argparse
import os
import time

if __name__ == "__main__":  # one BLAS/numba thread, set before numpy loads (not on import)
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                 "NUMBA_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

try:  # noqa: E402
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover
    threadpool_limits = None

from ..estimation.estimate import SOLVERS, EstimateOptions, estimate_rs_pose  # noqa: E402
from ..geometry import rotation_angle_deg  # noqa: E402
from ..solvers.registry import SOLVERS as SOLVER_TABLE  # noqa: E402
from ..sim.synthetic import make_frame, paper_camera  # noqa: E402

#: paper Table 1 (2.5 GHz i7, C++/Matlab-MEX), microseconds per iteration (from the registry)
PAPER_US = {s.name: s.paper_us for s in SOLVER_TABLE.values() if s.paper_us is not None}


def _median_us(fn, repeat: int) -> float:
    fn()  # warm-up (numba compilation, caches)
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts) * 1e6)


def bench_solvers(repeat: int = 200, batch: int = 1000, seed: int = 0) -> list[dict]:
    """Time every solver. Returns rows with ``us_call``, ``us_per_iteration`` (iterative
    solvers: the slope between 1 and 5 forced iterations), ``us_batched`` (per hypothesis, K =
    ``batch``) and ``us_batched_per_iteration``."""
    from .. import solvers as S

    rng = np.random.default_rng(seed)
    frames = [make_frame(rng, 9, rs_speed=0.5, angle_from_identity=0.0) for _ in range(batch)]
    x9 = np.array([f.x for f in frames])
    X9 = np.array([f.X for f in frames])
    x6, X6 = x9[:, :6].copy(), X9[:, :6].copy()
    f0 = frames[0]
    rows = []
    rows.append(dict(solver="p3p", us_call=_median_us(lambda: S.p3p(f0.x[:3], f0.X[:3]), repeat),
                     note="PoseLib"))
    rows.append(dict(solver="p3p (OpenCV)",
                     us_call=_median_us(lambda: S.p3p_opencv(f0.x[:3], f0.X[:3]), repeat)))
    rows.append(dict(solver="r6p", us_call=_median_us(lambda: S.r6p(f0.x[:6], f0.X[:6]),
                                                         max(repeat // 4, 10))))
    iterative = {"r6p_1lin": (S.r6p_1lin, S.r6p_1lin_batch),
                 "r6p_vC_wt": (S.r6p_vC_wt, S.r6p_vC_wt_batch),
                 "r6p_vCt_w": (S.r6p_vCt_w, S.r6p_vCt_w_batch),
                 "r6p_vCt_wt": (S.r6p_vCt_wt, S.r6p_vCt_wt_batch)}
    for name, (single, batched) in iterative.items():
        t1 = _median_us(lambda: single(f0.x[:6], f0.X[:6], iterations=1), repeat)
        t5 = _median_us(lambda: single(f0.x[:6], f0.X[:6], iterations=5, tol=-1.0), repeat)
        b1 = _median_us(lambda: batched(x6, X6, iterations=1), 20) / batch
        b5 = _median_us(lambda: batched(x6, X6, iterations=5, tol=-1.0), 20) / batch
        rows.append(dict(solver=name, us_call=t5, us_per_iteration=(t5 - t1) / 4,
                         us_batched=b5, us_batched_per_iteration=(b5 - b1) / 4,
                         us_batched_1_iteration=b1))
    rows.append(dict(solver="r9p", us_call=_median_us(lambda: S.r9p(f0.x, f0.X), repeat),
                     us_batched=_median_us(lambda: S.r9p_batch(x9, X9), 20) / batch))
    rows.append(dict(solver="r6p_joined",
                     us_call=_median_us(lambda: S.r6p_joined(f0.x[:6], f0.X[:6]), repeat)))
    return rows


def _poselib_estimate(f, cam, threshold_px):
    import poselib

    K = cam.K
    camera = {"model": "PINHOLE", "width": cam.width, "height": cam.height,
              "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]}
    pose, info = poselib.estimate_absolute_pose(f.points_px, f.X, camera,
                                                {"max_reproj_error": threshold_px}, {})
    return np.asarray(pose.R), np.asarray(pose.t), int(info["num_inliers"])


def _opencv_estimate(f, cam, threshold_px):
    import cv2

    ok, rvec, tvec, inl = cv2.solvePnPRansac(f.X, f.points_px, cam.K, None,
                                              reprojectionError=threshold_px,
                                              iterationsCount=1000, confidence=0.9999,
                                              flags=cv2.SOLVEPNP_P3P)
    if not ok:
        return None, None, 0
    return cv2.Rodrigues(rvec)[0], tvec.ravel(), 0 if inl is None else len(inl)


def bench_estimate(frames: int = 50, n_points: int = 500, rs_speed: float = 0.5,
                   noise_px: float = 1.0, outlier_ratio: float = 0.3, solvers=None,
                   baselines: bool = True, seed: int = 0) -> list[dict]:
    """Time the full estimator per solver (and the global-shutter baselines) on the same
    frames. Returns rows with ``ms_median``, ``ms_p95``, median rotation error (deg), median
    position error (% of scene distance) and inliers."""
    cam = paper_camera()
    data = [make_frame(seed * 100003 + k, n_points, rs_speed=rs_speed, noise_px=noise_px,
                       outlier_ratio=outlier_ratio) for k in range(frames)]
    opts = EstimateOptions()
    methods = {}
    for s in solvers or SOLVERS:
        if s == "r6p":  # 1-2 ms per call x up to 20 roots: cap the iterations as the paper does
            methods[s] = lambda f, s=s: _ours(f, cam, s, EstimateOptions(max_iterations=100))
        else:
            methods[s] = lambda f, s=s: _ours(f, cam, s, opts)
    if baselines:
        methods["PoseLib estimate_absolute_pose (GS)"] = lambda f: _poselib_estimate(
            f, cam, opts.threshold_px)
        methods["OpenCV solvePnPRansac P3P (GS)"] = lambda f: _opencv_estimate(
            f, cam, opts.threshold_px)
    rows = []
    for name, fn in methods.items():
        fn(data[0])  # warm-up
        ts, rot, pos, inl, stages = [], [], [], [], []
        for f in data:
            t0 = time.perf_counter()
            R, C, n, *st = fn(f)
            ts.append(time.perf_counter() - t0)
            stages += st
            if R is None:
                rot.append(180.0)
                pos.append(100.0)
            else:
                rot.append(rotation_angle_deg(R, f.R))
                pos.append(100 * np.linalg.norm(-R.T @ C - f.position)
                           / np.linalg.norm(f.position))
            inl.append(n)
        rows.append(dict(method=name, ms_median=1e3 * np.median(ts),
                         ms_p95=1e3 * np.percentile(ts, 95), rot_deg=np.median(rot),
                         pos_pct=np.median(pos), inliers=np.median(inl),
                         stages_ms={k: 1e3 * np.median([d.get(k, 0.0) for d in stages])
                                    for k in STAGES} if stages else None))
    return rows


#: stages of :attr:`RSPoseEstimate.timings` reported by ``bench estimate``
STAGES = ("prepare", "ransac", "local_optimization", "refine")


def _ours(f, cam, solver, opts):
    e = estimate_rs_pose(f.points_px, f.X, cam, solver, opts)
    if not e.success:
        return None, None, 0, e.timings
    return e.R, e.C, e.num_inliers, e.timings


def _fmt(v, spec):
    width = int(spec.split(".")[0].rstrip("dfs") or 0)
    return format(v, spec) if isinstance(v, (int, float, np.floating)) else "-".rjust(width)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m rs_localizer.evaluation.bench", description=__doc__.split("\n")[0])
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
    pe.add_argument("--no-baselines", action="store_true")
    a = p.parse_args(argv)
    ctx = threadpool_limits(1) if threadpool_limits else None
    try:
        if a.what == "solvers":
            rows = bench_solvers(a.repeat, a.batch)
            print(f"{'solver':<16}{'us/call':>10}{'us/iter':>10}{'batched us/hyp':>16}"
                  f"{'batched us/iter':>17}{'paper us/iter':>15}")
            for r in rows:
                print(f"{r['solver']:<16}{_fmt(r.get('us_call'), '10.1f')}"
                      f"{_fmt(r.get('us_per_iteration'), '10.2f')}"
                      f"{_fmt(r.get('us_batched'), '16.2f')}"
                      f"{_fmt(r.get('us_batched_per_iteration'), '17.2f')}"
                      f"{_fmt(PAPER_US.get(r['solver']), '15d')}")
        else:
            rows = bench_estimate(a.frames, a.points, a.speed, a.noise, a.outliers, a.solvers,
                                  not a.no_baselines)
            ref = next((r for r in rows if r["method"] == "r6p_1lin"), rows[0])
            print(f"{a.frames} frames, {a.points} correspondences, {a.noise} px noise, "
                  f"{100 * a.outliers:.0f}% outliers, RS speed {a.speed} "
                  f"({30 * a.speed:.0f} deg, {0.3 * a.speed:.2f} per frame); one BLAS thread")
            print(f"{'method':<38}{'ms median':>10}{'ms p95':>9}{'x r6p_1lin':>11}"
                  f"{'rot deg':>10}{'pos %':>8}{'inliers':>9}")
            for r in rows:
                print(f"{r['method']:<38}{r['ms_median']:10.2f}{r['ms_p95']:9.2f}"
                      f"{r['ms_median'] / ref['ms_median']:11.2f}{r['rot_deg']:10.3f}"
                      f"{r['pos_pct']:8.2f}{r['inliers']:9.0f}")
            print("\nmedian ms per stage (ours): " + ", ".join(STAGES))
            for r in rows:
                if r["stages_ms"]:
                    print(f"{r['method']:<38}" + "".join(f"{r['stages_ms'][k]:10.2f}"
                                                         for k in STAGES))
    finally:
        if ctx is not None:
            ctx.unregister() if hasattr(ctx, "unregister") else None
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
