"""Board front ends (checkerboard, ChArUco, AprilTag/ArUco tag boards) on OpenCV's sample
photos (test/data/photos, see ATTRIBUTION.md there) and on boards rendered through a known
camera.

The photo counts were checked by eye once on images with the detections drawn. Poses on the
still photos: our P3P estimate must agree with cv2.solvePnP (and the checkerboard's with the
extrinsics OpenCV's calibration stored in left_intrinsics.yml). The rolling-shutter estimate
on the checkerboard photos agrees with P3P and reports a velocity consistent with zero once its
covariance includes the photos' correlated image error
(``python -m benchmarks.still_boards``).

Runs on OpenCV 4.6 (contrib) and on 4.7+ / 5.x (the compatibility layer cv_compat).
"""

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rs_localizer import cv_compat as cvc
from rs_localizer import estimate_rs_pose
from rs_localizer.camera import CameraModel
from rs_localizer.frontends.boards import (
    CharucoFrontend,
    CheckerboardFrontend,
    TagFrontend,
    _canonical_checkerboard,
    make_board_frontend,
)
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.maps.boards import (
    CharucoBoardModel,
    CheckerboardModel,
    TagBoard,
    load_board,
    load_dictionary,
    pose_from_spec,
)
from rs_localizer.sim.render.boards import board_image

PHOTOS = Path(__file__).resolve().parents[1] / "data" / "photos"
LEFT = ["01", "02", "03", "04", "05", "06", "07", "08", "09", "11", "12", "13", "14"]
LINE_DELAY = 30e-6  # nominal: the photos' cameras are unknown; only scales the velocities


