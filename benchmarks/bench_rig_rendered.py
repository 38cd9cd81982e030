"""A rig of rolling-shutter cameras in a rendered room: ``python -m benchmarks.bench_rig_rendered``
(from the repository root).

Rigs of 2, 3 and 4 cameras (:func:`rs_localizer.sim.render.renderer.rendered_rig`: 640x480 with mild
lens distortion, front/back (2), front/left/right (3), front/right/back/left (4), readout 20-30
ms in four directions, first frames 0-9 ms apart) turn in the closed AprilTag room
``apriltag_rig_room`` (the renderer's ``pan`` motion, rotation amplitudes times
``--motion-scale``: 1.5 turns at up to 2.1 rad/s). Every camera's images are rendered line by
line at their capture times and the AprilTag front end
(:class:`~rs_localizer.frontends.ArucoFrontend` of the room's tags) gives the correspondences;
camera frames of the same index form a rig frame (its reference time: the front camera's
reference line). Each rig frame is estimated by

* ``rig``: :func:`rs_localizer.estimation.rig.estimate_rig_pose` on every camera at once;
* ``camera <name>``: :func:`rs_localizer.estimation.estimate_rs_pose` (``r6p_1lin``) on that
  camera alone, mapped to the rig through its mounting
  (:func:`~rs_localizer.estimation.result.rig_model_of_camera`);
* ``cameras averaged``: the cameras' rig poses averaged (chordal mean of the rotations, mean
  positions and angular velocities);
* ``PoseLib generalized GS``: PoseLib's ``estimate_generalized_absolute_pose`` (global
  shutter) on the undistorted pixels (pinhole, the undistortion timed with it) and the
  mountings;

at matched settings (:mod:`benchmarks.bench_rig`: the single camera's defaults, 2 px
threshold). Printed per rig size and method: frames posed, median errors against the rendered
truth at the rig's reference time (rotation deg, position cm, angular velocity deg/s), the
median CPU time per rig frame (ms, one thread, ``time.thread_time``; the cameras alone: the
sum over the cameras); then the median correspondences per camera and the issue's targets
where they apply to these frames (pass/fail; the exit code stays 0: the rendered frames do not
have the targets' 300 correspondences per camera). The render's own CPU time per camera frame
is printed too.

    python -m benchmarks.bench_rig_rendered [--frames 60] [--rigs 2 3 4] [--motion-scale 1.5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.bench_rig import (
    OPTIONS,
    _mean_model,
    _median,
    _poselib,
    _rig_options,
    _timed,
    print_table,
)
from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.result import rig_model_of_camera
from rs_localizer.estimation.rig import estimate_rig_pose
from rs_localizer.estimation.view import View
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.pose import RSPose

__all__ = ["main", "render", "run"]

SCENE = "apriltag_rig_room"


def render(m: int, frames: int, scale: float, fps: float = 30.0, seed: int = 0) -> dict:
    """Render a rig of ``m`` cameras for ``frames`` frames each: {"cameras": the rig,
    "trajectory", "frames": {(name, k): RigFrameSim}, "render_ms", "frontend_ms":
    median CPU ms per camera frame}."""
    from rs_localizer.sim.render import render_rig_video, rendered_rig, rig_trajectory
    from rs_localizer.sim.render.scene import load_scene

    sc = load_scene(SCENE)
    cams = rendered_rig(m, fps)
    duration = max(c.offset for c in cams) + frames / fps
    traj = rig_trajectory("pan", sc, duration, scale=scale)
    out = {}
    for f in render_rig_video(cams, sc, traj, frames, t0_ns=0, seed=seed):
        out[(f.name, f.index)] = f
    return {
        "cameras": cams,
        "trajectory": traj,
        "frames": out,
        "render_ms": 1e3 * float(np.median([f.render_s for f in out.values()])),
        "frontend_ms": 1e3 * float(np.median([f.frontend_s for f in out.values()])),
    }


def _undistorted_views(views):
    """The views with pinhole pixels (each camera's K, no distortion) for PoseLib."""
    out = []
    for v in views:
        xn = v.camera.undistort(v.uv)
        K = v.camera.K
        uv = xn @ K[:2, :2].T + K[:2, 2]
        out.append(View(uv, v.X, v.camera, v.mounting, v.stamp_offset, v.name))
    return out


def _errors(pose: RSPose, truth) -> tuple[float, float, float]:
    """(rotation deg, position cm, angular velocity deg/s; NaN without velocity) of a rig
    pose against the truth ``(R rig -> world, position, angular velocity rig frame)``."""
    R, p, w = truth
    om = pose.angular_velocity
    return (
        rotation_angle_deg(pose.orientation, R),
        float(np.linalg.norm(pose.position - p) * 100),
        np.nan if om is None else float(np.degrees(np.linalg.norm(om - w))),
    )


def run(rendered: dict, fps: float = 30.0) -> dict:
    """Estimate every rig frame of :func:`render`'s output. Returns {method: {"err": (F, 3),
    "time": (F,) s}} as :func:`benchmarks.bench_rig.run`, with ``"names"``, ``"points"``
    (F, M) correspondences per camera and ``"speed"`` (F,) the rig's true angular speed
    (rad/s)."""
    cams, traj, fr = rendered["cameras"], rendered["trajectory"], rendered["frames"]
    front = cams[0]
    ks = sorted({k for _, k in fr})
    out: dict = {}
    nan3 = (np.nan, np.nan, np.nan)
    points, speed = [], []

    def add(key, err, dt):
        d = out.setdefault(key, {"err": [], "time": []})
        d["err"].append(err)
        d["time"].append(dt)

    for k in ks:
        t_rig = front.offset + k / fps + float(front.camera.line_time(front.camera.reference_line))
        R, p = traj.pose(t_rig)
        w, _ = traj.velocity_body(t_rig)
        truth = (R, p, w)
        speed.append(float(np.linalg.norm(w)))
        views = []
        for c in cams:
            f = fr[(c.name, k)]
            t_ref = c.offset + k / fps + float(c.camera.line_time(c.camera.reference_line))
            views.append(View(f.uv, f.xyz, c.camera, c.mounting, t_ref - t_rig, c.name))
        points.append([len(v.uv) for v in views])
        est, dt = _timed(lambda views=views: estimate_rig_pose(views, _rig_options()))
        add("rig", _errors(est.pose, truth) if est.success else nan3, dt)
        alone, total = [], 0.0
        for v, c in zip(views, cams, strict=True):
            if len(v.uv) < 6:  # (the single-camera estimator needs 6 points)
                add(f"camera {c.name}", nan3, 0.0)
                continue
            e1, dt1 = _timed(lambda v=v: estimate_rs_pose(v.uv, v.X, v.camera, options=OPTIONS))
            total += dt1
            if e1.success:
                mdl = rig_model_of_camera(
                    e1.model, c.mounting, v.stamp_offset, c.camera.seconds_per_unit_r
                )
                alone.append(mdl)
                add(f"camera {c.name}", _errors(RSPose.from_model(mdl, 1.0), truth), dt1)
            else:
                add(f"camera {c.name}", nan3, dt1)
        avg = nan3
        if alone:
            Rm, Cm, wm, _ = _mean_model(alone)
            q = RSPose.from_model((Rm, Cm, wm, np.zeros(3)), 1.0)
            avg = _errors(q, truth)
        add("cameras averaged", avg, total)
        try:
            (Rg, Cg), dt = _timed(lambda views=views: _poselib(_undistorted_views(views)))
            q = RSPose.from_model((Rg, Cg, np.zeros(3), np.zeros(3)), 1.0)
            add("poselib", (*_errors(q, truth)[:2], np.nan), dt)
        except Exception:  # (PoseLib finds no pose: not posed)
            add("poselib", nan3, 0.0)
    for d in out.values():
        d["err"] = np.array(d["err"], dtype=float)
        d["time"] = np.array(d["time"])
    out["names"] = [c.name for c in cams]
    out["points"] = np.array(points)
    out["speed"] = np.array(speed)
    return out


def summary(res: dict, mask: np.ndarray | None = None) -> dict:
    """{method: (posed, frames, median rotation deg, position cm, angular velocity deg/s,
    median ms per rig frame)} over the rig frames of ``mask`` (default all)."""
    out = {}
    for key, d in res.items():
        if key in ("names", "points", "speed"):
            continue
        e, t = d["err"], d["time"]
        if mask is not None:
            e, t = e[mask], t[mask]
        posed = int(np.isfinite(e[:, 0]).sum())
        med = [_median(e[:, j]) for j in range(3)]
        ms = 1e3 * float(np.median(t[np.isfinite(e[:, 0])])) if posed else np.nan
        out[key] = (posed, len(e), *med, ms)
    return out


def targets(res3: dict) -> list[tuple[str, bool, str]]:
    """(target, passed, measured) of the issue's targets that apply to the rendered 3-camera
    rig (``res3``: :func:`run`)."""
    s3 = summary(res3)
    rig = s3["rig"]
    cams = [v for k, v in s3.items() if k.startswith("camera ")]
    best_rot = min(c[2] for c in cams)
    best_pos = min(c[3] for c in cams)
    best_om = min(c[4] for c in cams)
    turning = res3["speed"] >= 1.0
    st = summary(res3, turning)
    out = [
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
            "3 cameras turning >= 1 rad/s: rotation >= 5x better than PoseLib generalized GS",
            bool(5 * st["rig"][2] <= st["poselib"][2]),
            f"{int(turning.sum())} frames: {st['rig'][2]:.4f} vs {st['poselib'][2]:.4f} deg "
            f"({st['poselib'][2] / st['rig'][2]:.1f}x)",
        ),
        (
            "3 cameras: angular velocity error <= the best single camera's",
            bool(rig[4] <= best_om),
            f"{rig[4]:.3f} vs {best_om:.3f} deg/s",
        ),
        (
            "3 cameras: time per rig frame <= 1.0x PoseLib generalized GS",
            bool(rig[5] <= s3["poselib"][5]),
            f"{rig[5]:.1f} vs {s3['poselib'][5]:.1f} ms ({rig[5] / s3['poselib'][5]:.1f}x)",
        ),
    ]
    # a rig frame where one camera sees >= 20 points and another few: posed, and better than
    # the first camera alone (rotation and position)
    pts = res3["points"]
    few = (pts.max(axis=1) >= 20) & (pts.min(axis=1) <= 12)
    if few.any():
        names = res3["names"]
        e_rig = res3["rig"]["err"][few]
        posed = int(np.isfinite(e_rig[:, 0]).sum())
        best = [names[i] for i in pts[few].argmax(axis=1)]
        e_one = np.array(
            [res3[f"camera {n}"]["err"][i] for n, i in zip(best, np.flatnonzero(few), strict=True)]
        )
        fr, fa = _median(e_rig[:, :2]), _median(e_one[:, :2])
        out.append(
            (
                "rig frames where one camera sees >= 20 points and another <= 12: posed, "
                "better than the first camera alone",
                bool(posed == few.sum() and fr[0] < fa[0] and fr[1] < fa[1]),
                f"{posed}/{int(few.sum())} posed; rig {fr[0]:.4f} deg {fr[1]:.3f} cm, that "
                f"camera alone {fa[0]:.4f} deg {fa[1]:.3f} cm",
            )
        )
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_rig_rendered",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--frames", type=int, default=60, help="rig frames per rig size")
    p.add_argument("--rigs", type=int, nargs="+", default=[2, 3, 4], help="cameras per rig")
    p.add_argument(
        "--motion-scale", type=float, default=1.5, help="rotation scale (1.5: up to 2.1 rad/s)"
    )
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed")
    args = p.parse_args(argv)
    if args.frames < 1 or any(m not in (2, 3, 4) for m in args.rigs):
        p.error("--frames >= 1; --rigs: 2, 3 or 4 cameras")
    with one_thread():
        res3 = None
        tables = []
        for m in args.rigs:
            t0 = time.process_time()
            rd = render(m, args.frames, args.motion_scale, seed=args.seed)
            t_render = time.process_time() - t0
            if not tables:  # (warm-up: numba compiles the estimators' kernels on first use)
                run({**rd, "frames": {k: v for k, v in rd["frames"].items() if k[1] < 2}})
            res = run(rd)
            tables.append((m, res, rd, t_render))
            if m == 3:
                res3 = res
        sp = tables[0][1]["speed"]
        print(
            f"rendered {SCENE}, pan x {args.motion_scale:g} (turning {sp.min():.2f}-"
            f"{sp.max():.2f} rad/s, median {np.median(sp):.2f}), {args.frames} rig frames per "
            "rig, AprilTag front end; medians"
        )
        print(
            f"{'cameras':>7s}  {'method':24s} {'posed':>7s} {'rot deg':>9s} {'pos cm':>8s} "
            f"{'w deg/s':>10s} {'ms/frame':>8s}"
        )
        for m, res, _, _ in tables:
            print_table(m, summary(res), ms_digits=2)
        print()
        for m, res, rd, t_render in tables:
            pts = np.median(res["points"], axis=0)
            per = ", ".join(f"{n} {v:g}" for n, v in zip(res["names"], pts, strict=True))
            print(
                f"{m} cameras: correspondences per camera frame (median) {per}; CPU per camera "
                f"frame: render {rd['render_ms']:.0f} ms, front end {rd['frontend_ms']:.1f} ms "
                f"({t_render:.0f} s for the rig's {len(rd['frames'])} camera frames)"
            )
    if res3 is None:
        print("\n(targets need the 3-camera rig: --rigs 3)")
        return 0
    print("\ntargets where they apply (the rendered cameras see 8-50 points, not 300)")
    for name, passed, measured in targets(res3):
        print(f"  {'PASS' if passed else 'FAIL'}  {name}: {measured}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
