"""CameraModel: undistortion against OpenCV, RS timing and validation."""

import cv2
import numpy as np
import pytest

from rs_localizer.camera import CameraModel

K = np.array([[800.0, 0, 320.5], [0, 810.0, 240.5], [0, 0, 1]])


@pytest.mark.parametrize(
    "model,D",
    [
        ("plumb_bob", [-0.2, 0.05, 0.001, -0.002, 0.01]),
        ("rational_polynomial", [-0.2, 0.05, 0.001, -0.002, 0.01, 0.01, 0.0, 0.002]),
        ("equidistant", [0.05, -0.01, 0.002, 0.0]),
    ],
)
def test_distort_undistort_roundtrip_matches_opencv(model, D):
    cam = CameraModel(K, D, 640, 480, distortion_model=model)
    rng = np.random.default_rng(0)
    xn = rng.uniform(-0.35, 0.35, (50, 2))
    px = cam.distort(xn)
    if model == "equidistant":
        ref, _ = cv2.fisheye.projectPoints(
            np.c_[xn, np.ones(50)].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.array(D)
        )
    else:
        ref, _ = cv2.projectPoints(np.c_[xn, np.ones(50)], np.zeros(3), np.zeros(3), K, np.array(D))
    np.testing.assert_allclose(px, ref.reshape(-1, 2), atol=1e-9)
    np.testing.assert_allclose(cam.undistort(px), xn, atol=1e-7)


def test_no_distortion_is_k_inverse():
    cam = CameraModel(K, [], 640, 480)
    px = np.array([[320.5, 240.5], [100.0, 50.0]])
    np.testing.assert_allclose(cam.undistort(px)[1], [(100 - 320.5) / 800, (50 - 240.5) / 810])
    np.testing.assert_allclose(cam.distort(cam.undistort(px)), px)


@pytest.mark.parametrize(
    "readout,axis,sign",
    [
        ("top_to_bottom", 1, 1),
        ("bottom_to_top", 1, -1),
        ("left_to_right", 0, 1),
        ("right_to_left", 0, -1),
    ],
)
def test_rs_coordinate_is_proportional_to_capture_time(readout, axis, sign):
    cam = CameraModel(K, [], 640, 480, line_delay=2e-5, readout=readout)
    rng = np.random.default_rng(1)
    px = rng.uniform(0, 479, (20, 2))
    r = cam.rs_coordinate(px)
    times = cam.line_time(px[:, axis])
    # time difference = (r_i - r_j) * seconds_per_unit_r for every pair
    np.testing.assert_allclose(times - times[0], (r - r[0]) * cam.seconds_per_unit_r, atol=1e-15)
    assert np.all(np.diff(times[np.argsort(px[:, axis])]) * sign >= 0)
    np.testing.assert_allclose(cam.undistort(px) @ cam.readout_vector, r, atol=1e-12)
    assert cam.line_time(cam.reference_line) == pytest.approx(
        cam.readout_time / 2 - cam.line_delay / 2
    )


def test_reference_row_and_readout_time():
    cam = CameraModel.from_readout_time(K, 0.0288, 640, 480, reference_row=0.0)
    assert cam.line_delay == pytest.approx(0.0288 / 480)
    assert cam.r0 == pytest.approx((0 - 240.5) / 810)
    assert cam.time_offset(0.0, 100.0) == pytest.approx(100 * cam.line_delay)
    cam2 = CameraModel.from_readout_time(K, 0.0288, 640, 480, readout="left_to_right")
    assert cam2.line_delay == pytest.approx(0.0288 / 640)


def test_normalize_offsets_for_distorted_rows():
    cam = CameraModel(K, [-0.3, 0.1, 0, 0, 0], 640, 480, line_delay=1e-5)
    px = np.array([[10.0, 10.0], [320.5, 240.5]])
    x, r, r0e = cam.normalize(px)
    np.testing.assert_allclose(r, (px[:, 1] - 240.5) / 810)
    # r0_eff shifts r0 by the distortion offset of each point's row
    np.testing.assert_allclose(r0e, cam.r0 - (r - x[:, 1]))


@pytest.mark.parametrize(
    "kw",
    [
        dict(K=np.diag([0.0, 1, 1])),
        dict(K=np.full((3, 3), np.nan)),
        dict(K=K, width=0),
        dict(K=K, line_delay=-1.0),
        dict(K=K, readout="diagonal"),
        dict(K=K, distortion_model="kb8"),
        dict(K=K, D=[0.1, 0.2, 0.3]),
        dict(K=K, D=[np.inf]),
    ],
)
def test_invalid_camera_raises(kw):
    with pytest.raises(ValueError):
        CameraModel(**kw)
