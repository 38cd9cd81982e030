"""One square marker in view: its four corners posed alone (too few for the robust
estimator): the plane's ambiguity refused without a prediction and resolved with one, the
estimate's fields, the inlier threshold on a tag whose corners fit a square only roughly.
Ground truth: rendered corners. (Against OpenCV's IPPE and a real tag:
test/benchmarks/test_bench_single_tag.py.)"""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from rs_localizer.camera import CameraModel
from rs_localizer.estimation import (
    EstimateOptions,
    InitialModel,
    RansacOptions,
    estimate_rs_pose,
    physical_velocities,
)
from rs_localizer.estimation.result import FAILURE_REASONS
from rs_localizer.estimation.single_tag import AMBIGUITY_CHI2, MIN_CORNER_SIGMA_PX
from rs_localizer.geometry import rotation_angle_deg

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def tag_corners(side):
    s = side / 2
    return np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])


def _frontal_small_tag(rng):
    cam = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    X = tag_corners(0.1)
    a = np.radians(20)  # (20 degrees off the tag's axis: its mirror pose is ~40 degrees away)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    R = R @ np.diag([1.0, -1.0, -1.0])
    C = np.array([0.02, -0.01, 4.0])
    uv = cam.project_rs(X, R, C) + rng.normal(0, 0.5, (4, 2))
    return cam, X, R, C, uv


def test_a_small_distant_frontal_tag_is_refused_without_a_prediction_and_resolved_with_one():
    rng = np.random.default_rng(0)
    refused = resolved = 0
    for _ in range(10):
        cam, X, R, C, uv = _frontal_small_tag(rng)
        e = estimate_rs_pose(uv, X, cam)
        if not e.success:
            assert e.failure == "ambiguous_tag"
            refused += 1
        p = estimate_rs_pose(
            uv, X, cam, initial_model=InitialModel((R, C, np.zeros(3), np.zeros(3)))
        )
        if not p.success:  # (the prediction nearer neither pose by the ratio: refused too)
            assert p.failure == "ambiguous_tag"
            continue
        assert p.single_tag and p.initial_used
        # (the one of IPPE's two poses on the true pose's side, not its mirror image)
        x = cam.undistort(uv)
        n, rvecs, _, _ = cv2.solvePnPGeneric(X, x, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
        both = [cv2.Rodrigues(rv)[0] for rv in rvecs[:n]]
        mirror = max(both, key=lambda Q: rotation_angle_deg(Q, R))
        assert rotation_angle_deg(mirror, R) > 25.0
        assert rotation_angle_deg(p.model.R, R) < 0.5 * rotation_angle_deg(mirror, R)
        if e.success:  # (the image told the two apart: the pose the prediction takes)
            assert rotation_angle_deg(e.model.R, p.model.R) < 1e-6
        assert p.motion_model == "global_shutter"  # (the prediction holds no motion)
        resolved += 1
    assert refused >= 8 and resolved >= 9
    assert "ambiguous_tag" in FAILURE_REASONS


def test_the_estimate_of_one_tag_is_complete_and_counted_as_such():
    rng = np.random.default_rng(3)
    cam = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    X = tag_corners(0.2)
    a = np.radians(35)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]) @ np.diag(
        [1.0, -1.0, -1.0]
    )
    C = np.array([0.0, 0.0, 0.8])
    w, t = np.array([0.01, -0.02, 0.005]), np.array([0.002, 0.0, -0.001])
    uv = cam.project_rs(X, R, C, w, t) + rng.normal(0, 0.5, (4, 2))
    e = estimate_rs_pose(uv, X, cam, initial_model=InitialModel((R, C, w, t)))
    assert e.success and e.single_tag and e.num_inliers == 4
    assert e.motion_model == "predicted_motion"
    # (the camera's own velocities held at the prediction's, whatever the fitted position)
    om, v, _, _ = physical_velocities(R, C, w, t, cam.seconds_per_unit_r)
    np.testing.assert_allclose(e.pose.angular_velocity, om, rtol=1e-9)
    np.testing.assert_allclose(e.pose.linear_velocity, v, rtol=1e-9, atol=1e-12)
    assert e.rmse_px <= 2.0 and e.pose_covariance is not None
    assert np.all(np.linalg.eigvalsh(e.pose_covariance) > 0)
    assert e.twist_covariance is None  # (the velocities are the prediction's, not measured)
    assert np.all(np.linalg.eigvalsh(e.covariance[6:, 6:]) > 0)  # (the motion prior's)
    # (its rotation standard deviation matches its error in size, no more than 5x off)
    sd = np.sqrt(np.trace(e.pose_covariance[3:, 3:]))
    err = np.radians(rotation_angle_deg(e.model.R, R))
    assert err < 5 * sd
    # non-coplanar points as few stay refused
    X3 = np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0.1, 0.1, 0.3]])
    bad = estimate_rs_pose(cam.project_rs(X3, R, C), X3, cam)
    assert not bad.success and bad.failure == "too_few_points"
    # a corner 4 px off (the corners fit a square to ~1.2 px, as a real tag's may): posed at
    # the default threshold (2 px); 10 px off: refused
    exact = cam.project_rs(X, R, C, w, t)
    for off, ok in ((4.0, True), (10.0, False)):
        moved = exact + np.array([[off, 0.0], [0, 0], [0, 0], [0, 0]])
        e = estimate_rs_pose(moved, X, cam, initial_model=InitialModel((R, C, w, t)))
        assert e.success == ok, (off, e.failure)
        if ok:
            assert 1.0 < e.rmse_px < 1.5 and e.num_inliers == 4
        else:
            assert e.failure == "too_few_inliers"