def read_camera(name: str, line_delay: float = 0.0) -> CameraModel:
    fs = cv2.FileStorage(str(PHOTOS / name), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    D = fs.getNode("distortion_coefficients").mat().ravel()
    fs.release()
    return CameraModel(K=K, D=D, width=640, height=480, line_delay=line_delay)


def photo(name: str) -> np.ndarray:
    img = cv2.imread(str(PHOTOS / name), cv2.IMREAD_GRAYSCALE)
    assert img is not None, f"missing {name}: run sh test/data/photos/fetch.sh"
    return img


def calibration_extrinsics():
    """(13, 6) rvec | tvec per view of left_intrinsics.yml (left01..09, 11..14)."""
    fs = cv2.FileStorage(str(PHOTOS / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    ext = fs.getNode("extrinsic_parameters").mat()
    fs.release()
    return ext


def solve_pnp(uv, X, camera):
    ok, rv, tv = cv2.solvePnP(X, uv, camera.K, camera.D, flags=cv2.SOLVEPNP_ITERATIVE)
    assert ok
    return cv2.Rodrigues(rv)[0], tv.ravel()


# ------------------------------------------------------------------------ checkerboard photos
@pytest.fixture(scope="module")
def left_board():
    return load_board(PHOTOS / "left_board.yaml")


@pytest.mark.parametrize("method", ["classic", "sb"])
def test_checkerboard_photos_all_corners_in_board_order(left_board, method):
    """All 54 corners of every photo; the order is the board's (not OpenCV's, which differs
    by 180 degrees between the two detectors): the pose from it matches the extrinsics of
    OpenCV's own calibration of these views."""
    camera = read_camera("left_intrinsics.yml")
    ext = calibration_extrinsics()
    fe = CheckerboardFrontend(left_board, method=method)
    for k, n in enumerate(LEFT):
        uv, X, ids = fe.process(photo(f"left{n}.jpg"), camera)
        assert len(ids) == 54 and fe.last_method == method
        np.testing.assert_array_equal(ids, np.arange(54))
        np.testing.assert_allclose(X, left_board.points[ids])
        R, t = solve_pnp(uv, X, camera)
        R_cal = cv2.Rodrigues(ext[k, :3])[0]
        # left02 is the calibration's worst view (1.18 px per-view error): 0.6 deg there
        assert rotation_angle_deg(R, R_cal) < 1.0, n
        assert np.linalg.norm(t - ext[k, 3:]) < 2e-3, n


def test_checkerboard_detectors_agree(left_board):
    """classic (+ cornerSubPix) and SB corners on the same photo: same ids, < 2 px apart
    (median < 0.3 px; measured: max 1.5, 99th percentile 1.17, median 0.16)."""
    a = CheckerboardFrontend(left_board, method="classic")
    b = CheckerboardFrontend(left_board, method="sb")
    errs = []
    for n in LEFT:
        img = photo(f"left{n}.jpg")
        uv_a, _, ids_a = a.process(img)
        uv_b, _, ids_b = b.process(img)
        np.testing.assert_array_equal(ids_a, ids_b)
        errs.append(np.linalg.norm(uv_a - uv_b, axis=1))
    errs = np.concatenate(errs)
    assert errs.max() < 2.0 and np.median(errs) < 0.3


@pytest.mark.slow
def test_checkerboard_pose_p3p_matches_solvepnp(left_board):
    """Our P3P (RANSAC + refinement, global shutter) vs cv2.solvePnP on every photo."""
    camera = read_camera("left_intrinsics.yml", LINE_DELAY)
    fe = CheckerboardFrontend(left_board)
    for n in LEFT:
        uv, X, _ = fe.process(photo(f"left{n}.jpg"))
        R_cv, t_cv = solve_pnp(uv, X, camera)
        est = estimate_rs_pose(uv, X, camera, "p3p")
        assert est.success and est.num_inliers == 54, n
        assert rotation_angle_deg(est.model.R, R_cv) < 0.05, n
        assert np.linalg.norm(est.model.C - t_cv) < 2e-4, n
        assert est.rmse_px < 0.35, n


@pytest.mark.slow
def test_checkerboard_pose_rs_fits_at_least_as_well(left_board):
    """r6p_1lin on the still photos: succeeds with every corner an inlier and, its model
    containing the global-shutter one, fits no worse than P3P. Its pose is NOT compared with
    solvePnP here (planar board, one view: near-degenerate for RS, see module doc)."""
    camera = read_camera("left_intrinsics.yml", LINE_DELAY)
    fe = CheckerboardFrontend(left_board)
    for n in LEFT:
        uv, X, _ = fe.process(photo(f"left{n}.jpg"))
        gs = estimate_rs_pose(uv, X, camera, "p3p")
        rs = estimate_rs_pose(uv, X, camera, "r6p_1lin")
        assert rs.success and rs.num_inliers == 54, n
        assert rs.rmse_px <= gs.rmse_px + 1e-3, n


def test_checkerboard_still_photos_rs_consistent_with_p3p(left_board):
    """The correlated image error is fitted on the 13 still photos (REML,
    as a user would on their calibration views); with it in the covariance, on every photo the
    RS estimate's twist is within the chi2(6) 99.73 % bound of zero, the P3P pose within the
    same bound under the RS pose covariance and the P3P rotation within the chi2(3) one under
    its rotation block; the rotations differ by less than 4.5 deg (at most 3.9). With the
    white-noise
    covariance alone the twist is "significant" on most photos (15-134)."""
    from scipy.stats import chi2

    from rs_localizer.estimation import CorrelatedNoise, EstimateOptions
    from rs_localizer.estimation.noise_model import fit_correlated_noise

    camera = read_camera("left_intrinsics.yml", LINE_DELAY)
    fe = CheckerboardFrontend(left_board)
    frames = []
    for n in LEFT:
        uv, X, _ = fe.process(photo(f"left{n}.jpg"))
        frames.append((n, uv, X, estimate_rs_pose(uv, X, camera, "p3p")))
    fit = fit_correlated_noise(camera, [(uv, X, g.model.R, g.model.C) for _, uv, X, g in frames])
    assert fit.log_likelihood_ratio > 100  # strong evidence for a correlated error
    assert 0.1 < fit.correlated_px < 0.4 and 40 < fit.length_px < 200, fit
    opts = EstimateOptions(
        correlated_noise=CorrelatedNoise(sigma_px=fit.correlated_px, length_px=fit.length_px)
    )
    q6, q3 = chi2.ppf(0.9973, 6), chi2.ppf(0.9973, 3)
    white = []
    for n, uv, X, gs in frames:
        rs = estimate_rs_pose(uv, X, camera, "r6p_1lin", opts)
        rs0 = estimate_rs_pose(uv, X, camera, "r6p_1lin")
        assert rs.success and rs.num_inliers == 54, n
        tw = np.r_[rs.pose.linear_velocity, rs.pose.angular_velocity]
        phi = Rotation.from_matrix(gs.model.R.T @ rs.model.R).as_rotvec()  # world axes
        dp = np.r_[gs.pose.position - rs.pose.position, phi]
        assert rotation_angle_deg(rs.model.R, gs.model.R) < 4.5, n
        assert tw @ np.linalg.solve(rs.twist_covariance, tw) < q6, n
        assert dp @ np.linalg.solve(rs.pose_covariance, dp) < q6, n
        assert phi @ np.linalg.solve(rs.pose_covariance[3:, 3:], phi) < q3, n
        white.append(tw @ np.linalg.solve(rs0.twist_covariance, tw))
    assert np.sum(np.asarray(white) > q6) >= 10


# ------------------------------------------------------------------------ ChArUco / tag photos
@pytest.mark.parametrize("use_camera", [True, False])
def test_charuco_photo(use_camera):
    """OpenCV's charuco tutorial photo: all 17 markers, all 24 inner corners (ids 0..23, as
    drawn once and checked by eye); P3P agrees with solvePnP."""
    camera = read_camera("tutorial_camera_charuco.yml", LINE_DELAY)
    board = load_board(PHOTOS / "choriginal_board.yaml")
    fe = make_board_frontend(board, use_camera=use_camera)
    assert isinstance(fe, CharucoFrontend)
    img = cv2.imread(str(PHOTOS / "choriginal.jpg"))
    uv, X, ids = fe.process(img, camera, encoding="bgr8")
    assert sorted(fe.last_markers) == list(range(17))
    np.testing.assert_array_equal(np.sort(ids), np.arange(24))
    R_cv, t_cv = solve_pnp(uv, X, camera)
    est = estimate_rs_pose(uv, X, camera, "p3p")
    assert est.success and est.num_inliers == 24
    assert rotation_angle_deg(est.model.R, R_cv) < 0.05
    assert np.linalg.norm(est.model.C - t_cv) < 2e-4
    assert est.rmse_px < 0.3


def test_tag_grid_photo_with_custom_dictionary():
    """OpenCV's board tutorial photo: a 5 x 7 grid of markers from the custom dictionary
    tutorial_dict.yml; all 35 found, ids row-major (checked by eye); a plane-to-image
    homography through all 140 corners fits (a wrong id or corner order would not)."""
    board = load_board(PHOTOS / "gboriginal_board.yaml")
    fe = make_board_frontend(board)
    assert isinstance(fe, TagFrontend)
    uv, X, ids = fe.process(cv2.imread(str(PHOTOS / "gboriginal.png")), encoding="bgr8")
    np.testing.assert_array_equal(np.sort(ids), np.arange(140))
    assert fe.last_unknown == 0
    H, _ = cv2.findHomography(X[:, :2], uv, 0)
    err = np.linalg.norm(cv2.perspectiveTransform(X[:, None, :2], H).reshape(-1, 2) - uv, axis=1)
    # paper not flat + lens distortion: ~1 px, vs tens of px for a swapped marker
    assert np.median(err) < 1.5 and err.max() < 3.0


def test_custom_dictionary_matches_opencv_reader():
    d = load_dictionary(PHOTOS / "tutorial_dict.yml")
    ref = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    fs = cv2.FileStorage(str(PHOTOS / "tutorial_dict.yml"), cv2.FILE_STORAGE_READ)
    assert ref.readDictionary(fs.root())
    np.testing.assert_array_equal(d.bytesList, ref.bytesList)
    assert d.markerSize == ref.markerSize == 6 and d.maxCorrectionBits == ref.maxCorrectionBits


def test_single_markers_photo():
    """OpenCV's marker tutorial photo: the 6 markers of its detection figure (DICT_6X6_250);
    a tag map holding 3 of them keeps only their 12 corners."""
    img = photo("singlemarkersoriginal.jpg")
    found = {23, 40, 62, 98, 124, 203}
    tags = [
        dict(id=i, size=0.05, pose=dict(translation=[0.1 * k, 0, 0]))
        for k, i in enumerate(sorted(found))
    ]
    fe = TagFrontend(TagBoard.from_tags(tags, "DICT_6X6_250"))
    _, tids = fe.detect(img)
    assert set(tids.tolist()) == found and len(tids) == 6
    _uv, _X, ids = fe.process(img)
    assert len(ids) == 24
    part = TagFrontend(TagBoard.from_tags(tags[:3], "DICT_6X6_250", id_offset=1000))
    found3 = part.process(img)
    _uv3, X3, ids3 = found3
    assert len(ids3) == 12 and part.last_unknown == 3
    # groups: the tags' own ids (the board's id offset is the correspondences' only)
    assert sorted(found3.groups.tolist()) == sorted(4 * [23, 40, 62])
    np.testing.assert_array_equal(found3.groups, (ids3 - 1000) // 4)
    assert set(((ids3 - 1000) // 4).tolist()) == {23, 40, 62}
    # the same corners, shifted ids, the map points of the 3 tags
    np.testing.assert_allclose(X3, part.board.points[part.board.lookup(ids3)[0]])


# ------------------------------------------------------------------------ synthetic renders
def look_at_board(board_center_b, dist, rotvec_cam_in_board, board_R=None, board_t=None):
    """World -> camera (R, C) of a camera ``dist`` in front of a board point; the camera axes
    are the board's (x right, y down, looking into the board) turned by ``rotvec``."""
    board_R = np.eye(3) if board_R is None else board_R
    board_t = np.zeros(3) if board_t is None else board_t
    Rc = Rotation.from_rotvec(rotvec_cam_in_board).as_matrix()  # camera axes in board frame
    c_b = np.asarray(board_center_b, float) - dist * Rc[:, 2]
    R = Rc.T @ board_R.T
    C = -Rc.T @ (board_R.T @ board_t + c_b)
    return R, C


def render(board, K, R, C, size=(640, 480), ppm=2500.0, margin=40, ss=4, noise=2.0, seed=0):
    """Global-shutter render of a planar board through a pinhole camera (warpPerspective at
    ``ss`` x resolution, area-averaged down). Returns (image, H) with H: board-frame (x, y) ->
    pixel."""
    tex, A = board_image(board, ppm, margin)
    M = R @ board.rotation
    H = K @ np.column_stack([M[:, 0], M[:, 1], R @ board.translation + C])
    S = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1.0]])
    W, Hh = size
    hi = cv2.warpPerspective(
        tex,
        S @ H @ np.linalg.inv(A),
        (W * ss, Hh * ss),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=110,
    )
    img = cv2.resize(hi, size, interpolation=cv2.INTER_AREA).astype(float)
    img += np.random.default_rng(seed).normal(0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8), H


def project(H, points_board):
    p = points_board[:, :2] @ H[:, :2].T + H[:, 2]
    return p[:, :2] / p[:, 2:]


K_SYN = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])


@pytest.mark.parametrize("roll_deg", [0, 90, 180, 270])
@pytest.mark.parametrize("method", ["classic", "sb"])
def test_synthetic_checkerboard_ids_follow_the_board(roll_deg, method):
    """Rendered 9 x 6 board turned in the image by 0/90/180/270 degrees (plus a tilt): every
    id lands on its own projected corner (< 0.5 px): the order does not follow OpenCV's."""
    board = CheckerboardModel(
        9, 6, 0.03, pose=dict(translation=[0.2, -0.1, 1.0], rotvec=[0.1, -0.2, 0.3]), id_offset=7
    )
    centre = np.array([4 * 0.03, 2.5 * 0.03, 0])
    rv = Rotation.from_euler("zx", [roll_deg, 20], degrees=True).as_rotvec()
    R, C = look_at_board(centre, 0.55, rv, board.rotation, board.translation)
    img, H = render(board, K_SYN, R, C, ppm=2000.0, margin=30)
    fe = CheckerboardFrontend(board, method=method)
    uv, X, ids = fe.process(img)
    assert fe.process(img).groups is None  # (each chessboard corner found alone)
    np.testing.assert_array_equal(ids, np.arange(54) + 7)
    err = np.linalg.norm(uv - project(H, board.points_board), axis=1)
    assert err.max() < 0.5 and np.median(err) < 0.15
    np.testing.assert_allclose(X, board.points)
    # the pose from it: our P3P = solvePnP, both near the rendering pose (SB corners are a
    # little less accurate here: up to 0.15 deg / 3 mm, classic 0.03 deg / 0.5 mm)
    camera = CameraModel(K=K_SYN)
    est = estimate_rs_pose(uv, X, camera, "p3p")
    R_cv, _t_cv = solve_pnp(uv, X, camera)
    assert est.success and rotation_angle_deg(est.model.R, R_cv) < 0.05
    assert rotation_angle_deg(est.model.R, R) < 0.25
    assert np.linalg.norm(est.pose.position - (-R.T @ C)) < 5e-3


def test_checkerboard_order_from_any_of_the_four_grid_orders():
    """The true corners handed over in each order OpenCV could report for a 9 x 6 grid (as is,
    turned by 180 degrees, mirrored left-right or top-bottom) come back in the board's order."""
    board = CheckerboardModel(9, 6, 0.03)
    R, C = look_at_board([0.12, 0.075, 0], 0.5, [0.2, -0.1, 2.0])
    img, H = render(board, K_SYN, R, C, ppm=2000.0, margin=30)
    truth = project(H, board.points_board).reshape(6, 9, 2)
    for grid in (truth, truth[::-1, ::-1], truth[:, ::-1], truth[::-1, :]):
        out = _canonical_checkerboard(np.ascontiguousarray(grid), img)
        np.testing.assert_allclose(out, truth)
    # no contrast (a flat image): orientation unknown -> None
    assert _canonical_checkerboard(truth, np.full_like(img, 128)) is None


def test_synthetic_charuco():
    board = CharucoBoardModel(
        6,
        5,
        0.04,
        0.03,
        "DICT_5X5_100",
        marker_ids=np.arange(20, 35),
        pose=dict(translation=[1, 2, 0.5], quaternion=[0, 0, 0.3, 0.95]),
    )
    R, C = look_at_board([0.12, 0.1, 0], 0.6, [0.25, -0.3, 0.4], board.rotation, board.translation)
    img, H = render(board, K_SYN, R, C)
    fe = CharucoFrontend(board)
    camera = CameraModel(K=K_SYN)
    uv, X, ids = fe.process(img, camera)
    assert fe.process(img, camera).groups is None  # (each chessboard corner found alone)
    assert sorted(fe.last_markers) == list(range(20, 35))
    np.testing.assert_array_equal(np.sort(ids), np.arange(20))  # (6-1) x (5-1) corners
    d = uv - project(H, board.points_board[ids])
    err = np.linalg.norm(d, axis=1)
    assert err.max() < 0.5 and np.median(err) < 0.15
    # no systematic shift (OpenCV 4.5.4 .. 4.12 alone: about +0.5 px in x and y)
    assert np.all(np.abs(d.mean(axis=0)) < 0.1)
    est = estimate_rs_pose(uv, X, camera, "p3p")
    assert est.success and rotation_angle_deg(est.model.R, R) < 0.1
    assert np.linalg.norm(est.pose.position - (-R.T @ C)) < 1e-3


def test_synthetic_apriltag_grid():
    """AprilTag 36h11 grid board (tags 10..21): all 48 corners on their projections."""
    board = TagBoard.grid(
        4,
        3,
        0.064,
        0.016,
        "DICT_APRILTAG_36h11",
        first_id=10,
        pose=dict(translation=[0, 0, 2.0], rotvec=[np.pi / 2, 0, 0]),
    )
    R, C = look_at_board(
        [0.152, 0.112, 0], 0.7, [-0.3, 0.2, -0.5], board.rotation, board.translation
    )
    img, H = render(board, K_SYN, R, C)
    fe = TagFrontend(board)
    found = fe.process(np.repeat(img[:, :, None], 3, axis=2))  # rgb8 in
    uv, X, ids = found
    np.testing.assert_array_equal(np.sort(ids), 4 * 10 + np.arange(48))
    # each corner's group is its tag: the 4 corners of a tag's printed square
    g = found.groups
    assert g.dtype == np.int64 and sorted(set(g.tolist())) == list(range(10, 22))
    for t in range(10, 22):
        np.testing.assert_allclose(X[g == t], board.points[board.lookup(4 * t + np.arange(4))[0]])
    err = np.linalg.norm(uv - project(H, board.points_board[board.lookup(ids)[0]]), axis=1)
    # subpixel refinement of square-marker corners pulls them ~0.1 px inwards
    assert err.max() < 0.5 and np.median(err) < 0.3
    est = estimate_rs_pose(uv, X, CameraModel(K=K_SYN), "p3p")
    assert est.success and rotation_angle_deg(est.model.R, R) < 0.2
    assert np.linalg.norm(est.pose.position - (-R.T @ C)) < 3e-3


def test_board_image_unrotated_detections():
    """board_image's pixel mapping A is exact: the flat image's detections sit on A's
    predictions (checkerboard, ChArUco, AprilTag grid)."""
    boards = [
        CheckerboardModel(5, 4, 0.02),
        CharucoBoardModel(4, 4, 0.02, 0.014, "DICT_4X4_50"),
        TagBoard.grid(3, 2, 0.024, 0.008),
    ]
    for b in boards:
        img, A = board_image(b, 2500.0, 30)
        uv, _, ids = make_board_frontend(b).process(img)
        assert len(ids) == len(b), b.kind
        err = np.linalg.norm(uv - project(A, b.points_board[b.lookup(ids)[0]]), axis=1)
        assert err.max() < 0.3, (b.kind, err.max())


# ------------------------------------------------------------------------ models and loading
def test_board_frames_match_opencv_layout():
    """Our corner coordinates equal OpenCV's board object points (both versions)."""
    d = "DICT_6X6_250"
    ch = CharucoBoardModel(5, 7, 0.04, 0.02, d)
    np.testing.assert_allclose(
        ch.points_board, cvc.charuco_chessboard_corners(ch.cv_board), atol=1e-6
    )
    tg = TagBoard.grid(5, 7, 0.04, 0.01, d)
    ref = cvc.board_object_points(cvc.grid_board(5, 7, 0.04, 0.01, load_dictionary(d)))
    np.testing.assert_allclose(tg.points_board, ref.reshape(-1, 3), atol=1e-6)
    # first ChArUco marker in square (1, 0), the top-left square being black
    np.testing.assert_allclose(ch.marker_corners[0][0], [0.05, 0.01, 0], atol=1e-6)


def test_poses_and_tag_map_yaml(tmp_path):
    # 90 degrees about z: x -> y; quaternion (x y z w) and rotvec give the same
    Rq, t = pose_from_spec(dict(translation=[1, 2, 3], quaternion=[0, 0, 2**-0.5, 2**-0.5]))
    Rv, _ = pose_from_spec(dict(rotvec=[0, 0, np.pi / 2]))
    np.testing.assert_allclose(Rq @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(Rq, Rv, atol=1e-12)
    np.testing.assert_allclose(t, [1, 2, 3])
    (tmp_path / "tags.yaml").write_text(
        "type: tag_map\n"
        "tag_size: 0.2\n"
        "id_offset: 100\n"
        "pose: {translation: [0, 0, 1]}\n"
        "tags:\n"
        "  - {id: 5, pose: {translation: [1, 0, 0], rotvec: [0, 0, 1.5707963267948966]}}\n"
        "  - {id: 6, size: 0.1, pose: {translation: [0, 0, 0]}}\n"
        "  - {id: 7, corners: [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}\n"
    )
    b = load_board(tmp_path / "tags.yaml")
    assert isinstance(b, TagBoard) and b.dictionary.markerSize == 6  # AprilTag 36h11 default
    np.testing.assert_array_equal(b.ids[:4], 100 + 4 * 5 + np.arange(4))
    # tag 5: corner TL (-0.1, -0.1) turned 90 deg about z -> (0.1, -0.1), + (1, 0, 0) + map z 1
    np.testing.assert_allclose(b.tag_corners[5][0], [1.1, -0.1, 1.0], atol=1e-12)
    np.testing.assert_allclose(
        b.tag_corners[6],
        [[-0.05, -0.05, 1], [0.05, -0.05, 1], [0.05, 0.05, 1], [-0.05, 0.05, 1]],
        atol=1e-12,
    )
    np.testing.assert_allclose(b.tag_corners[7][2], [1, 1, 1])


@pytest.mark.parametrize(
    "spec, match",
    [
        (dict(type="hexboard"), "unknown board type"),
        (dict(type="checkerboard", cols=9, rows=6), "needs"),
        (dict(type="checkerboard", cols=9, rows=6, square_size=0.02, colour="red"), "unknown keys"),
        (dict(type="checkerboard", cols=8, rows=6, square_size=0.02), "180 degrees"),
        (
            dict(
                type="checkerboard",
                cols=9,
                rows=6,
                square_size=0.02,
                pose=dict(quaternion=[0, 0, 0, 0]),
            ),
            "quaternion",
        ),
        (
            dict(
                type="checkerboard",
                cols=9,
                rows=6,
                square_size=0.02,
                pose=dict(quaternion=[0, 0, 0, 1], rotvec=[0, 0, 0]),
            ),
            "not both",
        ),
        (
            dict(
                type="charuco",
                cols=5,
                rows=7,
                square_size=0.04,
                marker_size=0.05,
                dictionary="DICT_6X6_250",
            ),
            "marker_size",
        ),
        (
            dict(
                type="charuco",
                cols=5,
                rows=7,
                square_size=0.04,
                marker_size=0.02,
                dictionary="DICT_6X6_50",
                marker_ids=list(range(40, 57)),
            ),
            "marker ids",
        ),
        (
            dict(
                type="charuco",
                cols=5,
                rows=7,
                square_size=0.04,
                marker_size=0.02,
                dictionary="DICT_7X7_BOGUS",
            ),
            "dictionary",
        ),
        (
            dict(type="tag_grid", cols=2, rows=2, tag_size=0.1, tag_spacing=0.02, ids=[1, 2, 3]),
            "distinct ids",
        ),
        (dict(type="tag_map", tags=[dict(id=1, pose={})]), "size"),
    ],
)
def test_load_board_rejects(spec, match):
    with pytest.raises(ValueError, match=match):
        load_board(spec)


def test_legacy_charuco_pattern():
    """Even-row ChArUco boards: the legacy (pre-4.6) layout exists on OpenCV >= 4.8 only."""
    args = (5, 6, 0.04, 0.02, "DICT_6X6_250")
    if hasattr(
        cvc.charuco_board(5, 6, 0.04, 0.02, load_dictionary("DICT_6X6_250")), "setLegacyPattern"
    ):
        new, old = CharucoBoardModel(*args), CharucoBoardModel(*args, legacy_pattern=True)
        assert not np.allclose(new.marker_corners[0], old.marker_corners[0])
    else:
        with pytest.raises(ValueError, match="legacy"):
            CharucoBoardModel(*args, legacy_pattern=True)


def test_frontends_on_empty_images_and_wrong_boards():
    blank = np.full((120, 160), 128, np.uint8)
    for b in (
        CheckerboardModel(5, 4, 0.02),
        CharucoBoardModel(4, 4, 0.02, 0.014, "DICT_4X4_50"),
        TagBoard.grid(2, 2, 0.03, 0.01),
    ):
        uv, X, ids = make_board_frontend(b).process(blank)
        assert uv.shape == (0, 2) and X.shape == (0, 3) and ids.shape == (0,)
    with pytest.raises(TypeError):
        CharucoFrontend(CheckerboardModel(5, 4, 0.02))
    with pytest.raises(ValueError):
        CheckerboardFrontend(CheckerboardModel(5, 4, 0.02), method="fast")


def test_compat_detector_parameters():
    """The parameters object is usable (DetectorParameters() crashes OpenCV 4.6 on first
    use; the compat layer never calls it there) and overrides are applied."""
    p = cvc.detector_parameters(minMarkerPerimeterRate=0.05, noSuchField=1)
    assert p.minMarkerPerimeterRate == pytest.approx(0.05)
    assert hasattr(cv2.aruco, "ArucoDetector") == cvc.NEW_ARUCO_API


# ------------------------------------------------------------------------ numbers for the docs
def _pose_table():  # pragma: no cover - run by hand: python test/frontends/test_boards.py
    camera = read_camera("left_intrinsics.yml", LINE_DELAY)
    fe = CheckerboardFrontend(load_board(PHOTOS / "left_board.yaml"))
    cases = [(f"left{n}.jpg", fe, camera) for n in LEFT]
    cases.append(
        (
            "choriginal.jpg",
            make_board_frontend(PHOTOS / "choriginal_board.yaml"),
            read_camera("tutorial_camera_charuco.yml", LINE_DELAY),
        )
    )
    print(f"OpenCV {cv2.__version__}; line delay {LINE_DELAY * 1e6:.0f} us (nominal)")
    print(
        "photo            n  p3p-pnp deg  p3p-pnp mm  rs-pnp deg  rs-pnp mm  "
        "rs rmse  p3p rmse  |w| rad/s  |v| m/s"
    )
    for name, f, cam in cases:
        uv, X, _ = f.process(photo(name), cam)
        R_cv, t_cv = solve_pnp(uv, X, cam)
        gs = estimate_rs_pose(uv, X, cam, "p3p")
        rs = estimate_rs_pose(uv, X, cam, "r6p_1lin")
        g, r = gs.model, rs.model
        print(
            f"{name:15s} {len(uv):3d}  {rotation_angle_deg(g.R, R_cv):10.3f}  "
            f"{1e3 * np.linalg.norm(g.C - t_cv):10.3f}  {rotation_angle_deg(r.R, R_cv):10.3f}"
            f"  {1e3 * np.linalg.norm(r.C - t_cv):9.2f}  {rs.rmse_px:7.3f}  {gs.rmse_px:8.3f}"
            f"  {np.linalg.norm(rs.pose.angular_velocity):9.3f}  "
            f"{np.linalg.norm(rs.pose.linear_velocity):7.3f}"
        )


if __name__ == "__main__":  # pragma: no cover
    _pose_table()


def test_make_frontend_board_kind_equals_board_frontend():
    """``make_frontend("board", yaml)`` (the node's ``frontend: board``) is the board front end of
    that YAML: same corners and ids on a real photo."""
    from rs_localizer.frontends import FRONTENDS, make_frontend
    from rs_localizer.frontends.boards import make_board_frontend

    assert "board" in FRONTENDS
    yml = PHOTOS / "left_board.yaml"
    img = cv2.imread(str(PHOTOS / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    a = make_frontend("board", yml).process(img, encoding="mono8")
    b = make_board_frontend(yml).process(img, encoding="mono8")
    assert len(a[0]) == 54
    np.testing.assert_array_equal(a[2], b[2])
    np.testing.assert_allclose(a[0], b[0])
