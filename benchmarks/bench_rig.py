"""A rig of rolling-shutter cameras posed as one body: ``python -m benchmarks.bench_rig``
(from the repository root).

Synthetic rig frames (:func:`rs_localizer.sim.synthetic.rig_frame`): rigs of 2, 3 and 4 RS cameras
looking front, back and to the sides (readout 15-35 ms in different directions, stamps up to 10 ms
apart, 5-20 cm levers), turning at 1-2 rad/s and moving at 1.5 m/s, ``--points`` correspondences per
camera (20 % outliers, 0.5 px noise). Each frame is estimated by

* ``rig``: :func:`rs_localizer.estimation.rig.estimate_rig_pose` on every camera at once;
* ``camera <name>``: :func:`rs_localizer.estimation.estimate_rs_pose` (``r6p_1lin``) on that
  camera alone, its pose mapped to the rig through the mounting
  (:func:`~rs_localizer.estimation.result.rig_model_of_camera`);
* ``cameras averaged``: the rig poses of the cameras alone averaged (chordal mean of the
  rotations, mean of the positions and of the angular velocities);
* ``PoseLib generalized GS``: PoseLib's ``estimate_generalized_absolute_pose`` (gP3P, global
  shutter) on the same pixels and mountings;

all at matched settings: the single camera's defaults (:class:`~rs_localizer.estimation.
EstimateOptions`: 2 px threshold, 20-1000 samples, confidence 0.9999), for PoseLib through
:func:`~rs_localizer.experiments.references.poselib_matched_options`. Prints per rig size and
method the frames posed, the median errors against the truth at the rig's reference time
(rotation deg, position cm, angular velocity deg/s) and the median time per rig frame (ms of
CPU time of the one thread, ``time.thread_time``; the cameras alone: the sum over the
cameras), one BLAS and numba thread. Then a 2-camera rig
where one camera sees 20 points and the other 3 (10 % outliers): frames posed and camera 0's
pose error from the rig against camera 0 alone. Last, the targets with pass/fail (exit code 1
if one fails).

``--gyro`` runs the rig with a gyro on it instead (:func:`gyro_run`): the same rig frames
estimated without a gyro, with a right one (the true angular velocity plus
``GYRO_SIGMA`` noise) and with wrong ones (biased by 0.087 rad/s or 0.017 rad/s, or mounted 5
degrees off): frames posed, gyro rejections, median errors and the 90th percentile of the
angular velocity error, CPU time; then its targets. ``--pre-rotation`` compares the
pre-rotations of RANSAC's samples (:func:`pre_rotation_run`): P3P within one camera
(default) against PoseLib's generalized P3P (``gp3p``, :class:`GeneralizedP3P`) on 2-4 cameras
and the 20 + 3 points rig.

    python -m benchmarks.bench_rig [--frames 40] [--points 300] [--rigs 2 3 4] [--seed 0]
    python -m benchmarks.bench_rig --gyro [--frames 40] [--points 300] [--rigs 3]
    python -m benchmarks.bench_rig --pre-rotation [--frames 40] [--points 300] [--rigs 2 3 4]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from rs_localizer.estimation import EstimateOptions, GyroMeasurement, estimate_rs_pose
from rs_localizer.estimation.result import rig_model_of_camera
from rs_localizer.estimation.rig import RIG_OPTIONS, estimate_rig_pose
from rs_localizer.estimation.sampling import draw_samples_numpy, least_error_roots
from rs_localizer.experiments.references import poselib_matched_options
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.synthetic import make_rig, rig_frame, rig_motion

__all__ = [
    "GeneralizedP3P",
    "few_points",
    "gyro_run",
    "gyro_targets",
    "main",
    "pre_rotation_run",
    "run",
    "targets",
]

#: the settings every method runs at (the single camera's defaults)
OPTIONS = EstimateOptions()
ANGULAR_SPEED = (1.0, 2.0)  # rad/s
LINEAR_SPEED = 1.5  # m/s
OUTLIERS = 0.2
NOISE_PX = 0.5


def _rig_options(min_inliers: int = RIG_OPTIONS.ransac.min_inliers) -> EstimateOptions:
    """The rig's options: the single camera's (:data:`OPTIONS`) with ``min_inliers`` over all
    cameras (the rig's default, :data:`~rs_localizer.estimation.rig.RIG_OPTIONS`)."""
    return replace(OPTIONS, ransac=replace(OPTIONS.ransac, min_inliers=min_inliers))


def errors(model, truth) -> tuple[float, float, float]:
    """(rotation deg, position cm, angular velocity deg/s) of a rig model ``(R, C, w, t)``
    against the true one (``w``: NaN for a model without velocities)."""
    R, C, w, _ = model
    Rt, Ct, wt, _ = truth
    pos = np.linalg.norm(-R.T @ C - (-Rt.T @ Ct)) * 100
    om = np.nan if w is None else float(np.degrees(np.linalg.norm(w - wt)))
    return rotation_angle_deg(R, Rt), float(pos), om


def _mean_model(models):
    """The chordal mean of the rotations, the mean position and mean w of rig models."""
    R = Rotation.from_matrix([m[0] for m in models]).mean().as_matrix()
    p = np.mean([-m[0].T @ m[1] for m in models], axis=0)
    return R, -R @ p, np.mean([m[2] for m in models], axis=0), None


def _poselib(views):
    """PoseLib's generalized absolute pose (global shutter) on the rig frame: raw pixels with
    each camera's pinhole intrinsics, the mountings as camera extrinsics. Returns (R, C)."""
    import poselib

    pts2, pts3, ext, cams = [], [], [], []
    for v in views:
        K = v.camera.K
        pts2.append(np.asarray(v.uv, dtype=float))
        pts3.append(np.asarray(v.X, dtype=float))
        e = poselib.CameraPose()
        e.R, e.t = v.mounting.R, v.mounting.c
        ext.append(e)
        cams.append(
            {
                "model": "PINHOLE",
                "width": v.camera.width,
                "height": v.camera.height,
                "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
            }
        )
    pose, _ = poselib.estimate_generalized_absolute_pose(
        pts2, pts3, ext, cams, poselib_matched_options(OPTIONS), {}
    )
    return np.asarray(pose.R), np.asarray(pose.t)


def _timed(fn):
    """(fn(), CPU seconds of the calling thread: what a shared machine's other processes do
    not inflate; every method timed runs in this thread)."""
    t0 = time.thread_time()
    out = fn()
    return out, time.thread_time() - t0


def run(m: int, frames: int, points: int, seed: int = 0) -> dict:
    """``frames`` frames of a rig of ``m`` cameras with ``points`` correspondences each.

    Returns {method: {"err": (F, 3) rotation deg, position cm, angular velocity deg/s (NaN
    rows: not posed), "time": (F,) s per rig frame}} for ``rig``, ``camera <name>``,
    ``cameras averaged``, ``poselib``; and ``"names"``: the cameras' names."""
    rng = np.random.default_rng(seed + 1000 * m)
    out: dict = {}

    def add(key, err, dt):
        d = out.setdefault(key, {"err": [], "time": []})
        d["err"].append(err)
        d["time"].append(dt)

    nan3 = (np.nan, np.nan, np.nan)
    names = None
    for _ in range(frames):
        rig = make_rig(m, rng)
        names = [k.name for k in rig.cameras]
        truth = rig_motion(rng, rng.uniform(*ANGULAR_SPEED), LINEAR_SPEED)
        f = rig_frame(rig, truth, [points] * m, rng, NOISE_PX, OUTLIERS)
        est, dt = _timed(lambda f=f: estimate_rig_pose(f.views, _rig_options()))
        add("rig", errors(est.model, truth) if est.success else nan3, dt)
        alone, total = [], 0.0
        for v, k in zip(f.views, rig.cameras, strict=True):
            e1, dt1 = _timed(lambda v=v: estimate_rs_pose(v.uv, v.X, v.camera, options=OPTIONS))
            total += dt1
            if e1.success:
                mdl = rig_model_of_camera(
                    e1.model, k.mounting, k.stamp_offset, k.camera.seconds_per_unit_r
                )
                alone.append(mdl)
                add(f"camera {k.name}", errors(mdl, truth), dt1)
            else:
                add(f"camera {k.name}", nan3, dt1)
        add("cameras averaged", errors(_mean_model(alone), truth) if alone else nan3, total)
        (R, C), dt = _timed(lambda f=f: _poselib(f.views))
        add("poselib", errors((R, C, None, None), truth), dt)
    for d in out.values():
        d["err"] = np.array(d["err"], dtype=float)
        d["time"] = np.array(d["time"])
    out["names"] = names
    return out


def few_points(frames: int, seed: int = 0, counts=(20, 3)) -> dict:
    """A 2-camera rig whose cameras see ``counts`` points (10 % outliers): returns {"posed":
    frames the rig posed, "frames", "rig": (F, 2) and "alone": (F, 2) camera 0's rotation (deg)
    and centre (cm) errors at its reference line from the rig and alone (inf: not posed)}."""
    from rs_localizer.estimation.result import camera_model_of_rig

    rng = np.random.default_rng(seed + 77)
    posed, rig_err, one_err = 0, [], []

    def cam_err(model, true):
        R, C = model[0], model[1]
        return (
            rotation_angle_deg(R, true[0]),
            float(np.linalg.norm(R.T @ C - true[0].T @ true[1]) * 100),
        )

    for _ in range(frames):
        rig = make_rig(2, rng)
        truth = rig_motion(rng, rng.uniform(*ANGULAR_SPEED), LINEAR_SPEED)
        f = rig_frame(rig, truth, list(counts), rng, NOISE_PX, 0.1)
        k = rig.cameras[0]
        true0 = f.camera_truth(0)
        est = estimate_rig_pose(f.views, _rig_options(min_inliers=6))
        if est.success:
            posed += 1
            mdl = camera_model_of_rig(
                est.model, k.mounting, k.stamp_offset, k.camera.seconds_per_unit_r
            )
            rig_err.append(cam_err(mdl, true0))
        else:
            rig_err.append((np.inf, np.inf))
        v = f.views[0]
        one = estimate_rs_pose(v.uv, v.X, v.camera, options=OPTIONS)
        one_err.append(cam_err(one.model, true0) if one.success else (np.inf, np.inf))
    return {
        "posed": posed,
        "frames": frames,
        "rig": np.array(rig_err),
        "alone": np.array(one_err),
    }


#: s.d. (rad/s) of the gyro's mean rate over one rig frame (its noise averaged over the frame)
GYRO_SIGMA = 0.003
#: the gyros of :func:`gyro_run`: name -> (bias rad/s (3,), mounting error deg about a random
#: axis); "none" runs without a gyro
GYROS = {
    "none": None,
    "right": (np.zeros(3), 0.0),
    "biased 0.087 rad/s": (np.array([0.05, -0.05, 0.05]), 0.0),
    "biased 0.017 rad/s": (np.array([0.01, -0.01, 0.01]), 0.0),
    "mounted 5 deg off": (np.zeros(3), 5.0),
}


def _gyro_of(kind, omega, rng):
    """The gyro measurement ``kind`` (:data:`GYROS`) of the rig's true angular velocity
    ``omega`` (rad/s, rig frame), with the gyro's noise."""
    if GYROS[kind] is None:
        return None
    bias, mount_deg = GYROS[kind]
    axis = rng.normal(size=3)
    R = rotvec_to_matrix(np.radians(mount_deg) * axis / np.linalg.norm(axis))
    meas = R @ omega + bias + rng.normal(size=3) * GYRO_SIGMA
    return GyroMeasurement(meas, GYRO_SIGMA**2 * np.eye(3))


def gyro_run(m: int, frames: int, points: int, seed: int = 0) -> dict:
    """``frames`` rig frames of ``m`` cameras with ``points`` correspondences each (as
    :func:`run`), each estimated with every gyro of :data:`GYROS`. Returns {gyro: {"err": (F,
    3) rotation deg, position cm, angular velocity deg/s (NaN: not posed), "time": (F,) s,
    "rejected": (F,) bool, "used": (F,) bool}}."""
    rng = np.random.default_rng(seed + 500 + 1000 * m)
    out = {k: {"err": [], "time": [], "rejected": [], "used": []} for k in GYROS}
    for _ in range(frames):
        rig = make_rig(m, rng)
        truth = rig_motion(rng, rng.uniform(*ANGULAR_SPEED), LINEAR_SPEED)
        f = rig_frame(rig, truth, [points] * m, rng, NOISE_PX, OUTLIERS)
        for kind in GYROS:
            g = _gyro_of(kind, -truth.w, rng)
            est, dt = _timed(lambda f=f, g=g: estimate_rig_pose(f.views, _rig_options(), gyro=g))
            d = out[kind]
            d["err"].append(errors(est.model, truth) if est.success else (np.nan,) * 3)
            d["time"].append(dt)
            d["rejected"].append(est.gyro_rejected)
            d["used"].append(est.gyro_used)
    for d in out.values():
        for k in d:
            d[k] = np.array(d[k])
    return out


def gyro_summary(res: dict) -> dict:
    """{gyro: (posed, frames, used, rejected, median rotation deg, position cm, angular
    velocity deg/s, 90th percentile angular velocity deg/s, median ms)}."""
    out = {}
    for kind, d in res.items():
        e = d["err"]
        ok = np.isfinite(e[:, 0])
        p90 = float(np.percentile(e[ok, 2], 90)) if ok.any() else np.nan
        out[kind] = (
            int(ok.sum()), len(e), int(d["used"].sum()), int(d["rejected"].sum()),
            *[_median(e[:, j]) for j in range(3)], p90, 1e3 * float(np.median(d["time"])),
        )  # fmt: skip
    return out


#: the wrong gyros whose error one rig frame cannot show: a bias of 0.017 rad/s (1 deg/s) is
#: within the image's own angular velocity error (0.4-0.9 deg/s); :func:`gyro_targets`
#: prints their ratios without a target (a video's gyro-bias estimate removes such a bias)
BELOW_RESOLUTION = ("biased 0.017 rad/s",)


def gyro_targets(s: dict) -> list[tuple[str, bool | None, str]]:
    """(target, passed, measured) of the gyro on the rig from :func:`gyro_summary`: a right
    gyro gives a better angular velocity; a wrong one is never worse than none (medians of
    rotation, position and angular velocity, within 5 %; ``passed`` None, no target, for
    :data:`BELOW_RESOLUTION`)."""
    none, right = s["none"], s["right"]
    out = [
        (
            "right gyro: angular velocity error < without a gyro",
            bool(right[6] < none[6]),
            f"{right[6]:.3f} vs {none[6]:.3f} deg/s ({right[6] / none[6]:.2f}x)",
        )
    ]
    for kind, v in s.items():
        if kind in ("none", "right"):
            continue
        worse = max(v[4] / none[4], v[5] / none[5], v[6] / none[6])
        passed = bool(worse <= 1.05 and v[0] >= none[0])
        out.append(
            (
                f"{kind}: rotation, position, angular velocity <= 1.05x without a gyro",
                None if kind in BELOW_RESOLUTION else passed,
                f"worst ratio {worse:.2f}x, {v[3]}/{v[1]} rejected",
            )
        )
    return out


class GeneralizedP3P:
    """PoseLib's generalized P3P (``poselib.gp3p``, Nister and Stewenius 2007) as the
    pre-rotation of the rig's RANSAC samples (``estimate_rig_pose(..., pre_rotation=)``, for
    :func:`pre_rotation_run`'s comparison with P3P in one camera; needs ``poselib``)."""

    @staticmethod
    def samples(pool, rng, n_samples: int, subset=None) -> np.ndarray:
        """n_samples samples of 6 distinct indices of the stacked views ``pool`` drawn
        uniformly as a camera's (:func:`~rs_localizer.estimation.sampling.draw_samples_numpy`;
        ``subset``: among those sorted indices, at least 6), whose first 3 points may lie in
        any cameras. Returns (S, 6)."""
        n = len(pool.cam) if subset is None else len(subset)
        u = draw_samples_numpy(rng.random((n_samples, 6)), n)
        return u if subset is None else subset[u]

    @staticmethod
    def poses(pool, samples: np.ndarray):
        """gp3p on each sample's first 3 points in whatever cameras they lie (rays ``R_c^T
        x`` from the camera centres ``-R_c^T c_c``): the rig's ``(R (H, 3, 3), C (H, 3), the
        sample of each (H,))``, a sample keeping the pose of least error on its other points
        (:func:`~rs_localizer.estimation.sampling.least_error_roots`), or None when none
        solved."""
        import poselib

        centres = -np.einsum("cji,cj->ci", pool.R_mount, pool.c_mount)
        first = samples[:, :3]
        rays = np.concatenate([pool.x[first], np.ones(first.shape + (1,))], axis=2)
        rays = np.einsum("hnji,hnj->hni", pool.R_mount[pool.cam[first]], rays)
        rays /= np.linalg.norm(rays, axis=2, keepdims=True)
        sols = [
            (s.R, s.t, h)
            for h in range(len(samples))
            for s in poselib.gp3p(centres[pool.cam[first[h]]], rays[h], pool.X[first[h]])
        ]
        if not sols:
            return None
        R, C = np.array([s[0] for s in sols]), np.array([s[1] for s in sols])
        ok = np.isfinite(R).all(axis=(1, 2)) & np.isfinite(C).all(axis=1)
        R, C, own = R[ok], C[ok], np.array([s[2] for s in sols], dtype=np.int64)[ok]
        if len(own) == 0:
            return None
        keep = least_error_roots(
            R, C, own, samples, pool.X, pool.x, pool.cam, pool.R_mount, pool.c_mount
        )
        return (R[keep], C[keep], own[keep]) if len(keep) else None


def pre_rotation_run(m: int, frames: int, points, seed: int = 0, outliers=OUTLIERS) -> dict:
    """``frames`` rig frames of ``m`` cameras (``points``: per camera, an int or a list),
    each estimated with both pre-rotations of RANSAC's samples (``estimate_rig_pose(...,
    pre_rotation=)``: ``p3p`` within one camera, the rig's own, ``gp3p`` PoseLib's
    generalized P3P, :class:`GeneralizedP3P`) from the same seed. Returns {pre-rotation:
    {"err": (F, 3), "time": (F,) s, "iterations": (F,)}}."""
    rng = np.random.default_rng(seed + 300 + 1000 * m)
    counts = [points] * m if np.ndim(points) == 0 else list(points)
    out = {k: {"err": [], "time": [], "iterations": []} for k in ("p3p", "gp3p")}
    hooks = {"p3p": None, "gp3p": GeneralizedP3P()}
    for _ in range(frames):
        rig = make_rig(m, rng)
        truth = rig_motion(rng, rng.uniform(*ANGULAR_SPEED), LINEAR_SPEED)
        f = rig_frame(rig, truth, counts, rng, NOISE_PX, outliers)
        for kind, d in out.items():
            est, dt = _timed(
                lambda f=f, k=kind: estimate_rig_pose(
                    f.views, _rig_options(min_inliers=6), pre_rotation=hooks[k]
                )
            )
            d["err"].append(errors(est.model, truth) if est.success else (np.nan,) * 3)
            d["time"].append(dt)
            d["iterations"].append(est.ransac_iterations)
    for d in out.values():
        for k in d:
            d[k] = np.array(d[k], dtype=float)
    return out


def _median(a):
    """Median over the frames with a value (NaN where none)."""
    a = np.asarray(a, dtype=float)
    ok = np.isfinite(a)
    return np.nanmedian(np.where(ok, a, np.nan), axis=0) if ok.any() else np.nan


def summary(res: dict) -> dict:
    """{method: (posed, frames, median rotation deg, position cm, angular velocity deg/s,
    median ms per rig frame)}."""
    out = {}
    for key, d in res.items():
        if key == "names":
            continue
        e = d["err"]
        posed = int(np.isfinite(e[:, 0]).sum())
        med = [_median(e[:, j]) for j in range(3)]
        out[key] = (posed, len(e), *med, 1e3 * float(np.median(d["time"])))
    return out


def targets(s3: dict, few: dict) -> list[tuple[str, bool, str]]:
    """(target, passed, measured) of the rig targets: ``s3``: :func:`summary` of the 3-camera
    rig; ``few``: :func:`few_points`."""
    rig = s3["rig"]
    cams = [v for k, v in s3.items() if k.startswith("camera ")]
    best_rot = min(c[2] for c in cams)
    best_pos = min(c[3] for c in cams)
    best_om = min(c[4] for c in cams)
    gs = s3["poselib"]
    fr, fa = _median(few["rig"]), _median(few["alone"])
    return [
        (
            "3 cameras: rig rotation error <= 0.5x the best single camera's",
            bool(rig[2] <= 0.5 * best_rot),
            f"{rig[2]:.4f} vs {best_rot:.4f} deg ({rig[2] / best_rot:.2f}x)",
        ),
        (
            "3 cameras: rig position error <= 0.5x the best single camera's",
            bool(rig[3] <= 0.5 * best_pos),
            f"{rig[3]:.3f} vs {best_pos:.3f} cm ({rig[3] / best_pos:.2f}x)",
        ),
        (
            "3 cameras turning 1-2 rad/s: rotation >= 5x better than PoseLib generalized GS",
            bool(5 * rig[2] <= gs[2]),
            f"{rig[2]:.4f} vs {gs[2]:.4f} deg ({gs[2] / rig[2]:.1f}x)",
        ),
        (
            "3 cameras: angular velocity error <= the best single camera's",
            bool(rig[4] <= best_om),
            f"{rig[4]:.3f} vs {best_om:.3f} deg/s",
        ),
        (
            "20 + 3 points: every rig frame posed",
            few["posed"] == few["frames"],
            f"{few['posed']}/{few['frames']}",
        ),
        (
            "20 + 3 points: camera 0 from the rig better than alone (rotation and position)",
            bool(fr[0] < fa[0] and fr[1] < fa[1]),
            f"{fr[0]:.3f} vs {fa[0]:.3f} deg, {fr[1]:.2f} vs {fa[1]:.2f} cm",
        ),
        (
            "3 cameras: time per rig frame <= 1.0x PoseLib generalized GS",
            bool(rig[5] <= gs[5]),
            f"{rig[5]:.1f} vs {gs[5]:.1f} ms ({rig[5] / gs[5]:.1f}x)",
        ),
    ]


def print_table(m: int, s: dict, ms_digits: int = 1) -> None:
    """One row per estimator of :func:`summary`'s ``s`` for rigs of ``m`` cameras (the time
    with ``ms_digits`` decimals)."""
    for key, (posed, n, rot, pos, om, ms) in s.items():
        name = "PoseLib generalized GS" if key == "poselib" else key
        oms = "-" if not np.isfinite(om) else f"{om:.3f}"
        print(
            f"{m:7d}  {name:24s} {posed:3d}/{n:<3d} {rot:9.4f} {pos:8.3f} {oms:>10s} "
            f"{ms:8.{ms_digits}f}"
        )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_rig",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--frames", type=int, default=40, help="rig frames per rig size")
    p.add_argument("--points", type=int, default=300, help="correspondences per camera")
    p.add_argument("--rigs", type=int, nargs="+", default=[2, 3, 4], help="cameras per rig")
    p.add_argument("--seed", type=int, default=0)
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--gyro", action="store_true", help="the rig with and without a gyro")
    mode.add_argument(
        "--pre-rotation", action="store_true", help="P3P in one camera against generalized P3P"
    )
    args = p.parse_args(argv)
    if args.frames < 1 or args.points < 6:
        p.error("--frames must be >= 1 and --points >= 6")
    if any(m not in (2, 3, 4) for m in args.rigs):
        p.error("--rigs: 2, 3 or 4 cameras")
    if args.gyro:
        return _main_gyro(args)
    if args.pre_rotation:
        return _main_pre_rotation(args)
    with one_thread():
        # (warm-up: numba compiles the kernels on first use)
        run(2, 1, 50, args.seed + 999)
        print(
            f"{args.points} correspondences per camera, {OUTLIERS:.0%} outliers, "
            f"{NOISE_PX} px noise, turning {ANGULAR_SPEED[0]}-{ANGULAR_SPEED[1]} rad/s, "
            f"{args.frames} frames per rig; medians"
        )
        print(
            f"{'cameras':>7s}  {'method':24s} {'posed':>7s} {'rot deg':>9s} {'pos cm':>8s} "
            f"{'w deg/s':>10s} {'ms/frame':>8s}"
        )
        s3 = None
        for m in args.rigs:
            s = summary(run(m, args.frames, args.points, args.seed))
            print_table(m, s)
            if m == 3:
                s3 = s
        few = few_points(args.frames, args.seed)
        fr, fa = _median(few["rig"]), _median(few["alone"])
        print(
            f"\n2 cameras, 20 + 3 points (10 % outliers): posed {few['posed']}/{few['frames']}; "
            f"camera 0 from the rig {fr[0]:.3f} deg, {fr[1]:.2f} cm; alone {fa[0]:.3f} deg, "
            f"{fa[1]:.2f} cm (medians)"
        )
    if s3 is None:
        print("\n(targets need the 3-camera rig: --rigs 3)")
        return 0
    print("\ntargets")
    ok = True
    for name, passed, measured in targets(s3, few):
        ok &= passed
        print(f"  {'PASS' if passed else 'FAIL'}  {name}: {measured}")
    return 0 if ok else 1


