"""A simulated gyro over one planar frame's readout: the measurements of the gyro-aided
estimate's tests and of ``python -m benchmarks.bench_gyro`` (docs/video.md "Gyro").

A 200 Hz gyro (:data:`RATE_HZ`) mounted as
:data:`~rs_localizer.sim.trajectory.R_IMU_CAMERA`, with a bias :data:`BIAS` (rad/s) known to
:data:`BIAS_SIGMA` and white noise :data:`NOISE` (rad/s per sample)."""

from __future__ import annotations

import numpy as np

from ..estimation.gyro import GyroMeasurement
from ..geometry import rotvec_to_matrix
from ..tracking.gyro import gyro_measurement, readout_window
from .planar import PlanarFrame
from .trajectory import R_IMU_CAMERA

__all__ = ["BIAS", "BIAS_SIGMA", "NOISE", "RATE_HZ", "R_WRONG", "simulated_gyro"]

#: Hz: the gyro's sample rate
RATE_HZ = 200.0
#: rad/s: the white noise of each sample (per axis)
NOISE = 0.003
#: rad/s: the gyro's bias (IMU axes)
BIAS = np.array([0.01, -0.02, 0.005])
#: rad/s: the error of the bias estimate handed to the measurement (per axis)
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
