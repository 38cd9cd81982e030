"""One camera's video on each implementation of the estimator: ``python -m
benchmarks.bench_camera_video``.

A synthetic rolling-shutter video (:func:`rs_localizer.sim.trajectory.generate_sequence`:
30 Hz, 0.5 px noise, 20 % outliers, the ``shake`` trajectory by default) through
:class:`~rs_localizer.tracking.sequence.SequenceLocalizer` with the video tracker, optionally
with a 200 Hz gyro (``--gyro``: mounted as ``R_IMU_CAMERA``, 0.003 rad/s noise, its bias
known), once per ``--implementations`` entry (``numpy`` is what a node's frames take while
its kernels compile in the background), the implementations run in turn ``--repeats`` times
(interleaved). One BLAS thread.

    python -m benchmarks.bench_camera_video [--frames 90] [--points 500]
        [--trajectory shake] [--gyro] [--implementations compiled numpy] [--repeats 3]

Prints per implementation the frames posed and their paths (cold, tracked, relocalized,
reset), the frames solved with the gyro, the median rotation (deg) and position (mm) errors
and the angular (rad/s) and linear (m/s) velocity errors of the frames' own and fused twists
against the simulated truth, and the time per frame (wall clock and processor time, the
median over the repeats; the processor time is the steadier on a loaded machine).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.trajectory import (
    R_IMU_CAMERA,
    SequenceConfig,
    generate_sequence,
    imu_samples,
    make_trajectory,
)
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import GyroSettings, SequenceLocalizer, SequenceSettings

__all__ = ["main", "run_video"]

NOISE = 0.003  # rad/s per gyro sample
BIAS = np.array([0.01, -0.02, 0.005])  # rad/s


def _errors(by_stamp, stamp, pose) -> list[float]:
    f = by_stamp[stamp]
    return [
        rotation_angle_deg(pose.orientation, f.orientation),
        1e3 * np.linalg.norm(pose.position - f.position),
        np.linalg.norm(pose.angular_velocity - f.angular_velocity),
        np.linalg.norm(pose.linear_velocity - f.linear_velocity),
    ]


def run_video(frames, cam, gyro, implementation: str) -> dict:
    """The video through a SequenceLocalizer on ``implementation`` (the gyro's samples, if
    any, added first). Returns own and fused errors, paths, wall and processor seconds."""
    imu = None
    if gyro is not None:
        imu = GyroSettings(
            R_cam_imu=R_IMU_CAMERA.T, gyro_noise=NOISE, gyro_bias=BIAS, gyro_bias_sigma=0.001
        )
    seq = SequenceLocalizer(
        SequenceSettings(stamp_row=0.0, imu=imu),
        implementation=lambda solver: implementation,
        imu_span=np.inf,
    )
    if gyro is not None:
        for t, w in zip(*gyro, strict=True):
            seq.add_imu(int(t), w)
    by = {f.t_ref_ns: f for f in frames}
    own, fused, paths, with_gyro = [], [], Counter(), 0
    t0, c0 = time.perf_counter(), time.process_time()
    for f in frames:
        o = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz))
        fused += o.fused
        if o.estimate is not None and o.estimate.success:
            own.append(_errors(by, o.stamp_ns, o.estimate.pose))
            paths[o.path] += 1
            with_gyro += bool(o.estimate.gyro_used)
    fused += seq.flush()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    fz = [_errors(by, g.pose.stamp_ns, g.pose) for g in fused]
    return {"own": own, "fused": fz, "paths": paths, "gyro": with_gyro, "wall": seconds,
            "cpu": cpu}  # fmt: skip


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--points", type=int, default=500)
    ap.add_argument("--trajectory", default="shake")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gyro", action="store_true", help="with a 200 Hz gyro")
    ap.add_argument("--implementations", nargs="+", default=["compiled", "numpy"],
                    choices=["compiled", "numpy"])  # fmt: skip
    ap.add_argument("--repeats", type=int, default=1)
    a = ap.parse_args(argv)
    traj = make_trajectory(a.trajectory)
    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=a.frames, num_points=a.points, seed=a.seed), trajectory=traj
    )
    gyro = None
    if a.gyro:
        t, om, _ = imu_samples(traj, -0.1, a.frames / 30.0 + 0.1, 200.0, a.seed, NOISE, BIAS)
        gyro = (SequenceConfig().t0_ns + np.round(t * 1e9).astype(np.int64), om)
    with one_thread():
        for impl in a.implementations:  # (warm-up: kernels, SciPy's and OpenCV's first calls)
            run_video(frames[:5], cam, gyro, impl)
        runs = {impl: [] for impl in a.implementations}
        for _ in range(max(a.repeats, 1)):  # (interleaved: each implementation in turn)
            for impl in a.implementations:
                runs[impl].append(run_video(frames, cam, gyro, impl))
    n = len(frames)
    gyro_text = ", gyro 200 Hz" if a.gyro else ""
    print(f"{a.trajectory}, {n} frames x {a.points} correspondences{gyro_text}, "
          f"{max(a.repeats, 1)} run(s) per implementation")  # fmt: skip
    print("impl          posed  cold/tracked/reloc/reset  fused  gyro   rot deg   pos mm"
          "  w own  w fused  v own  v fused   ms/frame (processor)")  # fmt: skip
    for impl, rr in runs.items():
        r = rr[0]
        m = np.median(r["own"], axis=0)
        mf = np.median(r["fused"], axis=0) if r["fused"] else np.full(4, np.nan)
        p = r["paths"]
        wall = 1e3 * np.median([x["wall"] for x in rr]) / n
        cpu = 1e3 * np.median([x["cpu"] for x in rr]) / n
        paths = f"{p['cold']}/{p['tracked']}/{p['relocalized']}/{p['reset']}"
        print(f"{impl:10s} {len(r['own']):5d}/{n}  {paths:>24s}  {len(r['fused']):5d}"
              f"  {r['gyro']:4d} {m[0]:9.4f} {m[1]:8.2f} {m[2]:6.4f} {mf[2]:8.4f} {m[3]:6.3f}"
              f" {mf[3]:8.3f}   {wall:6.2f} ({cpu:.2f})")  # fmt: skip


if __name__ == "__main__":
    main()
