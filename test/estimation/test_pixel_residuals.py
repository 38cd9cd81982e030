"""Residuals in pixels of the measured (distorted) image: the camera's pixel Jacobian, the
inlier test by true pixel error, the final residuals in px, and the unchanged path of a
camera without distortion."""

from __future__ import annotations

import numpy as np
import pytest

from rs_localizer.camera import CameraModel
from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.frame import SCORE_AT_MEASURED_TIME, prepare_frame
from rs_localizer.estimation.refine import Mountings, RefineSettings, refine_rs_pose
from rs_localizer.estimation.scoring import msac_evaluate
from rs_localizer.estimation.view import StackedViews, View
from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotvec_to_matrix

K = np.array([[400.0, 0.0, 640.0], [0.0, 402.0, 512.0], [0.0, 0.0, 1.0]])
CAMERAS = {
    "plumb_bob": CameraModel(K, [-0.3, 0.1, 0.001, -0.002, -0.02], 1280, 1024),
    "rational_polynomial": CameraModel(
        K,
        [0.2, -0.1, 0.001, 0.002, 0.01, 0.05, 0.01, 0.002],
        1280,
        1024,
        distortion_model="rational_polynomial",
    ),
    "equidistant": CameraModel(
        K, [-0.02, -0.003, 0.007, -0.003], 1280, 1024, distortion_model="equidistant"
    ),
    "none": CameraModel(np.array([[400.0, 0.7, 640.0], [0, 410.0, 512.0], [0, 0, 1]])),
}
#: a strong fisheye: 1280 x 1024, ~75 degrees off-axis at the image corners
FISHEYE = CameraModel(
    np.array([[300.0, 0.0, 640.0], [0.0, 300.0, 512.0], [0.0, 0.0, 1.0]]),
    [-0.05, 0.01, -0.002, 0.0005],
    1280,
    1024,
    distortion_model="equidistant",
)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_pixel_jacobian_matches_finite_differences(name):
    cam = CAMERAS[name]
    x = np.random.default_rng(1).uniform(-1.0, 1.0, (200, 2))
    x[0] = 0.0  # (the optical axis: the equidistant model's limit r -> 0)
    A = cam.pixel_jacobian(x)
    h = 1e-6
    num = np.stack(
        [(cam.distort(x + e) - cam.distort(x - e)) / (2 * h) for e in np.eye(2) * h], axis=2
    )
    np.testing.assert_allclose(A, num, atol=1e-6 * np.abs(num).max())


def _fisheye_scene(n, noise_px, seed):
    """A global-shutter fisheye view of n points up to ~70 degrees off-axis: the true pose,
    measured pixels (true projection + ``noise_px`` (n, 2)), world points."""
    rng = np.random.default_rng(seed)
    R = rotvec_to_matrix(np.array([0.1, -0.2, 0.05]))
    C = np.array([0.1, -0.05, 0.3])
    ang = rng.uniform(0.0, np.deg2rad(70.0), n)
    az = rng.uniform(-np.pi, np.pi, n)
    depth = rng.uniform(2.0, 6.0, n)
    Pc = np.stack([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)], 1)
    Pc *= depth[:, None]
    X = (Pc - C) @ R  # world points: R X + C = Pc
    uv_true = FISHEYE.project(Pc)
    return R, C, uv_true + noise_px, X


def test_inliers_are_the_points_within_the_threshold_in_the_measured_image():
    n, t = 400, 2.0
    rng = np.random.default_rng(3)
    err = rng.uniform(0.0, 2.0 * t, n)  # true distorted-pixel error of each point
    phi = rng.uniform(-np.pi, np.pi, n)
    noise = err[:, None] * np.stack([np.cos(phi), np.sin(phi)], 1)
    R, C, uv, X = _fisheye_scene(n, noise, 4)
    fr = prepare_frame(uv, X, FISHEYE, np.inf)
    assert fr.W.shape == (n, 4)
    true_err = err[fr.rows]
    z3 = np.zeros(3)
    th2 = (t / fr.f) ** 2
    _, inl, _ = msac_evaluate(fr.x, fr.X, fr.r0e, fr.d, R, C, z3, z3, th2, True, fr.W)
    # first order: disagreements only within 2 % of the threshold
    off = inl != (true_err < t)
    assert np.all(np.abs(true_err[off] - t) < 0.02 * t), true_err[off]
    # the undistorted plane times the focal length classifies by a stretched error
    _, inl0, _ = msac_evaluate(fr.x, fr.X, fr.r0e, fr.d, R, C, z3, z3, th2, True)
    assert np.count_nonzero(inl0 != (true_err < t)) > 10 * max(np.count_nonzero(off), 1)