def test_a_gyro_gives_one_tag_its_angular_velocity():
    from rs_localizer.estimation.gyro import GyroMeasurement

    rng = np.random.default_rng(4)
    cam = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    s = cam.seconds_per_unit_r
    X = tag_corners(0.2)
    a = np.radians(30)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    R = R @ np.diag([1.0, -1.0, -1.0])
    C = np.array([0.0, 0.0, 0.7])
    omega = np.array([0.5, -2.0, 0.3])  # rad/s, camera frame
    uv = cam.project_rs(X, R, C, -s * omega, s * np.cross(C, omega))
    uv = uv + rng.normal(0, 0.3, (4, 2))
    g = GyroMeasurement(angular_velocity=omega, covariance=np.eye(3) * 1e-4)
    e = estimate_rs_pose(uv, X, cam, gyro=g)
    assert e.success and e.single_tag and e.gyro_used and not e.gyro_rejected
    assert e.motion_model == "predicted_motion"
    np.testing.assert_allclose(e.pose.angular_velocity, omega, atol=1e-9)
    assert rotation_angle_deg(e.model.R, R) < 2.0


def test_a_video_of_one_tag_is_tracked():
    from rs_localizer.tracking.tracker import RSTracker

    rng = np.random.default_rng(6)
    cam = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    s = cam.seconds_per_unit_r
    X = tag_corners(0.2)
    omega = np.array([0.0, 0.6, 0.0])  # a slow pan, rad/s
    tracker = RSTracker()
    states, errors = [], []
    for k in range(12):
        a = np.radians(30 + 0.6 * np.degrees(k / 30))
        R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        R = R @ np.diag([1.0, -1.0, -1.0])
        C = np.array([0.0, 0.0, 0.8])
        uv = cam.project_rs(X, R, C, -s * omega, s * np.cross(C, omega))
        r = tracker.process(k * 33_333_333, uv + rng.normal(0, 0.3, (4, 2)), X, cam)
        assert r.estimate.success and r.estimate.single_tag, r.estimate.failure
        states.append(r.state)
        errors.append(rotation_angle_deg(r.estimate.model.R, R))
    assert states[0] == "cold" and states[-4:] == ["tracked"] * 4, states
    assert np.median(errors) < 2.0


def test_p3p_with_four_inliers_poses_one_tag_from_all_its_corners():
    # (P3P's minimal sample and the fourth corner to check it: a corner 4 px off, the corners
    # fitting a square to ~1.2 px, fails that check at 2 px; the four-corner fit does not)
    cam = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    X = tag_corners(0.2)
    a = np.radians(35)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    R = R @ np.diag([1.0, -1.0, -1.0])
    C = np.array([0.0, 0.0, 0.8])
    uv = cam.project_rs(X, R, C) + np.array([[4.0, 0.0], [0, 0], [0, 0], [0, 0]])
    opts = EstimateOptions(ransac=RansacOptions(min_inliers=4))
    e = estimate_rs_pose(uv, X, cam, "p3p", opts)
    assert e.success and e.single_tag and e.num_inliers == 4 and 1.0 < e.rmse_px < 1.5
    assert rotation_angle_deg(e.model.R, R) < 3.0


