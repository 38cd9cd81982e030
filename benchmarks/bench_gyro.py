"""Gyro-aided estimates: ``python -m benchmarks.bench_gyro``.

Per scene of :func:`rs_localizer.sim.planar.make_planar_frame` (``board``: 42 corners 0.8-2 m
away; ``plane``: 300 points 4 m away; ``depth``: the same points spread in depth, a 3D scene;
640x480, 40 us/line, 0.5 px noise, the camera turning at 1-3 rad/s and moving at 0.2-1 m/s),
the median rotation error (deg) and angular and linear velocity errors (rad/s, m/s) of
``r6p_1lin`` (default motion prior, tracking off) against the ground truth:

- ``no gyro``: the image alone;
- ``gyro``: with a simulated 200 Hz gyro (:func:`rs_localizer.sim.gyro.simulated_gyro`: IMU
  axes rotated from the camera's, the frame's constant angular velocity plus a bias of
  (0.01, -0.02, 0.005) rad/s known to 0.002 rad/s, 0.003 rad/s noise per sample) turned
  into a measurement over the frame's readout
  (:func:`~rs_localizer.tracking.gyro.gyro_measurement`);
- ``gyro, rotation 90 deg off``: the same samples with a camera-IMU rotation that is wrong
  by 90 deg about the optical axis (how often the estimator notices and falls back, and the
  error of what it returns);
- ``oracle``: the angular velocity error the gyro measurement itself has;
- ``floor``: the best achievable, the estimator's final refinement (exact model, its motion
  prior; with the gyro: the gyro-aided prior) started from the ground truth on the true
  inliers, without and with the gyro.

With a gyro RANSAC solves its 5-point samples with the gyro's angular velocity
(:func:`~rs_localizer.solvers.r5p_w.r5p_w_batch`); the ``gyro`` rows show it.

Then the time per frame with and without the gyro, interleaved frame by frame, one BLAS
thread; and the same on the scene's frames with a fraction ``--outliers`` (default 0.5) of
the correspondences replaced by random pixels: the hypotheses RANSAC drew (adaptive
termination: 5-point samples with the gyro, 6 without) and the time per frame.

``--video``: online gyro-bias estimation instead. A synthetic video
(:func:`rs_localizer.sim.trajectory.generate_sequence`, 1280x720, 30 us/line, 500
correspondences per frame with 0.5 px noise and 20 % outliers, 30 fps, the ``shake``
hand-held trajectory by default) with a simulated 200 Hz gyro
(:func:`~rs_localizer.sim.trajectory.imu_samples`: 0.003 rad/s noise per sample, mounted as
``R_IMU_CAMERA``), tracked as the node tracks a video, by
:class:`~rs_localizer.tracking.sequence.SequenceLocalizer` (the tracker, each frame's gyro
measurement, the online bias estimate, the check of the gyro against the image; initial bias 0,
sigma 0.05 rad/s). Rows: a gyro with a bias of 0.05 rad/s per axis, estimated
online; the same bias not estimated (the initial value and sigma kept, as
``imu.estimate_bias: false``); a gyro without bias (estimated online too, the reference); no
gyro. Printed: the bias error at 1, 2, 5 and 10 s, and the median errors against ground truth
of the per-frame pose (rotation deg, position cm) and of the fused twist (the smoother's final
states: angular rad/s, linear m/s), with their ratios to the zero-bias run.

``--video --mount``: the check of the gyro against the rotation between frames
(:class:`~rs_localizer.tracking.gyro_check.GyroMountCheck`, as the node runs it: frames solved
without the gyro while it is declared inconsistent, the bias estimator not fed then) on the
same kind of video of a planar scene (``--scene plane``, the default: 500 points on a wall 8 m
ahead, :func:`~rs_localizer.sim.planar.sequence_scene`) or the corridor; the gyro's bias of
0.05 rad/s per axis estimated online. Rows: no gyro; the right mount; a mount 90 deg off about
the optical axis, with and without the check; the gyro's stamps 10 ms late (``imu.time_offset``
left at 0), with and without the check (``--rows`` picks some). Printed: the frame at which
the gyro was first declared inconsistent, how often, the frames solved without it because of
that, and the median errors against ground truth with their ratios to no gyro.

    python -m benchmarks.bench_gyro [--frames 200] [--scenes board plane depth]
        [--outliers 0.5]
    python -m benchmarks.bench_gyro --video [--seconds 10] [--motion shake]
    python -m benchmarks.bench_gyro --video --mount [--scene plane] [--seconds 10]
    python -m benchmarks.bench_gyro --false-alarms [--frames 300]

``--false-alarms``: how often a right gyro is refused (:func:`run_false_alarms`), with the
time per frame with and without the gyro.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from rs_localizer.estimation import (
    EstimateOptions,
    RansacOptions,
    estimate_rs_pose,
    physical_velocities,
)
from rs_localizer.estimation.finalize import final_refinement
from rs_localizer.estimation.frame import configure_frame, prepare_frame
from rs_localizer.estimation.gyro import GyroMeasurement, gyro_prior
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.gyro import NOISE, R_WRONG, RATE_HZ, simulated_gyro
from rs_localizer.sim.planar import PlanarFrame, make_planar_frame, sequence_scene
from rs_localizer.sim.trajectory import (
    R_IMU_CAMERA,
    SequenceConfig,
    generate_sequence,
    imu_samples,
    make_trajectory,
)
from rs_localizer.tracking.gyro import ImuBuffer
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import GyroSettings, SequenceLocalizer, SequenceSettings


def _errors(e, f: PlanarFrame) -> tuple:
    if not e.success:
        return (np.nan,) * 3
    return (
        rotation_angle_deg(e.pose.orientation, f.orientation),
        float(np.linalg.norm(e.pose.angular_velocity - f.angular_velocity)),
        float(np.linalg.norm(e.pose.linear_velocity - f.linear_velocity)),
    )


def floor_errors(f: PlanarFrame, opts: EstimateOptions, gyro: GyroMeasurement | None) -> tuple:
    """Errors (rotation deg, angular rad/s, linear m/s) of the estimator's final refinement
    (:func:`~rs_localizer.estimation.finalize.final_refinement`: exact model, truncated Huber
    loss, the options' motion prior, with ``gyro`` the gyro-aided prior) started from the
    ground truth on the true inliers: the best the estimator can reach on the frame."""
    if gyro is not None:
        opts = replace(opts, motion_prior=gyro_prior(gyro, opts.motion_prior))
    fr = prepare_frame(f.points_px[f.inlier], f.X[f.inlier], f.camera, np.inf)
    configure_frame(
        fr,
        f.camera,
        "r6p_1lin",
        opts.ransac.min_inliers,
        opts.ransac.threshold_px,
        (np.inf, np.inf),
        opts.motion_prior,
    )
    th = opts.ransac.threshold_px / fr.f
    ref, _, _ = final_refinement(fr, (f.R, f.C, f.w, f.t), th, True, fr.final_prior)
    omega, v, _, _ = physical_velocities(ref.R, ref.C, ref.w, ref.t, fr.spr)
    return (
        rotation_angle_deg(ref.R.T, f.orientation),
        float(np.linalg.norm(omega - f.angular_velocity)),
        float(np.linalg.norm(v - f.linear_velocity)),
    )


def run_scene(scene: str, frames: int, seed: int = 0) -> dict:
    """Errors per row (frames x 3: rotation deg, angular rad/s, linear m/s), fall-backs of the
    wrong-rotation row, the gyro's own error, the floor's median errors (:func:`floor_errors`)
    and the interleaved times (ms)."""
    rng = np.random.default_rng(seed)
    opts = EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12))
    rows = {"no gyro": [], "gyro": [], "gyro, rotation 90 deg off": []}
    rejected = {k: 0 for k in rows}
    used = {k: 0 for k in rows}
    ms = {"no gyro": [], "gyro": []}
    own = []
    floor = {"floor, no gyro": [], "floor, gyro": []}
    for _ in range(frames):
        f = make_planar_frame(rng, scene)
        g = simulated_gyro(f, rng)
        bad = simulated_gyro(f, rng, R_WRONG @ R_IMU_CAMERA.T)
        own.append(float(np.linalg.norm(g.angular_velocity - f.angular_velocity)))
        floor["floor, no gyro"].append(floor_errors(f, opts, None))
        floor["floor, gyro"].append(floor_errors(f, opts, g))
        for name, gyro in (("no gyro", None), ("gyro", g), ("gyro, rotation 90 deg off", bad)):
            t0 = time.perf_counter()
            e = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", opts, gyro=gyro)
            if name in ms:
                ms[name].append((time.perf_counter() - t0) * 1e3)
            rows[name].append(_errors(e, f))
            rejected[name] += int(e.gyro_rejected)
            used[name] += int(e.gyro_used)
    return dict(
        rows={k: np.array(v) for k, v in rows.items()},
        rejected=rejected,
        used=used,
        ms={k: float(np.median(v)) for k, v in ms.items()},
        gyro_error=float(np.median(own)),
        floor={k: np.nanmedian(np.array(v), axis=0) for k, v in floor.items()},
    )


def run_outliers(scene: str, frames: int, ratio: float, seed: int = 0) -> dict:
    """Median hypotheses drawn and time per frame (ms) with and without the gyro, interleaved,
    on ``scene`` frames with ``ratio`` outliers, and the median rotation errors (deg)."""
    rng = np.random.default_rng(seed)
    opts = EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12))
    rows = {"no gyro": [], "gyro": []}
    for _ in range(frames):
        f = make_planar_frame(rng, scene, outlier_ratio=ratio)
        g = simulated_gyro(f, rng)
        for name, gyro in (("no gyro", None), ("gyro", g)):
            t0 = time.perf_counter()
            e = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", opts, gyro=gyro)
            ms = (time.perf_counter() - t0) * 1e3
            rows[name].append((e.ransac_iterations, ms, _errors(e, f)[0]))
    return {k: np.nanmedian(np.array(v), axis=0) for k, v in rows.items()}


def print_outliers(ratio: float, res: dict) -> None:
    """The outlier line of a scene."""
    a, b = res["gyro"], res["no gyro"]
    print(
        f"at {100 * ratio:g} % outliers: {a[0]:.0f} hypotheses with gyro, {b[0]:.0f} without; "
        f"{a[1]:.2f} ms with gyro, {b[1]:.2f} ms without (ratio {a[1] / b[1]:.2f}, "
        f"interleaved); rotation {a[2]:.3f} / {b[2]:.3f} deg"
    )


def print_scene(scene: str, res: dict) -> None:
    """The scene's table."""
    print(f"\n{scene}: median over frames (success / gyro used / fell back)")
    print(f"{'':28s} {'rot deg':>8s} {'omega rad/s':>12s} {'v m/s':>8s}   ok/used/fell back")
    for name, a in res["rows"].items():
        ok = np.isfinite(a[:, 0])
        med = np.nanmedian(a, axis=0) if ok.any() else (np.nan,) * 3
        print(
            f"{name:28s} {med[0]:8.3f} {med[1]:12.4f} {med[2]:8.3f}   "
            f"{ok.sum()}/{res['used'][name]}/{res['rejected'][name]}"
        )
    print(f"{'oracle (the gyro itself)':28s} {'':8s} {res['gyro_error']:12.4f}")
    for name, med in res["floor"].items():
        print(f"{name + ' (truth start)':28s} {med[0]:8.3f} {med[1]:12.4f} {med[2]:8.3f}")
    m = res["ms"]
    print(
        f"time per frame: {m['gyro']:.2f} ms with gyro, {m['no gyro']:.2f} ms without "
        f"(ratio {m['gyro'] / m['no gyro']:.2f}, interleaved)"
    )


# ---------------------------------------------------------------------------- video
#: the unknown bias of the video scenario (rad/s per IMU axis), its prior (value, sigma)
VIDEO_BIAS = 0.05
VIDEO_PRIOR = (0.0, 0.05)
#: seconds into the video at which the bias error is printed
BIAS_TIMES = (1.0, 2.0, 5.0, 10.0)


def make_video(
    seconds: float, motion: str = "shake", seed: int = 0, fps: float = 30.0, scene: str = "corridor"
):
    """``(frames, camera, trajectory)`` of a synthetic video (``generate_sequence``; ``scene``
    of :func:`~rs_localizer.sim.planar.sequence_scene`: ``corridor`` or ``plane``, one wall
    8 m ahead)."""
    n = int(round(seconds * fps))
    if scene not in ("corridor", "plane"):
        raise ValueError(f"scene must be corridor or plane, got {scene!r}")
    landmarks, _ = sequence_scene(scene, np.random.default_rng([seed, 16]))
    frames, _, cam, traj = generate_sequence(
        SequenceConfig(num_frames=n, seed=seed, fps=fps),
        trajectory=make_trajectory(motion),
        scene=landmarks,
    )
    return frames, cam, traj


def simulated_imu(
    frames, trajectory, bias: float, seed: int = 0, time_offset: float = 0.0
) -> ImuBuffer:
    """A 200 Hz gyro (``imu_samples``: bias ``bias`` rad/s on every axis, 0.003 rad/s noise)
    over the video, 0.1 s before its first frame to 0.1 s after its last, in an
    :class:`ImuBuffer`, stamped on a clock ``time_offset`` s behind the frames' (``t_cam =
    t_imu + time_offset``, as ``imu.time_offset``)."""
    t0_ns = SequenceConfig().t0_ns
    t_end = (frames[-1].t_ref_ns - t0_ns) * 1e-9 + 0.1
    t, om, _ = imu_samples(
        trajectory, -0.1, t_end, RATE_HZ, seed, NOISE, np.full(3, bias), R_imu_camera=R_IMU_CAMERA
    )
    buf = ImuBuffer(span=np.inf)
    for ti, wi in zip(t, om, strict=True):
        buf.add(t0_ns + int(round((ti - time_offset) * 1e9)), wi)
    return buf


def track_video(
    frames,
    cam,
    imu: ImuBuffer | None,
    estimate_bias: bool,
    true_bias: float,
    R_cam_imu: np.ndarray | None = None,
    check: bool = True,
):
    """Track ``frames`` as the node does, through
    :class:`~rs_localizer.tracking.sequence.SequenceLocalizer`, with the gyro samples of
    ``imu`` (None: no gyro) mounted as ``R_cam_imu`` (default: the simulated mount), the bias
    prior ``VIDEO_PRIOR`` and, with ``estimate_bias``, the bias estimated online; the gyro is
    tested against the rotation between solved frames unless ``check`` is false
    (:class:`~rs_localizer.tracking.gyro_check.GyroMountCheck`: frames solved without it
    while inconsistent, the bias estimator not fed then). Returns per-frame pose errors
    (rotation deg, position m), the fused twist errors (angular rad/s, linear m/s), the bias
    error (rad/s, the largest over the three axes) after each frame with its time, the
    estimator's counts, the mean normalized innovation squared of the pairs it tested (3 for
    a consistent covariance) and the check's results (the frame index of the first
    detection or None, detections, frames solved without the gyro because of it)."""
    gyro = None
    if imu is not None:
        gyro = GyroSettings(
            R_cam_imu=R_IMU_CAMERA.T if R_cam_imu is None else R_cam_imu,
            gyro_noise=NOISE,
            gyro_bias=np.full(3, VIDEO_PRIOR[0]),
            gyro_bias_sigma=VIDEO_PRIOR[1],
            estimate_bias=estimate_bias,
            buffer=np.inf,
        )
    seq = SequenceLocalizer(
        SequenceSettings(
            options=EstimateOptions(ransac=RansacOptions(seed=0)),
            imu=gyro,
            stamp_row=cam.reference_line,  # (the frames are stamped with their reference time)
            check_gyro=check,
        ),
        imu_span=np.inf,
    )
    if imu is not None:
        for t, w in imu.samples():
            seq.add_imu(t, w)
    first_detection = None
    truth = {f.t_ref_ns: f for f in frames}
    pose, finals, bias_err, nis = [], [], [], []
    prior = np.full(3, VIDEO_PRIOR[0])
    for k, f in enumerate(frames):
        tested = _bias_pairs(seq)
        out = seq.process(CameraFrame(f.t_ref_ns, cam, f.uv, f.xyz, f.scores))
        finals += out.fused
        e = out.estimate
        if e.success:
            pose.append(
                (
                    rotation_angle_deg(e.pose.orientation, f.orientation),
                    float(np.linalg.norm(e.pose.position - f.position)),
                )
            )
        if seq.gyro_inconsistent and first_detection is None:
            first_detection = k
        if _bias_pairs(seq) > tested:
            nis.append(seq.gyro_bias.last_nis)
        t = (f.t_ref_ns - frames[0].t_ref_ns) * 1e-9
        values = seq.gyro_bias_values()
        b = values[0] if values is not None else prior
        bias_err.append((t, float(np.abs(b - true_bias).max())))
    finals += seq.flush()
    twist = [
        (
            float(
                np.linalg.norm(x.pose.angular_velocity - truth[x.pose.stamp_ns].angular_velocity)
            ),
            float(np.linalg.norm(x.pose.linear_velocity - truth[x.pose.stamp_ns].linear_velocity)),
        )
        for x in finals
    ]
    est = seq.gyro_bias
    return dict(
        pose=np.array(pose),
        twist=np.array(twist),
        bias=np.array(bias_err),
        counts=dict(est.counts) if est is not None else {"used": 0, "rejected": 0},
        std=est.std if est is not None else np.full(3, VIDEO_PRIOR[1]),
        nis=float(np.mean(nis)) if nis else float("nan"),
        frames=len(frames),
        first_detection=first_detection,
        detections=seq.gyro_check.detections if seq.gyro_check is not None else 0,
        disabled=seq.counts["gyro_disabled_inconsistent"],
    )


def _bias_pairs(seq: SequenceLocalizer) -> int:
    """Pairs the online bias estimator has tested so far (used or rejected)."""
    est = seq.gyro_bias
    return 0 if est is None else est.counts["used"] + est.counts["rejected"]


def run_video(seconds: float, motion: str, seed: int) -> dict:
    """The rows of the ``--video`` table (see the module docstring)."""
    frames, cam, traj = make_video(seconds, motion, seed)
    biased = simulated_imu(frames, traj, VIDEO_BIAS, seed)
    clean = simulated_imu(frames, traj, 0.0, seed)
    return {
        "bias 0.05, estimated": track_video(frames, cam, biased, True, VIDEO_BIAS),
        "bias 0.05, not estimated": track_video(frames, cam, biased, False, VIDEO_BIAS),
        "zero bias, estimated": track_video(frames, cam, clean, True, 0.0),
        "no gyro": track_video(frames, cam, None, False, 0.0),
    }


def print_video(rows: dict, motion: str, seconds: float) -> None:
    """The ``--video`` tables."""
    print(
        f"\n{motion}, {seconds:g} s at 30 fps, 200 Hz gyro; bias {VIDEO_BIAS} rad/s per axis, "
        f"prior {VIDEO_PRIOR[0]} +- {VIDEO_PRIOR[1]}"
    )
    print("bias error (rad/s, the largest of the 3 axes) after:")
    print(
        f"{'':28s} "
        + " ".join(f"{t:>6g} s" for t in BIAS_TIMES)
        + "   pairs used/rejected, final std (rad/s), mean NIS (3 dof)"
    )
    for name, r in rows.items():
        if name == "no gyro":
            continue
        b = r["bias"]
        # (the estimate after the last frame at or before t)
        errs = [
            b[np.searchsorted(b[:, 0], t + 1e-6) - 1, 1] if t <= b[-1, 0] + 0.05 else np.nan
            for t in BIAS_TIMES
        ]
        c = r["counts"]
        print(
            f"{name:28s} "
            + " ".join(f"{e:8.4f}" for e in errs)
            + f"   {c['used']}/{c['rejected']}, {r['std'].max():.4f}, {r['nis']:.1f}"
        )
    med = {
        k: (np.median(r["pose"], axis=0), np.median(r["twist"], axis=0)) for k, r in rows.items()
    }
    p0, w0 = med["zero bias, estimated"]
    print("median errors vs ground truth (ratio to the zero-bias run):")
    print(f"{'':28s} {'rot deg':>14s} {'pos cm':>14s} {'omega rad/s':>16s} {'v m/s':>14s}")
    for name, (p, w) in med.items():
        print(
            f"{name:28s} {p[0]:7.4f} ({p[0] / p0[0]:4.2f}) {100 * p[1]:7.3f} ({p[1] / p0[1]:4.2f}) "
            f"{w[0]:9.4f} ({w[0] / w0[0]:4.2f}) {w[1]:7.4f} ({w[1] / w0[1]:4.2f})"
        )


#: the uncorrected time offset of the ``--mount`` rows (s)
MOUNT_TIME_OFFSET = 0.010


#: the rows of ``--video --mount``: name -> (wrong mount, uncorrected time offset, checked)
MOUNT_ROWS = {
    "right mount": (False, False, True),
    "mount 90 deg off": (True, False, True),
    "mount 90 deg off, no check": (True, False, False),
    f"time offset {MOUNT_TIME_OFFSET * 1e3:g} ms": (False, True, True),
    f"time offset {MOUNT_TIME_OFFSET * 1e3:g} ms, no check": (False, True, False),
}


def run_mount(seconds: float, motion: str, seed: int, scene: str = "plane", rows=None) -> dict:
    """The rows of the ``--video --mount`` table (see the module docstring): the gyro (bias
    0.05 rad/s per axis, estimated online) tested against the rotation between frames;
    ``rows``: names of :data:`MOUNT_ROWS` (default all); ``no gyro`` always."""
    frames, cam, traj = make_video(seconds, motion, seed, scene=scene)
    out = {"no gyro": track_video(frames, cam, None, False, 0.0)}
    for name in rows or MOUNT_ROWS:
        wrong, late, check = MOUNT_ROWS[name]
        imu = simulated_imu(
            frames, traj, VIDEO_BIAS, seed, time_offset=MOUNT_TIME_OFFSET if late else 0.0
        )
        R = R_WRONG @ R_IMU_CAMERA.T if wrong else None
        out[name] = track_video(frames, cam, imu, True, VIDEO_BIAS, R, check=check)
    return out


def print_mount(rows: dict, motion: str, seconds: float, scene: str) -> None:
    """The ``--video --mount`` table."""
    print(
        f"\n{scene}, {motion}, {seconds:g} s at 30 fps, 200 Hz gyro (bias {VIDEO_BIAS} rad/s per "
        "axis, estimated online), checked against the rotation between frames"
    )
    print(
        "detected: frame of the first detection; detections; frames solved without the gyro "
        "because of it; median errors vs ground truth (ratio to no gyro)"
    )
    print(
        f"{'':30s} {'detected':>9s} {'n':>3s} {'w/o':>5s} {'rot deg':>14s} {'pos cm':>14s} "
        f"{'omega rad/s':>16s} {'v m/s':>14s}"
    )
    med = {
        k: (np.median(r["pose"], axis=0), np.median(r["twist"], axis=0)) for k, r in rows.items()
    }
    p0, w0 = med["no gyro"]
    for name, r in rows.items():
        p, w = med[name]
        det = "-" if r["first_detection"] is None else str(r["first_detection"])
        print(
            f"{name:30s} {det:>9s} {r['detections']:3d} {r['disabled']:5d} "
            f"{p[0]:7.4f} ({p[0] / p0[0]:4.2f}) {100 * p[1]:7.3f} ({p[1] / p0[1]:4.2f}) "
            f"{w[0]:9.4f} ({w[0] / w0[0]:4.2f}) {w[1]:7.4f} ({w[1] / w0[1]:4.2f})"
        )


# --------------------------------------------------------------------- false alarms
def run_false_alarms(frames: int, seed: int = 0) -> dict:
    """Frames whose right gyro the estimator refused (``gyro_rejected``), per data set: the
    ``corridor`` (3D) and ``plane`` (a wall 8 m ahead) hand-held ``shake`` videos
    (:func:`make_video`, ``frames`` frames each, a clean 200 Hz gyro: 0.003 rad/s noise, no
    bias, the bias stated to 0.005 rad/s), and ``frames`` single frames of each
    :func:`~rs_localizer.sim.planar.make_planar_frame` scene (``depth``, ``plane``,
    ``board``; :func:`simulated_gyro`). Returns ``{name: (rejected, frames, ms with the gyro,
    ms without)}`` (median times per frame, interleaved, one BLAS thread)."""
    opts = EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12))
    out = {}

    def one(name, rows, args, g):
        t0 = time.perf_counter()
        e = estimate_rs_pose(*args, "r6p_1lin", opts, gyro=g)
        t1 = time.perf_counter()
        estimate_rs_pose(*args, "r6p_1lin", opts)
        rows.append((int(e.gyro_rejected), t1 - t0, time.perf_counter() - t1))

    for scene in ("corridor", "plane"):
        rows: list = []
        video, cam, traj = make_video(frames / 30.0, "shake", seed, scene=scene)
        buf = simulated_imu(video, traj, 0.0, seed)
        lead = int(round(cam.line_time(cam.reference_line) * 1e9))
        span = int(round(cam.line_delay * (cam.lines - 1) * 1e9))
        for f in video:
            first = f.t_ref_ns - lead
            g, _ = buf.measurement((first, first + span), R_IMU_CAMERA.T, np.zeros(3), NOISE, 0.005)
            one(f"{scene} video", rows, (f.uv, f.xyz, cam), g)
        out[f"{scene} video (shake)"] = rows
    rng = np.random.default_rng(seed)
    for scene in ("depth", "plane", "board"):
        rows = []
        for _ in range(frames):
            f = make_planar_frame(rng, scene)
            one(scene, rows, (f.points_px, f.X, f.camera), simulated_gyro(f, rng))
        out[f"{scene} frames"] = rows
    res = {}
    for k, rows in out.items():
        a = np.array(rows)
        res[k] = (int(a[:, 0].sum()), len(a), 1e3 * np.median(a[:, 1]), 1e3 * np.median(a[:, 2]))
    return res


