"""CameraInfo handling, stamps, quaternions and estimate -> message conversions."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("sensor_msgs.msg")

from sensor_msgs.msg import CameraInfo

from rs_localizer.camera import CameraModel
from rs_localizer.estimation.estimate import RSPoseEstimate
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.pose import RSPose
from rs_localizer.ros import conversions as cv


def _info(model="plumb_bob", d=(0.1, -0.2, 0.001, 0.002, 0.05), w=1280, h=720):
    msg = CameraInfo()
    msg.width, msg.height = w, h
    msg.k = [1000.0, 0.0, 640.0, 0.0, 990.0, 360.0, 0.0, 0.0, 1.0]
    msg.d = list(d)
    msg.distortion_model = model
    return msg


def test_quaternion_roundtrip_and_convention():
    q = cv.quaternion_from_matrix(rotvec_to_matrix(np.array([0.0, 0.0, np.pi / 2])))
    np.testing.assert_allclose(q, [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    rng = np.random.default_rng(0)
    for _ in range(20):
        R = rotvec_to_matrix(rng.normal(0, 1.5, 3))
        q = cv.quaternion_from_matrix(R)
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        np.testing.assert_allclose(cv.matrix_from_quaternion(q), R, atol=1e-12)
        np.testing.assert_allclose(cv.matrix_from_quaternion(-3 * q), R, atol=1e-12)
    with pytest.raises(ValueError):
        cv.matrix_from_quaternion([0, 0, 0, 0])


def test_quaternion_of_an_orthonormal_matrix_skips_the_projection_only():
    """``orthonormal=True`` (SciPy's ``assume_valid`` where it has it) gives the projected
    path's quaternion for a rotation; a non-orthonormal matrix still takes the projection."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        R = rotvec_to_matrix(rng.normal(0, 1.5, 3))
        np.testing.assert_allclose(
            cv.quaternion_from_matrix(R, orthonormal=True), cv.quaternion_from_matrix(R), atol=1e-15
        )
    skewed = R * 1.01
    np.testing.assert_allclose(cv.quaternion_from_matrix(skewed), cv.quaternion_from_matrix(R))
    # a perturbed matrix becomes the nearest rotation: the polar decomposition's orthogonal factor
    from scipy.linalg import polar

    for _ in range(20):
        M = rotvec_to_matrix(rng.normal(0, 1.5, 3)) + rng.normal(0, 0.05, (3, 3))
        q = cv.quaternion_from_matrix(M)
        np.testing.assert_allclose(cv.matrix_from_quaternion(q), polar(M)[0], atol=1e-12)
    for bad in (np.eye(4), np.full((3, 3), np.nan)):
        with pytest.raises(ValueError):
            cv.quaternion_from_matrix(bad)


def test_messages_of_interleaved_estimates_carry_their_own_orientation():
    """A frame's pose and, frames later, an earlier frame's odom are built alternately: each
    message carries its own estimate's orientation (the quaternion cache is per orientation)."""
    rng = np.random.default_rng(2)
    ests = []
    for _ in range(12):
        est, _ = _estimate()
        pose = dataclasses.replace(est.pose, orientation=rotvec_to_matrix(rng.normal(0, 1, 3)))
        ests.append(dataclasses.replace(est, pose=pose))
    for k in range(2, 12):
        for est, build in ((ests[k], cv.pose_stamped), (ests[k - 2], cv.pose_stamped)):
            R, _ = cv.pose_from_msg(build(est.pose, 1, "map").pose)
            np.testing.assert_allclose(R, est.pose.orientation, atol=1e-12)


def test_stamps():
    ns = 1_700_000_123_456_789_012
    st = cv.ns_to_stamp(ns)
    assert (st.sec, st.nanosec) == (1_700_000_123, 456_789_012)
    assert cv.stamp_to_ns(st) == ns
    # never clamped or wrapped ((2^31 - 1, 999999999) + 10.8 ms came out negative)
    for bad in (-5, 2**31 * 10**9, 2**63):
        with pytest.raises(ValueError, match="stamp"):
            cv.ns_to_stamp(bad)
    top = cv.ns_to_stamp(2**31 * 10**9 - 1)
    assert (top.sec, top.nanosec) == (2**31 - 1, 999_999_999)


def test_camera_info_plumb_bob():
    cam = cv.camera_model_from_camera_info(_info(), line_delay=30e-6)
    assert isinstance(cam, CameraModel)
    assert (cam.width, cam.height) == (1280, 720)
    np.testing.assert_array_equal(cam.K, [[1000, 0, 640], [0, 990, 360], [0, 0, 1]])
    np.testing.assert_array_equal(cam.D, [0.1, -0.2, 0.001, 0.002, 0.05])
    assert cam.distortion_model == "plumb_bob" and cam.has_distortion
    assert cam.line_delay == 30e-6 and cam.reference_row is None
    assert cam.reference_line == pytest.approx(359.5)


def test_camera_info_timing_options():
    cam = cv.camera_model_from_camera_info(
        _info(), line_delay=1e-3, readout_time=0.018, readout="bottom_to_top", reference_row=100.0
    )
    assert cam.line_delay == pytest.approx(0.018 / 720)  # readout_time wins
    assert cam.readout == "bottom_to_top" and cam.reference_line == 100.0
    cam = cv.camera_model_from_camera_info(_info(), readout_time=0.0128, readout="left_to_right")
    assert cam.line_delay == pytest.approx(0.0128 / 1280)
    assert cv.camera_model_from_camera_info(_info(), reference_row=-1.0).reference_row is None


@pytest.mark.parametrize(
    "model,d,expect",
    [
        ("rational_polynomial", [0.1, 0.01, 0.0, 0.0, 0.001, 0.2, 0.01, 0.001], 8),
        ("rational_polynomial", [0.1, 0.01, 0.0, 0.0, 0.001, 0.2, 0.01, 0.001] + [0.0] * 6, 8),
        ("equidistant", [0.1, 0.01, 0.001, 0.0001], 4),
        ("plumb_bob", [0.1, 0.01, 0.0, 0.0], 4),
        ("plumb_bob", [0.0] * 5, 0),
        ("", [], 0),
        ("", [0.1, 0.0, 0.0, 0.0, 0.0], 5),
    ],
)
def test_camera_info_distortion_models(model, d, expect):
    cam = cv.camera_model_from_camera_info(_info(model, d))
    assert len(cam.D) == expect
    assert cam.has_distortion == (expect > 0)
    # undistort/distort round trip works for the produced model
    p = np.array([[100.0, 100.0], [640.0, 360.0], [1200.0, 700.0]])
    np.testing.assert_allclose(cam.distort(cam.undistort(p)), p, atol=1e-6)


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial", "equidistant", "none"])
def test_camera_info_with_an_empty_d_is_an_undistorted_camera(model):
    """An empty D is accepted as no distortion under every model (what drivers publish for
    rectified images), as docs/node.md says: pixels map through K alone."""
    cam = cv.camera_model_from_camera_info(_info(model, []))
    assert not cam.has_distortion
    p = np.array([[100.0, 100.0], [640.0, 360.0], [1200.0, 700.0]])
    K = np.asarray(_info().k, dtype=float).reshape(3, 3)
    expected = (p - K[:2, 2]) / np.diag(K)[:2]
    np.testing.assert_allclose(cam.undistort(p), expected, atol=1e-12)
    doc = (Path(__file__).parents[2] / "docs" / "node.md").read_text()
    assert "An empty `D` (or all zeros) is accepted as no distortion" in doc


def test_camera_info_errors():
    bad = _info()
    bad.k = [0.0] * 9
    with pytest.raises(ValueError, match="uncalibrated"):
        cv.camera_model_from_camera_info(bad)
    with pytest.raises(ValueError, match="unsupported distortion model"):
        cv.camera_model_from_camera_info(_info("fisheye_magic"))
    with pytest.raises(ValueError, match="beyond"):
        cv.camera_model_from_camera_info(_info("rational_polynomial", [0.1] * 14))
    with pytest.raises(ValueError, match="image size"):
        cv.camera_model_from_camera_info(_info(w=0))


def test_camera_info_binning_and_roi():
    info = _info(d=[0.0] * 5)
    info.binning_x = info.binning_y = 2
    cam = cv.camera_model_from_camera_info(info)
    assert (cam.width, cam.height) == (640, 360)
    np.testing.assert_allclose(cam.K, [[500, 0, 320], [0, 495, 180], [0, 0, 1]])
    info = _info(d=[0.0] * 5)
    info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = 100, 50, 640, 480
    cam = cv.camera_model_from_camera_info(info)
    assert (cam.width, cam.height) == (640, 480)
    np.testing.assert_allclose(cam.K[:2, 2], [540, 310])
    # full-size ROI is a no-op
    info = _info(d=[0.0] * 5)
    info.roi.width, info.roi.height = 1280, 720
    assert cv.camera_model_from_camera_info(info).K[0, 2] == 640


def test_camera_info_msg_roundtrip():
    cam = cv.camera_model(
        np.array([[900.0, 0, 600], [0, 905, 350], [0, 0, 1]]),
        [0.05, -0.1, 0.0, 0.0, 0.02],
        1200,
        700,
        "plumb_bob",
        line_delay=2e-5,
    )
    info = cv.camera_info_msg(cam, "cam", 123)
    assert info.header.frame_id == "cam" and info.header.stamp.nanosec == 123
    back = cv.camera_model_from_camera_info(info, line_delay=2e-5)
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.D, cam.D)
    assert (back.width, back.height) == (1200, 700)
    np.testing.assert_array_equal(np.reshape(info.p, (3, 4))[:, :3], cam.K)