def test_final_residuals_are_the_measured_image_pixels():
    """The estimate's RMS residual (px) is the pixel noise of the measured image, and its
    pose is no worse than the truth's own fit predicts (Gaussian noise, no outliers)."""
    n, sigma = 300, 0.5
    noise = np.random.default_rng(5).normal(0.0, sigma, (n, 2))
    _, C, uv, X = _fisheye_scene(n, noise, 6)
    est = estimate_rs_pose(uv, X, FISHEYE, solver="p3p")
    assert est.success
    # (RMS of a 2D error: sigma * sqrt(2), less the fitted pose's 6 of 2n dof)
    expect = sigma * np.sqrt(2.0 * (2 * n - 6) / (2 * n))
    assert est.rmse_px == pytest.approx(expect, rel=0.1)
    assert np.linalg.norm(est.model.C - C) < 0.01


def test_camera_without_distortion_keeps_the_plain_errors():
    cam = CameraModel(np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]))
    rng = np.random.default_rng(7)
    X = rng.uniform(-1, 1, (50, 3)) + [0, 0, 4]
    uv = cam.project(X) + rng.normal(0, 0.5, (50, 2))
    fr = prepare_frame(uv, X, cam, np.inf)
    assert fr.W.shape == (0, 4) and fr.mountings() is None
    # the whitened path with identity whitening gives the plain path's errors and fit
    eye = np.tile([1.0, 0.0, 0.0, 1.0], (50, 1))
    z3, R, C = np.zeros(3), np.eye(3), np.zeros(3)
    th2 = (2.0 / fr.f) ** 2
    a = msac_evaluate(fr.x, fr.X, fr.r0e, fr.d, R, C, z3, z3, th2, SCORE_AT_MEASURED_TIME)
    b = msac_evaluate(fr.x, fr.X, fr.r0e, fr.d, R, C, z3, z3, th2, SCORE_AT_MEASURED_TIME, eye)
    assert a[0] == pytest.approx(b[0], rel=1e-12) and np.array_equal(a[1], b[1])
    tau = fr.r - fr.r0
    plain = refine_rs_pose((R, C, z3, z3), fr.X, fr.x, tau, 0.01, RefineSettings())
    m = Mountings(np.zeros(50, dtype=np.int64), np.eye(3)[None], np.zeros((1, 3)), eye)
    m = m._replace(scale=eye.reshape(50, 2, 2))
    white = refine_rs_pose((R, C, z3, z3), fr.X, fr.x, tau, 0.01, RefineSettings(), mountings=m)
    np.testing.assert_allclose(white.C, plain.C, atol=1e-9)
    np.testing.assert_allclose(white.covariance, plain.covariance, atol=1e-12)


def test_map_weighted_fit_keeps_the_measured_image_errors():
    """With the 3D points' precision stated (all but exact: weights ~1), the map-weighted
    final fit minimizes the same errors as the unweighted one: its RMS residual is the
    measured image's pixel noise and its pose the unweighted estimate's."""
    n, sigma = 300, 0.5
    noise = np.random.default_rng(5).normal(0.0, sigma, (n, 2))
    _, _, uv, X = _fisheye_scene(n, noise, 6)
    plain = estimate_rs_pose(uv, X, FISHEYE, solver="p3p")
    est = estimate_rs_pose(uv, X, FISHEYE, solver="p3p", point_sigma=np.full(n, 1e-9))
    assert plain.success and est.success
    expect = sigma * np.sqrt(2.0 * (2 * n - 6) / (2 * n))
    assert est.rmse_px == pytest.approx(expect, rel=0.1)
    assert est.rmse_px == pytest.approx(plain.rmse_px, rel=0.01)
    assert np.linalg.norm(est.model.C - plain.model.C) < 1e-4


