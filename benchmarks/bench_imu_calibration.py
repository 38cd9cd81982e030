"""How honest are the standard deviations ``calibrate-readout --imu-topic`` prints?

    python -m benchmarks.bench_imu_calibration [--motions shake,pan] [--seeds 6]

For each motion and seed: a 60-frame synthetic video (:func:`generate_sequence`, 1280x720,
30 us/line, 500 correspondences, 0.5 px noise, 20 % outliers) and a 200 Hz gyro
(:func:`imu_samples`: mounted as ``R_IMU_CAMERA``, bias (0.01, -0.02, 0.005) rad/s, 0.003 rad/s
noise), the library's calibration (:func:`per_frame_rates` + :func:`fit_line_delay`, as the
command runs it), and the errors of the camera-IMU rotation (about the camera's axes) and of
the bias against the simulation, in degrees, rad/s and in units of the printed std. Per motion:
the RMS and the largest |error| / std (1 and about 2.5 for honest stds over 18 values) and the
verdicts.
"""

from __future__ import annotations

import argparse

import numpy as np

from rs_localizer.calibration.readout import fit_line_delay, per_frame_rates
from rs_localizer.geometry import matrix_to_rotvec
from rs_localizer.sim.trajectory import (
    R_IMU_CAMERA,
    SequenceConfig,
    default_camera,
    generate_sequence,
    imu_samples,
    make_trajectory,
)

TRUE_BIAS = np.array([0.01, -0.02, 0.005])


def run(motion: str, seed: int) -> dict:
    """One calibration of ``motion`` with ``seed``: errors, stds and verdicts."""
    cfg = SequenceConfig(num_frames=60, seed=seed)
    traj = make_trajectory(motion)
    frames, _, cam, _ = generate_sequence(
        cfg, camera=default_camera(line_delay=30e-6), trajectory=traj
    )
    ti, om, _ = imu_samples(traj, -0.2, 2.2, 200.0, seed=seed + 100)
    gyro = (cfg.t0_ns + np.round(ti * 1e9).astype(np.int64), om)
    stamps, Os, ws, failed = per_frame_rates([(f.stamp_ns, f.uv, f.xyz) for f in frames], cam)
    res = fit_line_delay(stamps, Os, ws, cam, gyro=gyro, frames_failed=failed)
    rot_err = matrix_to_rotvec(res.camera_imu_rotation @ R_IMU_CAMERA)  # camera axes
    return {
        "line_delay_us": res.line_delay * 1e6 if res.line_delay else float("nan"),
        "rot_err_deg": np.degrees(rot_err),
        "rot_std_deg": np.degrees(res.camera_imu_rotation_std),
        "bias_err": res.gyro_bias - TRUE_BIAS,
        "bias_std": res.gyro_bias_std,
        "rotation_observable": res.camera_imu_rotation_observable,
        "bias_observable": res.gyro_bias_observable,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--motions", default="shake,pan")
    ap.add_argument("--seeds", type=int, default=6)
    args = ap.parse_args(argv)
    np.set_printoptions(precision=4, suppress=True)
    for motion in args.motions.split(","):
        zr, zb, flagged = [], [], 0
        for seed in range(args.seeds):
            r = run(motion, seed)
            zr.append(r["rot_err_deg"] / r["rot_std_deg"])
            zb.append(r["bias_err"] / r["bias_std"])
            flagged += not r["rotation_observable"]
            print(
                f"{motion} seed {seed}: line delay {r['line_delay_us']:.2f} us; rotation error "
                f"{r['rot_err_deg']} deg, std {r['rot_std_deg']}; bias error {r['bias_err']} "
                f"rad/s, std {r['bias_std']}; observable: rotation {r['rotation_observable']}, "
                f"bias {r['bias_observable']}",
                flush=True,
            )
        zr, zb = np.abs(np.array(zr)), np.abs(np.array(zb))
        print(
            f"{motion}: |error| / std, rotation RMS {np.sqrt(np.mean(zr**2, 0))} max "
            f"{zr.max():.2f}; bias RMS {np.sqrt(np.mean(zb**2, 0))} max {zb.max():.2f}; "
            f"rotation flagged not observable in {flagged} of {args.seeds}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