def test_camera_info_from_rosbags_type():
    pytest.importorskip("rosbags")
    from rclpy.serialization import serialize_message
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    msg = ts.deserialize_cdr(serialize_message(_info()), "sensor_msgs/msg/CameraInfo")
    cam = cv.camera_model_from_camera_info(msg)
    assert cam.K[0, 0] == 1000 and len(cam.D) == 5


def _estimate():
    R = rotvec_to_matrix(np.array([0.1, -0.2, 0.3]))
    pc = np.arange(36, dtype=float).reshape(6, 6)
    tc = np.eye(6) * 0.01
    return RSPoseEstimate(
        success=True,
        solver="r6p_1lin",
        pose=RSPose(
            R, np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.2, 0.3]), np.array([-1.0, -2.0, -3.0])
        ),
        pose_covariance=pc,
        twist_covariance=tc,
    ), R


def test_estimate_messages():
    est, R = _estimate()
    ns = 1_000_000_000 * 42 + 7
    pose = cv.pose_stamped(est.pose, ns, "map")
    assert pose.header.frame_id == "map" and cv.stamp_to_ns(pose.header.stamp) == ns
    Rb, p = cv.pose_from_msg(pose.pose)
    np.testing.assert_allclose(Rb, R, atol=1e-12)
    np.testing.assert_array_equal(p, [1, 2, 3])
    tw = cv.twist_stamped(est.pose, ns, "cam")
    assert tw.header.frame_id == "cam"
    w, v = cv.twist_from_msg(tw.twist)
    np.testing.assert_array_equal(w, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(v, [-1, -2, -3])
    pwc = cv.pose_with_covariance_stamped(est, ns, "map")
    assert list(pwc.pose.covariance) == list(range(36))
    odom = cv.odometry(est, ns, "map", "cam")
    assert odom.header.frame_id == "map" and odom.child_frame_id == "cam"
    assert odom.twist.covariance[0] == 0.01 and odom.twist.covariance[1] == 0.0
    assert odom.pose.covariance[6] == 6.0  # row-major
    np.testing.assert_allclose(cv.twist_from_msg(odom.twist.twist)[1], [-1, -2, -3])


def test_covariance_unknown():
    np.testing.assert_array_equal(cv.covariance36(None), np.zeros(36))
    np.testing.assert_array_equal(cv.covariance36(np.full((6, 6), np.nan)), np.zeros(36))


def test_tf_message_availability():
    est, _ = _estimate()
    if cv.have_tf2_msgs():
        tf = cv.tf_message(est.pose, 5, "map", "cam")
        assert tf.transforms[0].child_frame_id == "cam"
    else:
        with pytest.raises(ImportError):
            cv.tf_message(est.pose, 5, "map", "cam")


# ------------------------------------------------------------------ validation
def test_checked_stamp():
    from builtin_interfaces.msg import Time

    assert cv.checked_stamp_ns(Time(sec=3, nanosec=999_999_999)) == 3_999_999_999
    for sec, nsec in ((1, 1_000_000_000), (1, 4_000_000_000), (-1, 0), (-5, 10)):
        t = Time()
        t.sec, t.nanosec = sec, nsec
        with pytest.raises(ValueError, match="stamp") as e:
            cv.checked_stamp_ns(t)
        assert e.value.reason == "bad_stamp"


def test_camera_info_roi_outside_the_image_is_rejected():
    """A ROI outside or larger than the image was applied (a pose 77 deg off; a 5000x5000 ROI
    moved the output stamp by 64 ms)."""
    for x, y, w, h in (
        (1000, 0, 640, 480),
        (0, 300, 640, 480),
        (0, 0, 5000, 5000),
        (0, 0, 640, 0),
        (0, 0, 0, 480),
        (1280, 0, 0, 0),
    ):
        info = _info(d=[0.0] * 5)
        info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = x, y, w, h
        with pytest.raises(ValueError, match="roi") as e:
            cv.camera_model_from_camera_info(info)
        assert e.value.reason == "bad_roi", (x, y, w, h)
    info = _info(d=[0.0] * 5)
    info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = 640, 240, 640, 480
    cam = cv.camera_model_from_camera_info(info)  # touches the corner: fine
    assert (cam.width, cam.height) == (640, 480)


@pytest.mark.parametrize(
    "d",
    [
        [0.1, -0.2, 0.001],
        [0.1, -0.2],
        [0.1, -0.2, 0.001, 0.002, 0.05, 0.3],
        [0.1, -0.2, 0.001, 0.002, 0.05, 0.0, 0.0, 0.1, 0.2],
        [0.1, np.nan, 0.0, 0.0, 0.0],
        [np.inf, 0, 0, 0, 0],
    ],
)
def test_camera_info_ambiguous_or_bad_distortion_is_rejected(d):
    """plumb_bob D with 3 or 6 non-zero coefficients was zero-padded (1.7-3.3 cm error)."""
    with pytest.raises(ValueError) as e:
        cv.camera_model_from_camera_info(_info("plumb_bob", d))
    assert e.value.reason == "bad_distortion"
    with pytest.raises(ValueError):  # the fallback (camera.d) goes through the same check
        cv.camera_model(
            np.diag([1000.0, 1000.0, 1.0]) + [[0, 0, 640], [0, 0, 360], [0, 0, 0]],
            d,
            1280,
            720,
            "plumb_bob",
        )


def test_camera_info_trailing_zeros_are_trimmed():
    cam = cv.camera_model_from_camera_info(_info("plumb_bob", [0.1, -0.2, 0.001, 0.002, 0.05, 0.0]))
    np.testing.assert_array_equal(cam.D, [0.1, -0.2, 0.001, 0.002, 0.05])
    cam = cv.camera_model_from_camera_info(_info("plumb_bob", [0.1, -0.2, 0.001, 0.002, 0.0, 0.0]))
    np.testing.assert_array_equal(cam.D, [0.1, -0.2, 0.001, 0.002, 0.0])


def test_camera_info_nan_intrinsics_message():
    """NaN cx was logged as 'K has fx or fy <= 0'."""
    info = _info()
    k = list(info.k)
    k[2] = float("nan")
    info.k = k
    with pytest.raises(ValueError, match="non-finite") as e:
        cv.camera_model_from_camera_info(info)
    assert e.value.reason == "bad_intrinsics"
    info = _info()
    info.k = [1000.0, 0.0, 640.0, 0.0, 990.0, 360.0, 0.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="K") as e:
        cv.camera_model_from_camera_info(info)
    assert e.value.reason == "bad_intrinsics"
    bad = _info(w=0)
    with pytest.raises(ValueError) as e:
        cv.camera_model_from_camera_info(bad)
    assert e.value.reason == "bad_size"