def _main_gyro(args) -> int:
    ok = True
    with one_thread():
        gyro_run(2, 1, 50, args.seed + 999)  # (warm-up: numba compiles the kernels)
        print(
            f"{args.points} correspondences per camera, {OUTLIERS:.0%} outliers, {NOISE_PX} px "
            f"noise, turning {ANGULAR_SPEED[0]}-{ANGULAR_SPEED[1]} rad/s, gyro noise "
            f"{GYRO_SIGMA} rad/s, {args.frames} frames per rig; medians"
        )
        print(
            f"{'cameras':>7s}  {'gyro':20s} {'posed':>7s} {'used':>4s} {'rej':>4s} "
            f"{'rot deg':>9s} {'pos cm':>8s} {'w deg/s':>8s} {'w p90':>7s} {'ms/frame':>8s}"
        )
        for m in args.rigs:
            s = gyro_summary(gyro_run(m, args.frames, args.points, args.seed))
            for kind, (posed, n, used, rej, rot, pos, om, p90, ms) in s.items():
                print(
                    f"{m:7d}  {kind:20s} {posed:3d}/{n:<3d} {used:4d} {rej:4d} {rot:9.4f} "
                    f"{pos:8.3f} {om:8.3f} {p90:7.3f} {ms:8.1f}"
                )
            print(f"targets, {m} cameras")
            for name, passed, measured in gyro_targets(s):
                if passed is None:
                    print(f"  info  {name} (below one frame's resolution): {measured}")
                    continue
                ok &= passed
                print(f"  {'PASS' if passed else 'FAIL'}  {name}: {measured}")
    return 0 if ok else 1


