"""Planar scenes: ``python -m benchmarks.bench_planar``.

Prints, per scene of :func:`rs_localizer.sim.planar.make_planar_frame` (``plane``: 300 points on
a plane 4 m away, tilted up to 35 deg; ``board``: a 6x7-corner checkerboard with 8 cm squares,
0.8-2 m away; ``depth``: the plane's points spread in depth, the 3D reference), 640x480, f = 600
px, 40 us/line, 0.5 px noise, no outliers unless ``--outliers``, camera turning at 1-3 rad/s and
moving at 0.2-1 m/s, the rotation error (median, p90, max; deg) and the angular and linear
velocity errors (median; rad/s, m/s) of:

- ``OpenCV IPPE (GS)``: ``cv2.solvePnP(SOLVEPNP_IPPE)`` on the true inliers (global shutter; the
  planar baseline; SQPnP on ``depth``, where IPPE does not apply), ``p3p``: our RANSAC with P3P
  (global shutter);
- ``r6p_1lin ML``: the estimator with the motion prior off (``motion_prior=None``);
  ``r6p_1lin MAP``: with the default prior (3 rad/s, 1.5 m/s); ``r6p_1lin MAP 3/2``: with a
  looser linear prior (3 rad/s, 2 m/s);
- the exact-model oracles: the refinement (:func:`rs_localizer.estimation.refine_rs_pose`)
  started from the ground truth on the true inliers, maximum likelihood and MAP with the same
  priors: the accuracy limit of each cost function.

For the estimator rows also the fraction of frames whose rotation and angular velocity errors
lie within the reported 3-sigma (NEES of the 3x3 covariance block below chi2_3(0.9973) = 14.16)
the median condition number of the data's information (``RSPoseEstimate.condition_number``) and
the median time per frame. Then the accuracy targets of :func:`check_targets`, checked. One
BLAS thread.

    python -m benchmarks.bench_planar [--frames 100] [--scenes plane board depth]
        [--outliers 0.0] [--linear-speed 0.2 1.0]
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from rs_localizer.estimation import EstimateOptions, MotionPrior, RansacOptions, estimate_rs_pose
from rs_localizer.estimation.refine import RefineSettings, refine_rs_pose
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import matrix_to_rotvec, rotation_angle_deg
from rs_localizer.sim.planar import make_planar_frame

__all__ = ["CHI2_3_3SIGMA", "main", "run_scene"]

#: chi-square quantile of 3 degrees of freedom at the 3-sigma probability (0.9973)
CHI2_3_3SIGMA = 14.16

#: a looser linear prior (3 rad/s, 2 m/s), for comparison with the default (3, 1.5)
LOOSE_PRIOR = MotionPrior(3.0, 2.0)


def _nees(err, cov) -> float:
    try:
        return float(err @ np.linalg.solve(cov, err))
    except np.linalg.LinAlgError:
        return float("inf")


def _estimator_row(f, solver, prior):
    t0 = time.perf_counter()
    e = estimate_rs_pose(
        f.points_px,
        f.X,
        f.camera,
        solver,
        EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12), motion_prior=prior),
    )
    ms = (time.perf_counter() - t0) * 1e3
    if not e.success:
        return dict(ok=False, ms=ms)
    out = dict(
        ok=True,
        ms=ms,
        rot=rotation_angle_deg(e.pose.orientation, f.orientation),
        cond=e.condition_number,
    )
    if solver != "p3p":
        out["ang"] = float(np.linalg.norm(e.pose.angular_velocity - f.angular_velocity))
        out["lin"] = float(np.linalg.norm(e.pose.linear_velocity - f.linear_velocity))
        if e.pose_covariance is not None and e.twist_covariance is not None:
            phi = matrix_to_rotvec(e.pose.orientation @ f.orientation.T)  # world axes, as reported
            out["nees_rot"] = _nees(phi, e.pose_covariance[3:, 3:])
            out["nees_ang"] = _nees(
                e.pose.angular_velocity - f.angular_velocity, e.twist_covariance[3:, 3:]
            )
    return out


def _oracle_row(f, prior):
    cam = f.camera
    x, r, _ = cam.normalize(f.points_px[f.inlier])
    s = cam.seconds_per_unit_r
    ref = refine_rs_pose(
        (f.R, f.C, f.w, f.t),
        f.X[f.inlier],
        x,
        r - cam.r0,
        2.0 / cam.mean_focal,
        RefineSettings(max_iterations=50, seconds_per_unit_r=s, covariance=False),
        prior=prior,
    )
    om = -ref.w / s
    v = (np.cross(ref.w, ref.C) - ref.t) / s
    return dict(
        ok=True,
        ms=float("nan"),
        rot=rotation_angle_deg(ref.R, f.R),
        ang=float(np.linalg.norm(om - f.angular_velocity)),
        lin=float(np.linalg.norm(v - f.linear_velocity)),
    )


def _ippe_row(f):
    inl = f.inlier
    t0 = time.perf_counter()
    flags = cv2.SOLVEPNP_IPPE if f.scene != "depth" else cv2.SOLVEPNP_SQPNP  # IPPE: planes only
    ok, rvec, _ = cv2.solvePnP(f.X[inl], f.points_px[inl], f.camera.K, None, flags=flags)
    ms = (time.perf_counter() - t0) * 1e3
    if not ok:
        return dict(ok=False, ms=ms)
    return dict(ok=True, ms=ms, rot=rotation_angle_deg(cv2.Rodrigues(rvec)[0], f.R))


#: row label -> how to compute it
ROWS = {
    "OpenCV IPPE (GS; SQPnP on depth)": lambda f: _ippe_row(f),
    "p3p (GS)": lambda f: _estimator_row(f, "p3p", None),
    "r6p_1lin ML (prior off)": lambda f: _estimator_row(f, "r6p_1lin", None),
    "r6p_1lin MAP (default 3/1.5)": lambda f: _estimator_row(f, "r6p_1lin", MotionPrior()),
    "r6p_1lin MAP (3/2)": lambda f: _estimator_row(f, "r6p_1lin", LOOSE_PRIOR),
    "oracle ML (exact model from truth)": lambda f: _oracle_row(f, None),
    "oracle MAP 3/1.5": lambda f: _oracle_row(f, MotionPrior()),
    "oracle MAP 3/2": lambda f: _oracle_row(f, LOOSE_PRIOR),
}


def run_scene(
    scene: str, frames: int, outliers: float = 0.0, seed: int = 0, linear_speed=(0.2, 1.0)
) -> dict:
    """Every row of :data:`ROWS` on ``frames`` frames of ``scene`` (seeds ``seed``...; the
    camera's ``linear_speed`` range in m/s). Returns {row label: summary dict}: ``solved``
    (frames), ``rot_med``, ``rot_p90``, ``rot_max`` (deg), ``ang_med`` (rad/s), ``lin_med``
    (m/s), ``rot_3s`` and ``ang_3s`` (fraction of solved frames within 3-sigma; estimator
    rows), ``cond`` (median condition number of the data's information; estimator rows),
    ``ms`` (median)."""
    per = {k: [] for k in ROWS}
    for i in range(frames):
        f = make_planar_frame(
            seed + i, scene, outlier_ratio=outliers, linear_speed=tuple(linear_speed)
        )
        for k, fn in ROWS.items():
            per[k].append(fn(f))
    out = {}
    for k, rows in per.items():
        ok = [r for r in rows if r["ok"]]
        rot = np.array([r["rot"] for r in ok]) if ok else np.array([np.nan])
        summ = dict(
            solved=len(ok),
            frames=len(rows),
            rot_med=float(np.median(rot)),
            rot_p90=float(np.percentile(rot, 90)),
            rot_max=float(np.max(rot)),
            ms=float(np.median([r["ms"] for r in rows])),
        )
        for key in ("ang", "lin", "cond"):
            vals = [r[key] for r in ok if key in r]
            summ[f"{key}_med"] = float(np.median(vals)) if vals else float("nan")
        for key in ("rot", "ang"):
            nees = [r[f"nees_{key}"] for r in ok if f"nees_{key}" in r]
            summ[f"{key}_3s"] = (
                float(np.mean(np.array(nees) < CHI2_3_3SIGMA)) if nees else float("nan")
            )
        out[k] = summ
    return out


def _fmt(v, spec):
    width = int(spec.split(".")[0])
    return f"{'-':>{width}s}" if v is None or not np.isfinite(v) else format(v, spec)


def _pct(v):
    return f"{'-':>7s}" if not np.isfinite(v) else f"{100 * v:6.0f}%"


def print_table(scene: str, res: dict, outliers: float):
    print(f"\n{scene}: {res[next(iter(res))]['frames']} frames, {outliers:.0%} outliers")
    print(
        f"{'estimate':36s} {'solved':>6s} {'rot med':>8s} {'p90':>7s} {'max':>7s} "
        f"{'ang.vel':>8s} {'lin.vel':>8s} {'rot<3s':>7s} {'ang<3s':>7s} {'cond':>8s} "
        f"{'ms':>6s}"
    )
    for k, s in res.items():
        print(
            f"{k:36s} {s['solved']:>6d} {_fmt(s['rot_med'], '8.3f')} "
            f"{_fmt(s['rot_p90'], '7.3f')} {_fmt(s['rot_max'], '7.2f')} "
            f"{_fmt(s['ang_med'], '8.3f')} {_fmt(s['lin_med'], '8.3f')} "
            f"{_pct(s['rot_3s'])} {_pct(s['ang_3s'])} {_fmt(s['cond_med'], '8.2g')} "
            f"{_fmt(s['ms'], '6.1f')}"
        )


def check_targets(results: dict) -> list:
    """The planar accuracy targets (rotation, angular velocity and calibrated uncertainty
    of ``r6p_1lin`` against ``p3p``) as (text, met) pairs from :func:`run_scene` results by
    scene."""
    out = []
    mp, p3 = "r6p_1lin MAP (default 3/1.5)", "p3p (GS)"
    if "plane" in results:
        r = results["plane"]
        out += [
            ("plane: r6p_1lin rotation median <= 0.5 deg", r[mp]["rot_med"] <= 0.5),
            ("plane: r6p_1lin rotation p90 <= 1.0 deg", r[mp]["rot_p90"] <= 1.0),
            ("plane: r6p_1lin angular velocity median <= 0.5 rad/s", r[mp]["ang_med"] <= 0.5),
            ("plane: r6p_1lin p90 <= p3p p90", r[mp]["rot_p90"] <= r[p3]["rot_p90"]),
        ]
    if "board" in results:
        r = results["board"]
        out += [
            ("board: solved on every frame", r[mp]["solved"] == r[mp]["frames"]),
            ("board: rotation median <= 1.3 deg", r[mp]["rot_med"] <= 1.3),
            ("board: rotation p90 <= 2.8 deg", r[mp]["rot_p90"] <= 2.8),
            ("board: r6p_1lin p90 <= p3p p90", r[mp]["rot_p90"] <= r[p3]["rot_p90"]),
        ]
    for scene in ("plane", "board", "depth"):
        if scene in results:
            r = results[scene][mp]
            out.append(
                (
                    f"{scene}: rotation and angular velocity within 3-sigma in >= 95 % of frames",
                    r["rot_3s"] >= 0.95 and r["ang_3s"] >= 0.95,
                )
            )
    if "depth" in results:
        r = results["depth"]
        lim = r["oracle ML (exact model from truth)"]
        out.append(
            (
                "depth (3D): MAP angular velocity median within 10 % of the ML oracle's",
                r[mp]["ang_med"] <= 1.1 * lim["ang_med"],
            )
        )
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_planar",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--frames", type=int, default=100, help="frames per scene (seeds 0..)")
    p.add_argument(
        "--scenes",
        nargs="+",
        default=["plane", "board", "depth"],
        choices=["plane", "board", "depth"],
    )
    p.add_argument("--outliers", type=float, default=0.0, help="outlier fraction")
    p.add_argument(
        "--linear-speed",
        type=float,
        nargs=2,
        default=(0.2, 1.0),
        metavar=("MIN", "MAX"),
        help="camera speed range (m/s)",
    )
    args = p.parse_args(argv)
    with one_thread():
        make_planar_frame(0, "board")  # warm-up: numba compilation outside the timings
        _estimator_row(make_planar_frame(0, "board"), "r6p_1lin", MotionPrior())
        _estimator_row(make_planar_frame(0, "depth"), "r6p_1lin", MotionPrior())
        print(
            f"640x480, f = 600 px, 40 us/line, 0.5 px noise, 1-3 rad/s, "
            f"{args.linear_speed[0]:g}-{args.linear_speed[1]:g} m/s; rotation in deg, "
            "velocities in rad/s and m/s (median errors), cond: median condition number of "
            "the data's information (unit-free); one BLAS thread"
        )
        results = {}
        for scene in args.scenes:
            results[scene] = run_scene(
                scene, args.frames, args.outliers, linear_speed=args.linear_speed
            )
            print_table(scene, results[scene], args.outliers)
    default = args.outliers == 0.0 and tuple(args.linear_speed) == (0.2, 1.0)
    print(
        "\ntargets"
        + (":" if default else " (they assume the default protocol: no outliers, 0.2-1 m/s):")
    )
    for text, met in check_targets(results):
        print(f"  [{'met' if met else 'MISSED'}] {text}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