def test_two_tags_a_millimetre_off_one_plane_are_posed():
    """Two 0.16 m tags on a floor, one 1.5 mm higher and tilted 0.1 degree (as on a real
    floor: OpenCV's IPPE alone returns no pose for them), eight corners seen by a global-shutter
    camera: posed within a few hundredths of a degree and millimetres of the truth."""
    rng = np.random.default_rng(1)
    cam = CameraModel(K=K, width=640, height=480)
    a = np.radians(0.1)
    tilt = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    X = np.concatenate(
        [tag_corners(0.16), tag_corners(0.16) @ tilt.T + np.array([-0.5, 0.1, 0.0015])]
    )
    b = np.radians(30)
    R = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    R = R @ np.diag([1.0, -1.0, -1.0])
    C = -R @ np.array([-0.25, -0.6, 1.0])
    uv = cam.project(X @ R.T + C) + rng.normal(0, 0.3, (8, 2))
    e = estimate_rs_pose(uv, X, cam)
    assert e.success, e.failure
    assert e.single_tag
    assert rotation_angle_deg(e.model.R, R) < 0.3
    assert np.linalg.norm(e.model.R.T @ e.model.C - R.T @ C) < 0.01


def test_the_covariance_of_one_tag_is_its_fits_at_the_estimate():
    """The pose covariance of one tag (global shutter, no prediction) against an independent
    computation: ``sigma^2 (J^T J)^-1`` with ``J`` the central finite differences of the
    corners' normalized reprojection errors at the estimated pose over the camera's rotation
    (world axes) and position in the world (the estimate's ``covariance`` parameters),
    ``sigma^2`` the residuals' variance over 8 - 6 degrees of freedom, at least
    (MIN_CORNER_SIGMA_PX / f)^2."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(8)
    cam = CameraModel(K=K, width=640, height=480)
    X = tag_corners(0.2)
    a = np.radians(35)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    R = R @ np.diag([1.0, -1.0, -1.0])
    C = np.array([0.03, -0.02, 0.8])
    uv = cam.project(X @ R.T + C) + rng.normal(0, 1.0, (4, 2))
    e = estimate_rs_pose(uv, X, cam)
    assert e.success and e.single_tag
    x = (uv - K[:2, 2]) / K[0, 0]

    Rwc = e.model.R.T  # (camera -> world)
    c = -Rwc @ e.model.C  # (the camera's position in the world)

    def residuals(p):
        Rp = (Rotation.from_rotvec(p[:3]).as_matrix() @ Rwc).T
        P = (X - c - p[3:]) @ Rp.T
        return (P[:, :2] / P[:, 2:] - x).ravel()

    h = 1e-6
    J = np.stack([(residuals(h * d) - residuals(-h * d)) / (2 * h) for d in np.eye(6)], axis=1)
    res = residuals(np.zeros(6))
    sigma2 = max(res @ res / 2, (MIN_CORNER_SIGMA_PX / K[0, 0]) ** 2)
    np.testing.assert_allclose(e.covariance[:6, :6], sigma2 * np.linalg.inv(J.T @ J), rtol=1e-5)


def test_a_fisheye_tag_is_judged_in_pixels_of_the_measured_image():
    """A tag far off a fisheye's centre (equidistant lens, a RealSense T265's calibration):
    acceptance, the ambiguity decision, ``rmse_px`` and the covariance against an independent
    computation in pixels of the measured image: each IPPE pose refined by SciPy on the
    corners' reprojection errors through the lens (``CameraModel.project``), the image
    deciding when the other pose's squared errors exceed the better one's by
    ``AMBIGUITY_CHI2`` variances (``max(SSE / 2, MIN_CORNER_SIGMA_PX^2)``), the covariance
    ``sigma^2 (J^T J)^-1`` of those errors' finite differences at the estimate."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    cam = CameraModel(
        K=np.array([[283.943, 0, 421.079], [0, 284.986, 400.527], [0, 0, 1]]),
        D=[0.00132, 0.03049, -0.02875, 0.0034],
        width=848,
        height=800,
        distortion_model="equidistant",
    )
    X = tag_corners(0.3)
    rng = np.random.default_rng(11)
    outcomes = set()
    for _ in range(12):
        R = Rotation.from_rotvec(rng.normal(0, 0.25, 3)).as_matrix() @ np.diag([1.0, -1, -1])
        d = rng.uniform(1.0, 2.0)
        C = np.array([*rng.uniform(0.9, 1.2, 2) * d, d])  # (~50 degrees off the axis)
        uv = cam.project(X @ R.T + C) + rng.normal(0, 0.3, (4, 2))

        def residuals(p, R0, c0, uv=uv):  # (measured px; p: rotation (world axes), position)
            Rp = (Rotation.from_rotvec(p[:3]).as_matrix() @ R0.T).T
            return (cam.project((X - c0 - p[3:]) @ Rp.T) - uv).ravel()

        fits = []
        x = cam.undistort(uv)
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(X, x, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
        for rv, tv in zip(rvecs[:n], tvecs[:n], strict=True):
            R0 = cv2.Rodrigues(rv)[0]
            c0 = -R0.T @ tv.ravel()
            p = least_squares(residuals, np.zeros(6), args=(R0, c0), xtol=1e-14).x
            Rf = (Rotation.from_rotvec(p[:3]).as_matrix() @ R0.T).T
            res = residuals(p, R0, c0)
            fits.append((float(res @ res), Rf, Rf @ -(c0 + p[3:])))
        fits.sort(key=lambda f: f[0])
        sigma2 = max(fits[0][0] / 2, MIN_CORNER_SIGMA_PX**2)
        if rotation_angle_deg(fits[0][1], fits[-1][1]) < 0.05:
            fits = fits[:1]
        gap = fits[1][0] - fits[0][0] if len(fits) > 1 else np.inf
        e = estimate_rs_pose(uv, X, cam)
        if abs(gap / (AMBIGUITY_CHI2 * sigma2) - 1) < 0.1:
            continue  # (too near the boundary for an independent fit to call)
        if gap < AMBIGUITY_CHI2 * sigma2:
            assert not e.success and e.failure == "ambiguous_tag", (gap, sigma2, e.failure)
            outcomes.add("ambiguous")
            continue
        outcomes.add("posed")
        assert e.success and e.single_tag
        assert rotation_angle_deg(e.model.R, fits[0][1]) < 0.05
        np.testing.assert_allclose(e.rmse_px, np.sqrt(fits[0][0] / 4), rtol=0.02)
        Rwc, c = e.model.R.T, -e.model.R.T @ e.model.C
        h = 1e-6
        J = np.stack(
            [
                (residuals(h * q, Rwc.T, c) - residuals(-h * q, Rwc.T, c)) / (2 * h)
                for q in np.eye(6)
            ],
            axis=1,
        )
        res = residuals(np.zeros(6), Rwc.T, c)
        s2 = max(res @ res / 2, MIN_CORNER_SIGMA_PX**2)
        ref = s2 * np.linalg.inv(J.T @ J)  # (the whitening is the lens's first order: ~1 %)
        np.testing.assert_allclose(e.covariance[:6, :6], ref, rtol=0.05, atol=0.01 * ref.max())
    assert outcomes == {"ambiguous", "posed"}


def _two_walls(side=0.2):
    """Two square tags' corners (8, 3) m: one on the floor, one on a wall 90 degrees to it."""
    quarter = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    return np.concatenate([tag_corners(side), tag_corners(side) @ quarter.T + [0.0, 0.3, 0.15]])


def _view(deg, C):
    a = np.radians(deg)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return R @ np.diag([1.0, -1.0, -1.0]), np.asarray(C, dtype=float)


def test_two_tags_on_two_planes_are_posed_as_opencv_refines_them():
    """Two tags on two planes (8 corners: fewer than ``min_inliers``), a global-shutter camera
    without distortion: the pose against an independent computation, OpenCV's SQPnP refined
    by ``cv2.solvePnPRefineLM`` (the same least squares of the corners' reprojection errors),
    and within a degree and a centimetre of the truth."""
    rng = np.random.default_rng(21)
    cam = CameraModel(K=K, width=640, height=480)
    X = _two_walls()
    for k in range(5):
        R, C = _view(30 + 5 * k, [0.05 * k, -0.02, 1.2])
        uv = cam.project(X @ R.T + C) + rng.normal(0, 0.5, (8, 2))
        e = estimate_rs_pose(uv, X, cam)
        assert e.success, e.failure
        assert e.few_points and not e.single_tag and not e.planar
        assert e.num_inliers == 8 and e.ransac_iterations == 0
        assert e.motion_model == "global_shutter" and e.twist_covariance is None
        assert np.all(np.linalg.eigvalsh(e.pose_covariance) > 0)
        x = (uv - K[:2, 2]) / K[0, 0]
        _, rv, tv = cv2.solvePnP(X, x, np.eye(3), None, flags=cv2.SOLVEPNP_SQPNP)
        rv, tv = cv2.solvePnPRefineLM(
            X, x, np.eye(3), None, rv, tv, (cv2.TERM_CRITERIA_EPS, 100, 1e-15)
        )
        Rcv = cv2.Rodrigues(rv)[0]
        assert rotation_angle_deg(e.model.R, Rcv) < 1e-5
        np.testing.assert_allclose(e.model.C, tv.ravel(), atol=1e-7)
        assert rotation_angle_deg(e.model.R, R) < 1.0
        assert np.linalg.norm(e.model.R.T @ e.model.C - R.T @ C) < 0.01


def test_a_few_points_hold_the_predicted_motion_and_refuse_a_wrong_match():
    """A rolling-shutter camera turning at 1 rad/s sees two tags on two planes: with the
    tracker's prediction its velocities are held and the pose is right; a corner 30 px off (a
    wrong match) fails the frame as ``too_few_inliers`` (none is rejected); five points on two
    planes stay ``too_few_points``."""
    from rs_localizer.estimation.single_tag import MIN_SPREAD_POINTS

    cam = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    s = cam.seconds_per_unit_r
    X = _two_walls()
    R, C = _view(35, [0.0, 0.0, 1.2])
    omega = np.array([0.2, 1.0, 0.0])
    w, t = -s * omega, s * np.cross(C, omega)
    uv = cam.project_rs(X, R, C, w, t) + np.random.default_rng(5).normal(0, 0.3, (8, 2))
    e = estimate_rs_pose(uv, X, cam, initial_model=InitialModel((R, C, w, t)))
    assert e.success and e.few_points and e.initial_used, e.failure
    assert e.motion_model == "predicted_motion"
    np.testing.assert_allclose(e.pose.angular_velocity, omega, rtol=1e-9)
    assert rotation_angle_deg(e.model.R, R) < 0.5
    # (without the prediction, held at zero: the rotation during the readout is in the pose)
    still = estimate_rs_pose(uv, X, cam)
    assert still.success and still.motion_model == "global_shutter"
    assert rotation_angle_deg(e.model.R, R) < rotation_angle_deg(still.model.R, R)
    wrong = uv.copy()  # (a wrong match)
    wrong[5] += [30.0, 0.0]
    bad = estimate_rs_pose(wrong, X, cam, initial_model=InitialModel((R, C, w, t)))
    assert not bad.success and bad.failure == "too_few_inliers"
    keep = [0, 1, 2, 4, 5, 6, 7][: MIN_SPREAD_POINTS - 1]  # (on both planes)
    few = estimate_rs_pose(uv[keep], X[keep], cam)
    assert not few.success and few.failure == "too_few_points"
    more = [0, 1, 2, 4, 5, 6, 7][:MIN_SPREAD_POINTS]
    assert estimate_rs_pose(
        uv[more], X[more], cam, initial_model=InitialModel((R, C, w, t))
    ).success


def test_the_fits_kernel_is_opencvs_rotation_and_the_refinement_of_each_start():
    """The compiled fits of a tag's IPPE starts (``_fit_starts``) against the separate steps
    they stand for: each start's rotation by ``cv2.Rodrigues``, refined by ``refine_rs_pose``
    (the pose alone, least squares, every point, the frame's mountings), its sum of squared
    errors by ``exact_errors``: the same numbers to the bit, on a fisheye (errors whitened
    into measured pixels) and a pinhole camera (plain errors); the fits ordered by that sum,
    the second dropped only when it is the first's rotation."""
    from scipy.spatial.transform import Rotation

    from rs_localizer.estimation.frame import prepare_frame
    from rs_localizer.estimation.refine import RefineSettings, exact_errors, refine_rs_pose
    from rs_localizer.estimation.single_tag import SAME_POSE_DEG, _fit_starts, _rodrigues, _starts

    rng = np.random.default_rng(5)
    scales = np.repeat([1e-6, 1.0, 3.0], 100)[:, None]  # (tiny, common and large angles)
    for r in [np.zeros(3), np.full(3, 1e-17), *rng.normal(0, 1, (300, 3)) * scales]:
        Q = np.empty((3, 3))
        _rodrigues(np.ascontiguousarray(r, dtype=float), Q)
        assert np.array_equal(Q, cv2.Rodrigues(r)[0])
    lens = {"D": [0.00132, 0.03049, -0.02875, 0.0034], "distortion_model": "equidistant"}
    fisheye = CameraModel(K=K, width=640, height=480, **lens)
    settings = RefineSettings(rolling_shutter=False, max_iterations=200, tol=1e-12)
    X, z, kinds = tag_corners(0.2), np.zeros(3), set()
    for cam in (fisheye, CameraModel(K=K, width=640, height=480)):
        for _ in range(8):
            R = Rotation.from_rotvec(rng.normal(0, 0.4, 3)).as_matrix() @ np.diag([1.0, -1, -1])
            C = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(0.8, 3.0)])
            uv = cam.project(X @ R.T + C) + rng.normal(0, 0.3, (4, 2))
            fr = prepare_frame(uv, X, cam, 1e6)
            fr.planar = True
            rv, tv = _starts(fr)
            k, tau = len(rv), fr.r - fr.r0
            Rk, Ck, Hk, sse = (
                np.empty((k, 3, 3)),
                np.empty((k, 3)),
                np.empty((k, 6, 6)),
                np.empty(k),
            )
            kept = _fit_starts(rv, tv, fr.X, fr.x, tau, fr.W, Rk, Ck, Hk, sse)
            mountings = fr.mountings()
            kinds.add(mountings is None)
            for j in range(k):
                start = (cv2.Rodrigues(rv[j])[0], tv[j], z, z)
                ref = refine_rs_pose(start, fr.X, fr.x, tau, 1e6, settings, mountings=mountings)
                assert np.array_equal(ref.R, Rk[j]) and np.array_equal(ref.C, Ck[j])
                assert np.array_equal(ref.data_information[:6, :6], Hk[j])
                e = exact_errors(ref.R, ref.C, z, z, fr.X, fr.x, tau, fr.W)
                assert float(e @ e) == sse[j]
            assert list(kept) == sorted(kept, key=lambda j: sse[j]) and 1 <= len(kept) <= k
            if len(kept) < k:
                assert rotation_angle_deg(Rk[0], Rk[1]) < SAME_POSE_DEG
    assert kinds == {True, False}