def _main_pre_rotation(args) -> int:
    with one_thread():
        pre_rotation_run(2, 1, 50, args.seed + 999)  # (warm-up)
        print(
            f"pre-rotation of RANSAC's samples: {OUTLIERS:.0%} outliers ({args.points} points "
            f"per camera; 20 + 3: 10 %), {args.frames} frames per rig; medians"
        )
        print(
            f"{'rig':>10s}  {'pre-rotation':12s} {'posed':>7s} {'rot deg':>9s} {'pos cm':>8s} "
            f"{'w deg/s':>8s} {'samples':>7s} {'ms/frame':>8s}"
        )
        cases = [(m, args.points, OUTLIERS, f"{m} x {args.points}") for m in args.rigs]
        cases.append((2, [20, 3], 0.1, "20 + 3"))
        for m, pts, out, label in cases:
            r = pre_rotation_run(m, args.frames, pts, args.seed, out)
            for kind, d in r.items():
                e = d["err"]
                posed = int(np.isfinite(e[:, 0]).sum())
                med = [_median(e[:, j]) for j in range(3)]
                print(
                    f"{label:>10s}  {kind:12s} {posed:3d}/{len(e):<3d} {med[0]:9.4f} "
                    f"{med[1]:8.3f} {med[2]:8.3f} {np.median(d['iterations']):7.0f} "
                    f"{1e3 * np.median(d['time']):8.1f}"
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