def print_false_alarms(res: dict) -> None:
    """The ``--false-alarms`` table."""
    print(f"{'data':24s} {'refused':>8s} {'frames':>7s} {'ms gyro':>8s} {'ms none':>8s} ratio")
    for k, (r, n, a, b) in res.items():
        print(f"{k:24s} {r:8d} {n:7d} {a:8.2f} {b:8.2f} {a / b:5.2f}")
    r = sum(v[0] for v in res.values())
    n = sum(v[1] for v in res.values())
    print(f"right gyro refused in {r} of {n} frames ({r / n:.4f}; stated false-alarm P = 0.001)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--scenes", nargs="+", default=["board", "plane", "depth"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--outliers", type=float, default=0.5, help="outlier ratio of the cost line")
    ap.add_argument("--video", action="store_true", help="online gyro-bias estimation")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--motion", default="shake")
    ap.add_argument(
        "--mount",
        action="store_true",
        help="with --video: a wrong mount and time offset against the check of the gyro",
    )
    ap.add_argument("--scene", default="plane", choices=["corridor", "plane"], help="--mount scene")
    ap.add_argument(
        "--rows", nargs="+", default=None, choices=list(MOUNT_ROWS), help="--mount rows"
    )
    ap.add_argument(
        "--false-alarms",
        action="store_true",
        help="how often a right gyro is refused (videos of --frames frames, --frames frames "
        "per single-frame scene)",
    )
    args = ap.parse_args(argv)
    if args.false_alarms:
        with one_thread():
            print_false_alarms(run_false_alarms(args.frames, args.seed))
        return 0
    if args.video and args.mount:
        with one_thread():
            rows = run_mount(args.seconds, args.motion, args.seed, args.scene, args.rows)
            print_mount(rows, args.motion, args.seconds, args.scene)
        return 0
    if args.video:
        with one_thread():
            print_video(run_video(args.seconds, args.motion, args.seed), args.motion, args.seconds)
        return 0
    with one_thread():
        # compile the kernels before timing
        f = make_planar_frame(0, "board")
        estimate_rs_pose(
            f.points_px, f.X, f.camera, gyro=simulated_gyro(f, np.random.default_rng(0))
        )
        for scene in args.scenes:
            print_scene(scene, run_scene(scene, args.frames, args.seed))
            print_outliers(
                args.outliers, run_outliers(scene, args.frames, args.outliers, args.seed)
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
