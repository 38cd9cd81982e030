"""The gyro benchmark's floor rows (the final refinement started from the simulated truth on
the true inliers): they end near the simulated pose and velocities, and the gyro-aided floor's
angular velocity is the gyro's, far closer to the truth than the image alone gives."""

import numpy as np

from benchmarks.bench_gyro import floor_errors
from rs_localizer.estimation import EstimateOptions, RansacOptions
from rs_localizer.sim.gyro import simulated_gyro
from rs_localizer.sim.planar import make_planar_frame


def test_floor_rows_end_at_the_simulated_truth():
    rng = np.random.default_rng(0)
    opts = EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12))
    for _ in range(3):
        f = make_planar_frame(rng, "depth")
        g = simulated_gyro(f, rng)
        gyro_err = float(np.linalg.norm(g.angular_velocity - f.angular_velocity))
        rot, ang, lin = floor_errors(f, opts, None)
        rot_g, ang_g, lin_g = floor_errors(f, opts, g)
        assert rot < 0.05 and rot_g < 0.05  # deg
        assert ang < 0.2 and lin < 0.5  # rad/s, m/s
        assert ang_g < 2 * gyro_err + 0.005 < ang
        assert lin_g < 0.5