def test_a_mounted_views_estimate_is_the_bodys():
    """``estimate_rs_pose(..., view=)`` (a rig frame posed by one camera's few points) against
    the camera's own estimate of the same frame carried to the body by an independent
    computation: the body's model (the mounting and stamp offset applied to the camera's
    model), its covariance (the map's central differences times the camera's), the ROS pose
    covariance of it, the same inliers, per-view fields and record; the prediction given in
    the body's terms. One tag seen by a global and a rolling shutter, with and without a
    prediction (held velocities), an ambiguous tag, a wrong match, two tags on two planes."""
    from scipy.spatial.transform import Rotation

    from rs_localizer.estimation.result import output_covariance
    from rs_localizer.estimation.view import View
    from rs_localizer.frames import Mounting
    from rs_localizer.geometry import rotvec_to_matrix

    rng = np.random.default_rng(8)
    gs = CameraModel(K=K, width=640, height=480)
    rs = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    R, C = _view(35, [0.05, -0.02, 0.8])
    moving = InitialModel((R, C, np.array([1e-4, -2e-4, 3e-4]), np.array([2e-4, 1e-4, -1e-4])))
    Rm = rotvec_to_matrix(np.radians(40.0) * np.array([0.3, -1.0, 0.2]) / np.sqrt(1.13))
    mount, offset = Mounting(Rm, np.array([0.1, -0.05, 0.02])), 0.004
    cases = []
    for cam in (gs, rs):
        uv = cam.project_rs(tag_corners(0.2), R, C) + rng.normal(0, 0.3, (4, 2))
        cases += [(uv, tag_corners(0.2), cam, None), (uv, tag_corners(0.2), cam, moving)]
        wrong = uv.copy()
        wrong[0] += 30.0
        cases.append((wrong, tag_corners(0.2), cam, None))
        cam_f, Xf, Rf, Cf, uvf = _frontal_small_tag(rng)
        cases += [
            (uvf, Xf, cam_f, None),
            (uvf, Xf, cam_f, InitialModel((Rf, Cf, np.zeros(3), np.zeros(3)))),
        ]
        X2 = _two_walls()
        cases.append((cam.project_rs(X2, R, C) + rng.normal(0, 0.3, (8, 2)), X2, cam, None))
    outcomes = set()
    for uv, X, cam, im in cases:
        spr = cam.seconds_per_unit_r
        own = estimate_rs_pose(uv, X, cam, initial_model=im)
        body_im = None
        if im is not None:  # (the prediction of the body: the camera's, carried by hand)
            Rk, Ck, wk, tk = im.model
            w = Rm.T @ wk / spr if spr > 0 else np.zeros(3)
            t = Rm.T @ tk / spr if spr > 0 else np.zeros(3)
            R1 = rotvec_to_matrix(-offset * w) @ Rm.T @ Rk
            body_im = InitialModel((R1, Rm.T @ (Ck - mount.c) - offset * t, w, t))
        view = View(uv, X, cam, mount, offset)
        est = estimate_rs_pose(uv, X, cam, initial_model=body_im, view=view)
        for wrong in (replace(view, camera=gs if cam is rs else rs), replace(view, mounting=None)):
            with pytest.raises(ValueError, match="a view must have"):
                estimate_rs_pose(uv, X, cam, view=wrong)
        assert (est.success, est.failure) == (own.success, own.failure)
        outcomes.add(est.failure or est.motion_model)
        np.testing.assert_array_equal(est.inliers, own.inliers)
        assert est.inliers_per_view[0] is est.inliers or np.array_equal(
            est.inliers_per_view[0], est.inliers
        )
        assert est.num_inliers_per_view == own.num_inliers_per_view == (own.num_inliers,)
        assert est.num_valid_per_view == own.num_valid_per_view == (own.num_valid,)
        if not est.success:
            assert np.array_equal(est.model.R, np.eye(3))
            continue
        for name in ("few_points", "single_tag", "motion_model", "initial_used", "solver"):
            assert getattr(est, name) == getattr(own, name), name
        for name in ("rmse_px", "planarity", "condition_number", "num_behind"):
            assert np.isclose(getattr(est, name), getattr(own, name), rtol=1e-9), name
        # (the camera's model carried to the body: x_cam = Rm x_body + c at offset + tau)
        Rk, Ck, wk, tk = own.model
        w = Rm.T @ wk / spr if spr > 0 else np.zeros(3)
        t = Rm.T @ tk / spr if spr > 0 else np.zeros(3)
        R1 = rotvec_to_matrix(-offset * w) @ Rm.T @ Rk
        want = (R1, Rm.T @ (Ck - mount.c) - offset * t, w, t)
        for got, exp in zip(est.model, want, strict=True):
            np.testing.assert_allclose(got, exp, rtol=1e-7, atol=1e-10)
        if own.model_covariance is None:
            assert est.model_covariance is None and est.pose_covariance is None
            continue
        J = np.zeros((12, 12))  # (central differences of the map, rotation on the left)
        for k in range(12):
            d = np.zeros(12)
            d[k] = 1e-7
            ends = []
            for sgn in (1.0, -1.0):
                Rp = rotvec_to_matrix(sgn * d[:3]) @ Rk
                Cp, wp, tp = Ck + sgn * d[3:6], wk + sgn * d[6:9], tk + sgn * d[9:12]
                wb = Rm.T @ wp / spr if spr > 0 else np.zeros(3)
                tb = Rm.T @ tp / spr if spr > 0 else np.zeros(3)
                Rb = rotvec_to_matrix(-offset * wb) @ Rm.T @ Rp
                dv = Rotation.from_matrix(Rb @ R1.T).as_rotvec()
                ends.append(np.concatenate([dv, Rm.T @ (Cp - mount.c) - offset * tb, wb, tb]))
            J[:, k] = (ends[0] - ends[1]) / 2e-7
        cov = J @ own.model_covariance @ J.T
        scale = np.abs(cov).max()
        np.testing.assert_allclose(est.model_covariance, cov, rtol=0, atol=1e-5 * scale)
        pose_cov = output_covariance(cov, *want[:3], 1.0)[1]
        np.testing.assert_allclose(
            est.pose_covariance, pose_cov, rtol=0, atol=1e-5 * np.abs(pose_cov).max()
        )
        assert est.twist_covariance is None and own.twist_covariance is None
    assert {"global_shutter", "predicted_motion", "ambiguous_tag"} <= outcomes
    assert "too_few_inliers" in outcomes