def test_rig_errors_are_measured_image_pixels():
    """The rig's scoring errors (a fisheye camera of a rig, points up to 75 deg off-axis, the
    measured pixels moved by known errors of 0-3 px) are those pixel errors to first order."""
    n = 200
    rng = np.random.default_rng(8)
    err = rng.uniform(0.0, 3.0, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    noise = err[:, None] * np.stack([np.cos(phi), np.sin(phi)], 1)
    R, C, uv, X = _fisheye_scene(n, noise, 9)
    view = View(uv=uv, X=X, camera=FISHEYE)
    pool = StackedViews([view])
    e = pool.errors((R, C, np.zeros(3), np.zeros(3)))
    # first order: within a few % at 3 px (the focal length alone: up to ~2x off here)
    np.testing.assert_allclose(e, err[pool.row], rtol=0.05, atol=1e-3)


def test_rig_implementations_agree_on_a_fisheye_rig():
    """Two fisheye cameras on a rig (the second turned 90 deg and 15 cm off), 150 points each
    up to 70 deg off-axis, 0.5 px noise, 10 % outliers: the compiled and the NumPy
    implementation (whose least squares and covariance take the same 2x2 pixel Jacobians)
    pose the rig within 0.05 deg and 5 mm of the truth and within 0.002 deg and 0.2 mm of each
    other, their rotation sigmas within 10 %, and each inlier's RMS error is the noise's."""
    from rs_localizer.estimation.rig import estimate_rig_pose

    n, sigma = 150, 0.5
    rng = np.random.default_rng(12)
    noise = rng.normal(0.0, sigma, (n, 2))
    out = rng.random(n) < 0.1
    noise[out] += rng.uniform(20.0, 60.0, (out.sum(), 2)) * rng.choice([-1, 1], (out.sum(), 2))
    R, C, uv0, X0 = _fisheye_scene(n, noise, 13)
    Rm = rotvec_to_matrix(np.array([0.0, np.pi / 2, 0.0]))
    cm = np.array([0.15, 0.0, 0.02])
    _, _, uv1, Xs = _fisheye_scene(n, rng.normal(0.0, sigma, (n, 2)), 14)
    Pc1 = R @ Xs.T + C[:, None]  # (3, n) the points in camera 1's frame
    X1 = ((Rm.T @ (Pc1 - cm[:, None])).T - C) @ R  # world points: Rm (R X1 + C) + cm = Pc1
    views = [
        View(uv=uv0, X=X0, camera=FISHEYE),
        View(uv=uv1, X=X1, camera=FISHEYE, mounting=Mounting(Rm, cm)),
    ]
    c = estimate_rig_pose(views, implementation="compiled")
    p = estimate_rig_pose(views, implementation="numpy")
    assert c.success and p.success, (c.failure, p.failure)
    truth = -R.T @ C
    for est in (c, p):
        assert np.degrees(np.linalg.norm(_rotvec(est.model.R @ R.T))) < 0.05
        assert np.linalg.norm(est.pose.position - truth) < 5e-3
        assert est.rmse_px == pytest.approx(sigma * np.sqrt(2.0), rel=0.2)
    assert np.degrees(np.linalg.norm(_rotvec(c.model.R @ p.model.R.T))) < 0.002
    assert np.linalg.norm(c.pose.position - p.pose.position) < 2e-4
    sc = np.sqrt(np.diag(c.model_covariance)[:3])
    sp = np.sqrt(np.diag(p.model_covariance)[:3])
    np.testing.assert_allclose(sp, sc, rtol=0.1)


def _rotvec(R):
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()
