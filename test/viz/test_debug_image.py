"""What the localizer shows (ROS-free): the RS forward projection of the camera model, the debug
image read back pixel by pixel, and the 3D geometry of the markers.

The debug-image frames are built from a known pose and velocity (no estimator in the loop), so
the expected pixel of every drawn element is computed independently: the RS projection with
SciPy's ``expm`` / the Newton solver of :func:`rs_localizer.geometry.rs_project_exact`, the
global-shutter one with ``cv2.projectPoints``.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from helpers.debug_frames import K, known_frame, known_pose, world_points
from scipy.linalg import expm

from rs_localizer.camera import CameraModel
from rs_localizer.estimation.estimate import RSPoseEstimate
from rs_localizer.geometry import rs_project_exact, skew
from rs_localizer.viz import (
    COLORS,
    DebugImageOptions,
    draw_debug_image,
    frustum_corners,
    frustum_segments,
    velocity_arrows,
)
from rs_localizer.viz.debug_image import CANVAS_GREY


@pytest.mark.parametrize("readout", ["top_to_bottom", "bottom_to_top", "left_to_right"])
def test_project_rs_solves_the_rs_constraint(readout):
    cam = CameraModel(K, [], 640, 480, line_delay=60e-6, readout=readout)
    R, C = known_pose()
    rng = np.random.default_rng(3)
    X = world_points(R, C, rng.uniform([-0.55, -0.4], [0.55, 0.4], (40, 2)), rng.uniform(2, 8, 40))
    w, t = np.array([0.05, -0.12, 0.04]), np.array([0.2, 0.05, -0.1])  # per unit r
    uv = cam.project_rs(X, R, C, w, t)
    # every point lies where the exact model at its own capture line puts it (SciPy expm)
    tau = cam.rs_coordinate(uv) - cam.r0
    p = np.array([expm(tk * skew(w)) @ R @ x + C + tk * t for x, tk in zip(X, tau, strict=False)])
    np.testing.assert_allclose(p[:, :2] / p[:, 2:] @ K[:2, :2].T + K[:2, 2], uv, atol=1e-6)
    # and it is the root the Newton solver of geometry.rs_project_exact finds
    x, _ = rs_project_exact(X, R, C, w, t, r0=cam.r0, readout=cam.readout_vector)
    np.testing.assert_allclose(x @ K[:2, :2].T + K[:2, 2], uv, atol=1e-6)


def test_project_rs_global_shutter_with_distortion_is_opencv():
    D = np.array([0.05, -0.1, 3e-4, -2e-4, 0.03])
    cam = CameraModel(K, D, 640, 480, line_delay=60e-6)
    R, C = known_pose()
    rng = np.random.default_rng(4)
    X = world_points(R, C, rng.uniform(-0.5, 0.5, (30, 2)), rng.uniform(1, 5, 30))
    ref, _ = cv2.projectPoints(X, cv2.Rodrigues(R)[0], C, K, D)
    np.testing.assert_allclose(cam.project_rs(X, R, C), ref.reshape(-1, 2), atol=1e-6)
    # behind the camera: nan
    behind = world_points(R, C, np.zeros((1, 2)), [-2.0])
    assert np.isnan(cam.project_rs(behind, R, C)).all()


# ------------------------------------------------------------------------------ debug image
def _px(img, p):
    return tuple(int(c) for c in img[int(round(p[1])), int(round(p[0]))])


def _near(img, p, colour, tol=60, r=1):
    """A pixel within ``r`` of ``p`` has ``colour`` (BGR, each channel within ``tol``)."""
    u, v = int(round(p[0])), int(round(p[1]))
    patch = img[max(v - r, 0) : v + r + 1, max(u - r, 0) : u + r + 1].reshape(-1, 3).astype(int)
    return bool((np.abs(patch - np.array(colour)) <= tol).all(axis=1).any())


def test_debug_image_points_residuals_and_text():
    cam = CameraModel(K, [], 640, 480, line_delay=60e-6)
    uv, X, est, _truth = known_frame(cam)
    img = draw_debug_image(cam, uv, X, est, options=DebugImageOptions(cube=False))
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    for p, good in zip(uv, est.inliers, strict=False):
        assert _px(img, p) == (COLORS["inlier"] if good else COLORS["outlier"]), p
    # outliers: residual = prediction - measured = (-25, 0) px, x10 = 250 px, capped at 60 px
    for p in uv[~est.inliers]:
        for d in (15, 30, 45, 55):
            assert _px(img, p - [d, 0]) == COLORS["residual"], (p, d)
        assert _px(img, p - [70, 0]) == (CANVAS_GREY,) * 3
    # inliers: residuals of ~0.3 px drawn 10x: within 3 px of the point, never 20 px away
    for p in uv[est.inliers][:5]:
        for q in (p + [20, 0], p - [20, 0], p + [0, 20]):
            assert _px(img, q) == (CANVAS_GREY,) * 3
    # the text band: black with white text over the first rows, canvas below it
    band = img[:20]
    assert (band.reshape(-1, 3) == 0).all(axis=1).mean() > 0.5
    assert (band.reshape(-1, 3) > 200).all(axis=1).sum() > 50
    # the line shows the estimate's numbers: redrawing the expected text over the image
    # changes no pixel (a different string would)
    from rs_localizer.viz.debug_image import _text_lines

    w, v = np.linalg.norm(est.pose.angular_velocity), np.linalg.norm(est.pose.linear_velocity)
    assert 1.0 < w < 5.0 and 0.05 < v < 5.0
    expected = [
        f"r6p_1lin  inliers 31/35  RMSE 0.42 px  |omega| {w:.3f} rad/s  |v| {v:.3f} m/s",
        "green inlier  red outlier  yellow residual x10  cyan RS cube  magenta global-shutter cube",
    ]
    again = img.copy()
    _text_lines(again, expected, COLORS["text"])
    np.testing.assert_array_equal(again, img)
    wrong = img.copy()
    _text_lines(wrong, [expected[0].replace("31/35", "30/35"), expected[1]], COLORS["text"])
    assert (wrong != img).any()


def test_debug_image_background_from_the_input_image():
    cam = CameraModel(K, [], 640, 480, line_delay=60e-6)
    uv, X, est, _ = known_frame(cam)
    far = (300, 455)  # away from every point, residual and the text
    mono = np.full((480, 640), 200, np.uint8)
    img = draw_debug_image(cam, uv, X, est, mono, "mono8", DebugImageOptions(cube=False))
    assert _px(img, far) == (140, 140, 140)  # 0.7 x 200
    rgb = np.zeros((480, 640, 3), np.uint8)
    rgb[..., 0] = 200  # red in rgb8
    img = draw_debug_image(cam, uv, X, est, rgb, "rgb8", DebugImageOptions(cube=False))
    assert _px(img, far) == (0, 0, 140)  # BGR
    img = draw_debug_image(
        cam, uv, X, est, rgb[..., ::-1].copy(), "bgr8", DebugImageOptions(cube=False)
    )
    assert _px(img, far) == (0, 0, 140)
    for p, good in zip(uv, est.inliers, strict=False):
        assert _px(img, p) == (COLORS["inlier"] if good else COLORS["outlier"])


def test_debug_image_cube_rs_next_to_global_shutter():
    """The cube's vertices where the RS model images them (cyan) and where a global-shutter
    projection of the same pose puts them (magenta), several px apart at the top and bottom."""
    cam = CameraModel(K, [], 640, 480, line_delay=60e-6)
    w = np.array([0.0, 0.1, 0.0])  # ~3.2 rad/s pan (per unit r: 31 ms)
    uv, X, est, _ = known_frame(cam, w=w, t=(0, 0, 0))
    center = est.pose.position + 4.0 * est.pose.orientation[:, 2]
    side = 1.6
    img = draw_debug_image(
        cam,
        uv[:0],
        X[:0],
        est,
        options=DebugImageOptions(cube_center=tuple(center), cube_side=side, residual_scale=0),
    )
    from rs_localizer.viz.debug_image import cube_edge_points

    P = cube_edge_points(center, side, 60).reshape(-1, 3)  # dense points along the 12 edges
    x, _ = rs_project_exact(
        P, est.model.R, est.model.C, est.model.w, est.model.t, r0=cam.r0, readout=cam.readout_vector
    )
    rs = x @ K[:2, :2].T + K[:2, 2]
    gs, _ = cv2.projectPoints(P, cv2.Rodrigues(est.model.R)[0], est.model.C, K, None)
    gs = gs.reshape(-1, 2)
    for p in rs:
        assert _near(img, p, COLORS["cube_rs"]), p
    # global-shutter edge points more than 4 px from every RS edge point are drawn magenta
    apart = np.min(np.linalg.norm(gs[:, None] - rs[None], axis=2), axis=1)
    off = gs[apart > 4]
    assert len(off) > 0.2 * len(gs), apart.max()  # the motion moves much of the cube
    assert np.mean([_near(img, p, COLORS["cube_gs"]) for p in off]) > 0.95
    # no motion: the two coincide, the RS cube (drawn last, thicker) covers the GS one
    uv, X, est0, _ = known_frame(cam, w=(0, 0, 0), t=(0, 0, 0))
    img0 = draw_debug_image(
        cam,
        uv[:0],
        X[:0],
        est0,
        options=DebugImageOptions(cube_center=tuple(center), cube_side=side, residual_scale=0),
    )
    cyan = (np.abs(img0.astype(int) - COLORS["cube_rs"]) <= 60).all(axis=2).sum()
    magenta = (np.abs(img0.astype(int) - COLORS["cube_gs"]) <= 60).all(axis=2).sum()
    assert cyan > 500 and magenta < 0.05 * cyan, (cyan, magenta)


def test_debug_image_default_cube_is_in_view_and_failures_are_grey():
    cam = CameraModel(K, [0.05, -0.1, 0, 0, 0.03], 640, 480, line_delay=60e-6)
    uv, X, est, _ = known_frame(cam)
    img = draw_debug_image(cam, uv, X, est)
    cyan = (np.abs(img.astype(int) - COLORS["cube_rs"]) <= 60).all(axis=2)
    assert cyan.sum() > 500
    vs, us = np.nonzero(cyan)  # around the image centre (on the optical axis)
    assert abs(np.median(us) - 320) < 100 and abs(np.median(vs) - 240) < 100
    # a failed estimate: the points in grey, no inlier/outlier colours, the reason in the text
    failed = RSPoseEstimate(success=False, failure="too_few_inliers", solver="p3p")
    for e in (failed, None):
        img = draw_debug_image(cam, uv, X, e)
        assert not (img == COLORS["inlier"]).all(axis=2).any()
        assert not (img == COLORS["outlier"]).all(axis=2).any()
        for p in uv:
            assert _px(img, p) == COLORS["unclassified"]
    with pytest.raises(ValueError):
        draw_debug_image(cam, uv, X[:3], est)
    with pytest.raises(ValueError):
        draw_debug_image(cam, uv, X, est, np.zeros((480, 640, 2), np.uint8))


# ------------------------------------------------------------------------------ 3D markers
def test_frustum_corners_against_the_pose():
    R, C = known_pose()
    orientation, position = R.T, -R.T @ C
    cam = CameraModel(K, [], 640, 480)
    k = frustum_corners(cam, orientation, position, 0.5)
    px = np.array([[-0.5, -0.5], [639.5, -0.5], [639.5, 479.5], [-0.5, 479.5]])
    rays = np.c_[px, np.ones(4)] @ np.linalg.inv(K).T * 0.5  # K^-1 [u, v, 1], depth 0.5
    np.testing.assert_allclose(k, rays @ orientation.T + position, atol=1e-12)
    # with distortion: the corners project back onto the image corners (OpenCV)
    D = np.array([-0.2, 0.05, 0.001, -0.002, 0.01])
    cam = CameraModel(K, D, 640, 480)
    k = frustum_corners(cam, orientation, position, 2.0)
    back, _ = cv2.projectPoints(k, cv2.Rodrigues(R)[0], C, K, D)
    np.testing.assert_allclose(back.reshape(-1, 2), px, atol=1e-4)
    np.testing.assert_allclose((k - position) @ orientation[:, 2], 2.0, atol=1e-12)
    s = frustum_segments(cam, orientation, position, 2.0)
    assert s.shape == (16, 3)
    np.testing.assert_allclose(s[0:8:2], np.tile(position, (4, 1)))
    np.testing.assert_allclose(s[1:8:2], k)
    np.testing.assert_allclose(s[8::2], k)
    np.testing.assert_allclose(s[9::2], np.roll(k, -1, axis=0))
    with pytest.raises(ValueError):
        frustum_corners(cam, orientation, position, 0.0)


def test_velocity_arrows_in_the_map():
    cam = CameraModel(K, [], 640, 480, line_delay=60e-6)
    _, _, est, _ = known_frame(cam)
    a = velocity_arrows(est.pose, scale=2.0)
    s, e = a["angular_velocity"]
    np.testing.assert_allclose(s, est.pose.position)
    np.testing.assert_allclose(
        e - s, 2.0 * est.pose.orientation @ est.pose.angular_velocity, atol=1e-12
    )
    s, e = a["linear_velocity"]
    np.testing.assert_allclose(
        e - s, 2.0 * est.pose.orientation @ est.pose.linear_velocity, atol=1e-12
    )
