"""Global-shutter and fast-readout cameras: a frame that cannot show motion is posed on the
global-shutter model (as P3P poses it), never refused where P3P solves it, and a frame that does
show motion keeps the rolling-shutter model. Ground truth: the paper protocol's simulated
poses."""

import numpy as np
import pytest

from rs_localizer.estimation import EstimateOptions, RansacOptions, estimate_rs_pose
from rs_localizer.estimation.finalize import MOTION_SIGNIFICANCE_CHI2, motion_chi2
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.planar import make_planar_frame, planar_camera
from rs_localizer.sim.synthetic import IMAGE_SIZE, make_frame, paper_camera

LINE_DELAYS = (0.0, 1e-9, 1e-7, 1e-6, 2e-6)


@pytest.fixture(scope="module")
def still_frames():
    return [
        make_frame(k, n_points=100, rs_speed=0.0, noise_px=1.0, outlier_ratio=0.2)
        for k in range(12)
    ]


def _solve(frames, line_delay, solver):
    camera = paper_camera(line_delay * IMAGE_SIZE)
    return [
        estimate_rs_pose(
            f.points_px, f.X, camera, solver, EstimateOptions(ransac=RansacOptions(seed=k))
        )
        for k, f in enumerate(frames)
    ]


@pytest.mark.parametrize("line_delay", LINE_DELAYS)
def test_a_camera_at_rest_is_posed_as_p3p_poses_it(still_frames, line_delay):
    gs = _solve(still_frames, line_delay, "p3p")
    rs = _solve(still_frames, line_delay, "r6p_1lin")
    assert all(e.success for e in gs)
    assert [e.success for e in rs] == [True] * len(rs), [e.failure for e in rs]
    err_gs = [rotation_angle_deg(e.model.R, f.R) for e, f in zip(gs, still_frames, strict=True)]
    err_rs = [rotation_angle_deg(e.model.R, f.R) for e, f in zip(rs, still_frames, strict=True)]
    assert np.median(err_rs) <= 1.05 * np.median(err_gs)
    for e in rs:
        assert e.solver == "r6p_1lin"
        assert e.motion_model == "global_shutter"
        np.testing.assert_array_equal(e.model.w, 0.0)
        np.testing.assert_array_equal(e.model.t, 0.0)
        np.testing.assert_array_equal(e.pose.angular_velocity, 0.0)
        if line_delay == 0.0:
            assert e.twist_covariance is None  # (nothing observed: unknown)
            np.testing.assert_array_equal(e.covariance[6:, :], 0.0)
        else:  # (what the frame says of its motion: none, within this)
            assert e.twist_covariance is not None
            assert np.all(np.diag(e.twist_covariance) > 0)
            # (the (12, 12) covariance says the same of the velocities: ROS twist order is
            # linear, angular; the (12, 12)'s is angular, linear)
            v, w = e.twist_covariance[:3, :3], e.twist_covariance[3:, 3:]
            np.testing.assert_allclose(e.covariance[6:9, 6:9], w, rtol=1e-9)
            np.testing.assert_allclose(e.covariance[9:12, 9:12], v, rtol=1e-9)


def test_a_turning_fast_readout_camera_keeps_the_rolling_shutter_model():
    # 10 rad/s with 2 us per line: ~24 px of rolling-shutter shift over the 1000 lines
    d = 2e-6
    turn = np.degrees(10.0 * d * IMAGE_SIZE)
    frames = [
        make_frame(
            k,
            n_points=100,
            rot_per_frame_deg=turn,
            trans_per_frame=0.0,
            noise_px=1.0,
            outlier_ratio=0.2,
            readout_time=d * IMAGE_SIZE,
        )
        for k in range(10)
    ]
    rs = _solve(frames, d, "r6p_1lin")
    gs = _solve(frames, d, "p3p")
    assert [e.motion_model for e in rs] == ["rolling_shutter"] * len(rs)
    err_rs = [rotation_angle_deg(e.model.R, f.R) for e, f in zip(rs, frames, strict=True)]
    err_gs = [rotation_angle_deg(e.model.R, f.R) for e, f in zip(gs, frames, strict=True)]
    assert np.median(err_rs) < 0.7 * np.median(err_gs)
    w_err = [
        np.linalg.norm(e.pose.angular_velocity - f.angular_velocity)
        for e, f in zip(rs, frames, strict=True)
    ]
    assert np.median(w_err) < 3.0  # rad/s, of 10 (2 ms of readout: ~1 rad/s of noise)


def test_a_moving_rolling_shutter_camera_is_unchanged():
    # the paper protocol at half its maximum speed, 30 us per line: motion far above the noise
    frames = [make_frame(k, n_points=100, rs_speed=0.5, noise_px=1.0) for k in range(6)]
    camera = paper_camera(0.03)
    for k, f in enumerate(frames):
        est = estimate_rs_pose(
            f.points_px, f.X, camera, options=EstimateOptions(ransac=RansacOptions(seed=k))
        )
        assert est.motion_model == "rolling_shutter"
        assert np.linalg.norm(est.pose.angular_velocity - f.angular_velocity) < 0.5


