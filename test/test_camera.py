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


# a real fisheye lens (PointGrey Chameleon, 1280x1024, equidistant: TagSLAM's test_2 calibration)
FISHEYE = dict(
    K=np.array([[470.338, 0, 620.702], [0, 470.294, 534.861], [0, 0, 1]]),
    D=[-0.0177484, -0.00281825, 0.00696388, -0.0030704],
    width=1280,
    height=1024,
    distortion_model="equidistant",
)


def _directions(angles_deg, rng):
    """Unit vectors at the given angles from the optical axis, random azimuths."""
    th = np.radians(angles_deg)
    phi = rng.uniform(0, 2 * np.pi, len(th))
    return np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)], axis=1)


def test_fisheye_projection_matches_opencv_to_the_edge_of_the_field():
    """Corners 74-89 deg off-axis (where the projection used to clip at 71.6 deg): the same
    pixels as OpenCV's fisheye model on the 3D points."""
    cam = CameraModel(**FISHEYE)
    P = 2.5 * _directions(np.linspace(1.0, 89.0, 200), np.random.default_rng(0))
    ref, _ = cv2.fisheye.projectPoints(
        P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D[:4]
    )
    np.testing.assert_allclose(cam.project(P), ref.reshape(-1, 2), atol=1e-6)
    uv = cam.project_rs(P, np.eye(3), np.zeros(3))
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6)


def test_fisheye_projection_beyond_90_degrees_follows_the_lens_model():
    """Beyond 90 degrees (z < 0), where the lens model still grows: the radius is f times the
    distorted angle (the equidistant model written out here), on the ray's azimuth."""
    cam = CameraModel(**FISHEYE)
    assert cam.field_limit > np.radians(95)  # (97.2 deg for this lens)
    angles = np.linspace(90.5, np.degrees(cam.field_limit) - 0.5, 50)
    P = _directions(angles, np.random.default_rng(1))
    uv = cam.project(P)
    k = cam.D
    th = np.radians(angles)
    td = th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8)
    rho = np.hypot(P[:, 0], P[:, 1])
    expected = np.stack(
        [
            cam.K[0, 0] * td * P[:, 0] / rho + cam.K[0, 2],
            cam.K[1, 1] * td * P[:, 1] / rho + cam.K[1, 2],
        ],
        axis=1,
    )
    np.testing.assert_allclose(uv, expected, atol=1e-9)
    # (straight behind, past the model's turning point: no image)
    assert np.isnan(cam.project(np.array([[0.0, 1e-3, -1.0]]))).all()


def test_projection_refuses_points_where_the_distortion_turns_back():
    """plumb_bob with k1 < 0: the radius r (1 + k1 r^2) peaks at r = 1 / sqrt(-3 k1); beyond it
    the model folds points back into the image, so they get no pixel (nan) instead."""
    k1 = -0.2
    cam = CameraModel(K=np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]), D=[k1, 0, 0, 0, 0])
    assert cam.field_limit == pytest.approx(1 / np.sqrt(-3 * k1), rel=1e-5)
    r = np.array([0.5, 1.2, 1.3, 2.0])  # (limit 1.29)
    P = np.stack([r, np.zeros(4), np.ones(4)], axis=1)
    uv = cam.project(P)
    ref, _ = cv2.projectPoints(P[:2].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D)
    np.testing.assert_allclose(uv[:2], ref.reshape(-1, 2), atol=1e-9)
    assert np.isnan(uv[2:]).all()
    assert np.isnan(cam.project(np.array([[0.0, 0.0, -1.0]]))).all()  # (behind)
    plain = CameraModel(K=cam.K)
    assert plain.field_limit == np.inf


def test_checked_stamp_types_the_stamp_and_takes_a_typed_one_as_it_is():
    """A stamp in ns (int, numpy int, float truncated as ``int``) becomes a ``Stamp`` (an int);
    a ``Stamp`` comes back unchanged; a stamp that is no finite number or beyond the int64
    nanosecond range raises ValueError; arithmetic gives plain ints."""
    from rs_localizer.camera import MAX_STAMP_NS, Stamp, checked_stamp

    s = checked_stamp(np.int64(1_700_000_000_123_456_789))
    assert type(s) is Stamp and s == 1_700_000_000_123_456_789
    assert checked_stamp(s) is s
    assert checked_stamp(12.9) == 12 and checked_stamp(MAX_STAMP_NS) == 2**63 - 1
    assert type(s + 1) is int and str(s) == "1700000000123456789"
    for bad in (2**63, -(2**63) - 1, 5e19, float("nan"), float("inf"), "x", None):
        with pytest.raises(ValueError, match="stamp"):
            checked_stamp(bad, "IMU")


@pytest.mark.parametrize("readout", ["top_to_bottom", "bottom_to_top", "left_to_right"])
def test_reference_stamp_is_the_reference_lines_capture_time(readout):
    """The reference time of a frame stamped at line ``stamp_row``: the stamp plus the capture
    time from that line to the reference line, counted from the first line read out (rows
    for vertical readout, columns for horizontal); ``FrameTime.of`` checks the stamp and
    carries both."""
    from rs_localizer.camera import FrameTime, Stamp, reference_stamp_ns

    d = 20e-6
    cam = CameraModel(K=np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]]), width=640,
                      height=480, line_delay=d, readout=readout, reference_row=100.0)  # fmt: skip
    lines = 640 if readout == "left_to_right" else 480

    def read_at(line):  # s after the first line read out
        return (lines - 1 - line) * d if readout == "bottom_to_top" else line * d

    stamp = 1_000_000_000_000
    for stamp_row in (0.0, 37.5, 400.0):
        want = stamp + round((read_at(100.0) - read_at(stamp_row)) * 1e9)
        assert reference_stamp_ns(stamp, cam, stamp_row) == want
        t = FrameTime.of(stamp, cam, stamp_row)
        assert type(t.stamp_ns) is Stamp and t.stamp_ns == stamp and t.reference_ns == want
    with pytest.raises(ValueError, match="int64"):
        FrameTime.of(2**64, cam, 0.0)
