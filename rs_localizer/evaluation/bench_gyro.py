"""Gyro-aided estimates: ``python -m rs_localizer.evaluation.bench_gyro``.

Per scene of :func:`rs_localizer.sim.planar.make_planar_frame` (``board``: 42 corners 0.8-2 m
away; ``plane``: 300 points 4 m away; ``depth``: the same points spread in depth, a 3D scene;
640x480, 40 us/line, 0.5 px noise, the camera turning at 1-3 rad/s and moving at 0.2-1 m/s),
the median rotation error (deg) and angular and linear velocity errors (rad/s, m/s) of
``r6p_1lin`` (default motion prior, tracking off) against the ground truth:

- ``no gyro``: the image alone;
- ``gyro``: with a simulated 200 Hz gyro (IMU axes rotated from the camera's, the frame's
  constant angular velocity plus a bias of (0.01, -0.02, 0.005) rad/s known to 0.002 rad/s,
  0.003 rad/s noise per sample) turned into a measurement over the frame's readout
  (:func:`~rs_localizer.estimation.gyro.gyro_measurement`);
- ``gyro, rotation 90 deg off``: the same samples with a camera-IMU rotation that is wrong
  by 90 deg about the optical axis (how often the estimator notices and falls back, and the
  error of what it returns);
- ``oracle``: the angular velocity error the gyro measurement itself has.

Then the time per frame with and without the gyro, interleaved frame by frame, one BLAS
thread.

    python -m rs_localizer.evaluation.bench_gyro [--frames 200] [--scenes board plane depth]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ..estimation import EstimateOptions, RansacOptions, estimate_rs_pose, gyro_measurement
from ..estimation.gyro import GyroMeasurement, readout_window
from ..geometry import rotation_angle_deg, rotvec_to_matrix
from ..sim.planar import PlanarFrame, make_planar_frame
from ..sim.trajectory import R_IMU_CAMERA
from .threads import one_thread

RATE_HZ = 200.0
NOISE = 0.003
BIAS = np.array([0.01, -0.02, 0.005])
BIAS_SIGMA = 0.002
#: a camera-IMU rotation wrong by 90 deg about the optical axis
R_WRONG = rotvec_to_matrix(np.array([0.0, 0.0, np.pi / 2]))


def simulated_gyro(
    f: PlanarFrame, rng: np.random.Generator, R_cam_imu: np.ndarray | None = None
) -> GyroMeasurement:
    """A 200 Hz gyro over ``f``'s readout (stamp = its reference line at t = 0): samples of
    the frame's constant angular velocity in IMU axes plus bias and noise, the bias estimate
    off by ``BIAS_SIGMA``, turned into a measurement with ``R_cam_imu`` (default: the true
    ``R_IMU_CAMERA^T``)."""
    window = readout_window(f.camera, 0.0)
    t = np.arange(window[0] - 0.02 - rng.uniform(0, 1 / RATE_HZ), window[1] + 0.02, 1 / RATE_HZ)
    rates = (R_IMU_CAMERA @ f.angular_velocity) + BIAS + rng.normal(0, NOISE, (len(t), 3))
    bias_estimate = BIAS + rng.normal(0, BIAS_SIGMA, 3)
    R = R_IMU_CAMERA.T if R_cam_imu is None else R_cam_imu
    return gyro_measurement(t, rates, window, R, bias_estimate, NOISE, BIAS_SIGMA)


def _errors(e, f: PlanarFrame) -> tuple:
    if not e.success:
        return (np.nan,) * 3
    return (
        rotation_angle_deg(e.orientation, f.orientation),
        float(np.linalg.norm(e.angular_velocity - f.angular_velocity)),
        float(np.linalg.norm(e.linear_velocity - f.linear_velocity)),
    )


def run_scene(scene: str, frames: int, seed: int = 0) -> dict:
    """Errors per row (frames x 3: rotation deg, angular rad/s, linear m/s), fall-backs of the
    wrong-rotation row, the gyro's own error, and the interleaved times (ms)."""
    rng = np.random.default_rng(seed)
    opts = EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12))
    rows = {"no gyro": [], "gyro": [], "gyro, rotation 90 deg off": []}
    rejected = {k: 0 for k in rows}
    used = {k: 0 for k in rows}
    ms = {"no gyro": [], "gyro": []}
    own = []
    for _ in range(frames):
        f = make_planar_frame(rng, scene)
        g = simulated_gyro(f, rng)
        bad = simulated_gyro(f, rng, R_WRONG @ R_IMU_CAMERA.T)
        own.append(float(np.linalg.norm(g.angular_velocity - f.angular_velocity)))
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
    m = res["ms"]
    print(
        f"time per frame: {m['gyro']:.2f} ms with gyro, {m['no gyro']:.2f} ms without "
        f"(ratio {m['gyro'] / m['no gyro']:.2f}, interleaved)"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--scenes", nargs="+", default=["board", "plane", "depth"])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    with one_thread():
        # compile the kernels before timing
        f = make_planar_frame(0, "board")
        estimate_rs_pose(
            f.points_px, f.X, f.camera, gyro=simulated_gyro(f, np.random.default_rng(0))
        )
        for scene in args.scenes:
            print_scene(scene, run_scene(scene, args.frames, args.seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