def test_motion_chi2_is_the_mahalanobis_distance_of_the_velocities():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(12, 12))
    cov = A @ A.T + np.eye(12)
    w, t = rng.normal(size=3), rng.normal(size=3)
    z = np.concatenate([w, t])
    expected = z @ np.linalg.inv(cov[6:, 6:]) @ z
    assert motion_chi2(cov, w, t) == pytest.approx(expected, rel=1e-10)
    assert motion_chi2(None, w, t) == np.inf
    bad = cov.copy()
    bad[7, 7] = np.nan
    assert motion_chi2(bad, w, t) == np.inf
    # (the 0.999 quantile of chi-square with 6 degrees of freedom)
    from scipy.stats import chi2

    assert pytest.approx(chi2.ppf(0.999, 6), abs=1e-3) == MOTION_SIGNIFICANCE_CHI2


# planar scenes (a board): one plane barely separates the velocities from the pose, so the
# decision is on the posterior of the planar problem with the motion prior
PLANAR_DELAYS = (1e-9, 1e-7, 1e-6, 2e-6)


def _planar_board(k, line_delay, moving, angular_speed=(1.0, 3.0)):
    speeds = (
        {"angular_speed": angular_speed, "linear_speed": (0.2, 1.0)}
        if moving
        else {"angular_speed": (0.0, 0.0), "linear_speed": (0.0, 0.0)}
    )
    return make_planar_frame(k, "board", camera=planar_camera(line_delay), **speeds)


def _planar_solve(frames, solver):
    return [
        estimate_rs_pose(
            f.points_px, f.X, f.camera, solver, EstimateOptions(ransac=RansacOptions(seed=k))
        )
        for k, f in enumerate(frames)
    ]


@pytest.mark.parametrize("line_delay", PLANAR_DELAYS)
def test_a_board_at_rest_is_posed_as_p3p_poses_it(line_delay):
    frames = [_planar_board(k, line_delay, False) for k in range(20)]
    gs, rs = _planar_solve(frames, "p3p"), _planar_solve(frames, "r6p_1lin")
    assert all(e.success for e in gs)
    assert [e.success for e in rs] == [True] * len(rs), [e.failure for e in rs]
    assert all(e.planar for e in rs)
    err_gs = [rotation_angle_deg(e.model.R, f.R) for e, f in zip(gs, frames, strict=True)]
    err_rs = [rotation_angle_deg(e.model.R, f.R) for e, f in zip(rs, frames, strict=True)]
    # (the benchmark: 1.001x at 2 us; of these 20, one frame at rest that keeps the
    # rolling-shutter model sits at the median)
    assert np.median(err_rs) <= 1.1 * np.median(err_gs)
    on_gs = [k for k, e in enumerate(rs) if e.motion_model == "global_shutter"]
    assert len(on_gs) >= 17
    for k in on_gs:  # (the pose P3P gives the same points)
        assert err_rs[k] <= 1.05 * err_gs[k] + 0.005
        e = rs[k]
        np.testing.assert_array_equal(e.model.w, 0.0)
        np.testing.assert_array_equal(e.model.t, 0.0)
        assert e.twist_covariance is not None and np.all(np.diag(e.twist_covariance) > 0)


def test_a_moving_board_keeps_the_rolling_shutter_model():
    # a hand-held camera (2-3 rad/s, 0.2-1 m/s) at 30 us per line: 17-26 px of readout motion
    frames = [_planar_board(k, 30e-6, True, (2.0, 3.0)) for k in range(10)]
    rs, gs = _planar_solve(frames, "r6p_1lin"), _planar_solve(frames, "p3p")
    assert [e.motion_model for e in rs] == ["rolling_shutter"] * len(rs)
    err_rs = [rotation_angle_deg(e.model.R, f.R) for e, f in zip(rs, frames, strict=True)]
    err_gs = [rotation_angle_deg(e.model.R, f.R) for e, f in zip(gs, frames, strict=True)]
    assert np.median(err_rs) < 0.5 * np.median(err_gs)


def _three_tags(k, line_delay):
    """Three 10 cm tags in a row (12 corners) at rest where :func:`_planar_board` puts the
    board, 0.5 px noise."""
    f = _planar_board(k, line_delay, False)
    h = 0.05
    X = np.concatenate(
        [
            np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]]) + [0.15 * i, 0, 0]
            for i in (-1, 0, 1)
        ]
    )
    px = f.camera.project_rs(X, f.R, f.C) + np.random.default_rng(k).normal(0, 0.5, (12, 2))
    return px, X, f.camera, f.R


@pytest.mark.parametrize("line_delay", (1e-9, 2e-6))
def test_three_tags_at_rest_are_posed_as_p3p_poses_them(line_delay):
    # (12 corners: too few for the F test to mean "small"; the chi-square median decides)
    frames = [_three_tags(k, line_delay) for k in range(12)]
    ests = {
        solver: [
            estimate_rs_pose(px, X, cam, solver, EstimateOptions(ransac=RansacOptions(seed=k)))
            for k, (px, X, cam, _) in enumerate(frames)
        ]
        for solver in ("p3p", "r6p_1lin")
    }
    both = [k for k, e in enumerate(ests["p3p"]) if e.success]
    assert len(both) >= 10
    rs = [ests["r6p_1lin"][k] for k in both]
    assert all(e.success and not e.single_tag for e in rs), [e.failure for e in rs]
    assert sum(e.motion_model == "global_shutter" for e in rs) >= len(both) - 1
    err = {
        solver: [rotation_angle_deg(ests[solver][k].model.R, frames[k][3]) for k in both]
        for solver in ests
    }
    assert np.median(err["r6p_1lin"]) <= 1.05 * np.median(err["p3p"])
