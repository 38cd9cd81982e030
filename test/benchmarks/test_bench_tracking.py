"""``python -m benchmarks.bench_tracking``: the interval it prints beside its accuracy ratios,
against the ratio's sampling distribution found by simulating many videos, and its run over a
short rendered video."""

import numpy as np
import pytest
from helpers.videos import shake_video

from benchmarks.bench_tracking import median_ratio_interval, run_video


def _ar1_errors(rng, n: int, rho: float, videos: int = 1) -> np.ndarray:
    """(videos, n) positive per-frame errors whose logs are an AR(1) series (correlation
    ``rho`` between neighbouring frames, unit variance)."""
    z = np.empty((videos, n))
    z[:, 0] = rng.standard_normal(videos)
    e = rng.standard_normal((videos, n)) * np.sqrt(1 - rho**2)
    for k in range(1, n):
        z[:, k] = rho * z[:, k - 1] + e[:, k]
    return np.exp(0.5 * z)


def _monte_carlo_width(rng, n: int, rho: float, ratio: float) -> float:
    a = ratio * _ar1_errors(rng, n, rho, 2000)
    b = _ar1_errors(rng, n, rho, 2000)
    r = np.median(a, axis=1) / np.median(b, axis=1)
    lo, hi = np.quantile(r, [0.025, 0.975])
    return hi - lo


def test_a_constant_ratio_has_a_zero_width_interval():
    b = np.random.default_rng(0).exponential(size=300)
    lo, hi = median_ratio_interval(1.2 * b, b)
    assert lo == pytest.approx(1.2) and hi == pytest.approx(1.2)


@pytest.mark.parametrize("rho, block", [(0.0, 1), (0.95, 30)])
def test_interval_width_matches_the_sampling_distribution(rho, block):
    """Independent frames resampled one by one, and correlated frames resampled in 30-frame
    runs, give intervals as wide as the spread of the ratio over many simulated videos."""
    rng = np.random.default_rng(1)
    want = _monte_carlo_width(rng, 300, rho, 1.2)
    widths, covered = [], 0
    for _ in range(20):
        a, b = 1.2 * _ar1_errors(rng, 300, rho)[0], _ar1_errors(rng, 300, rho)[0]
        lo, hi = median_ratio_interval(a, b, block=block, resamples=500)
        widths.append(hi - lo)
        covered += lo <= 1.2 <= hi
    assert 0.6 * want < np.median(widths) < 1.4 * want
    assert covered >= 15


def test_frame_by_frame_resampling_is_too_narrow_for_correlated_errors():
    rng = np.random.default_rng(2)
    a, b = 1.2 * _ar1_errors(rng, 300, 0.95)[0], _ar1_errors(rng, 300, 0.95)[0]
    lo1, hi1 = median_ratio_interval(a, b, block=1, resamples=500)
    lo30, hi30 = median_ratio_interval(a, b, block=30, resamples=500)
    assert hi30 - lo30 > 1.5 * (hi1 - lo1)


def test_frames_not_posed_are_left_out():
    rng = np.random.default_rng(3)
    b = rng.exponential(size=300)
    a = 1.5 * b
    a[::7] = np.nan  # not posed with the first method
    lo, hi = median_ratio_interval(a, b, block=1)
    assert lo < 1.5 < hi or lo == pytest.approx(1.5) or hi == pytest.approx(1.5)
    assert hi - lo < 0.4


@pytest.mark.parametrize(
    "a, b, kw",
    [
        (np.ones(10), np.ones(9), {}),
        (np.ones((10, 2)), np.ones((10, 2)), {}),
        (np.ones(10), np.ones(10), {"block": 11}),
        (np.ones(10), np.ones(10), {"block": 5, "level": 1.0}),
    ],
)
def test_bad_input_is_refused(a, b, kw):
    with pytest.raises(ValueError):
        median_ratio_interval(a, b, **kw)


@pytest.fixture(scope="module")
def video():
    return shake_video(1.0, 10, seed=1)


@pytest.mark.slow  # (renders a map and a video)
def test_benchmark_run_reports_kinds_errors_and_shuffled_positions(video):
    """``bench_tracking.run_video`` on the short video with its truth: the first frame global,
    the rest tracked; every inlier's distance to its true projection sub-pixel; the position
    re-estimated with each tracked frame's own pixel errors shuffled among its inliers is there
    for tracked frames only, and as close to the truth as the tracked estimate (both from the
    same sub-pixel errors)."""
    fmap, frames, camera, renderer, motion = video
    r = run_video(fmap, [(f, False) for f in frames], camera, True, truth=(renderer, motion))
    tracked = r["kind"] == "tracked"
    assert r["kind"][0] == "global" and tracked[1:].all()
    assert np.isfinite(r["pos"]).all()
    assert np.isnan(r["pos_shuffled"][0]) and np.isfinite(r["pos_shuffled"][1:]).all()
    assert np.median(r["px_err"]) < 0.5 and set(np.unique(r["px_kind"])) <= {0, 1, 2}
    # (a few mm at most, like the frames' own estimates)
    assert r["pos_shuffled"][1:].max() < 0.01, r["pos_shuffled"]
    assert np.median(r["pos_shuffled"][1:]) < 3 * np.median(r["pos"][1:]) + 1e-3
