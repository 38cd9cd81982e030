"""The pixel-residual benchmark's protocol on a few frames: both variants pose every frame and
the measured image's errors label the inliers by their true pixel error."""

import numpy as np

from benchmarks.bench_pixel_residuals import run


def test_pixel_residuals_label_inliers_by_true_pixel_error():
    res = run(frames=3, points=200, solver="p3p", rolling=False)
    on, off = res[True], res[False]
    assert on.shape == off.shape == (3, 5) and np.isfinite(on[:, :4]).all()
    assert on[:, 2].sum() <= 3 < off[:, 2].sum()
    assert np.all(np.abs(on[:, 3] - 1.0) < 0.15)
