"""The marker detector's default corners on real photos made by others
(``shared/data/real_markers``, skipped when absent): no worse than the AprilTag library's own
corners, judged by how well each tag's corners fit a square and a calibrated board's corners
fit its known layout."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from rs_localizer import cv_compat
from rs_localizer.frontends import marker_detection as md
from rs_localizer.frontends.marker_detection import DetectorOptions, make_marker_detector

#: ``shared/data/real_markers`` beside the checkout (or beside its folder of worktrees)
REAL = next(
    (
        p
        for p in (
            Path(__file__).resolve().parents[k] / ".." / "shared" / "data" / "real_markers"
            for k in (2, 3)
        )
        if p.is_dir()
    ),
    None,
)

needs_real = pytest.mark.skipif(REAL is None, reason="no real marker photos (shared/data)")
needs_apriltag = pytest.mark.skipif(
    md.apriltag_binding() is None, reason="no AprilTag library binding installed"
)

#: the ChArUco photos of ``opencv_aruco_tutorial``: 5x7 squares of 40 mm, markers of 20 mm
CHARUCO_PHOTOS = (
    "choriginal.jpg",
    "chocclusion_original.jpg",
    "img_00.jpg",
    "img_02.jpg",
    "img_03.jpg",
)


def _square_fit(corners, K, D):
    """(M,) RMS px of each marker's 4 corners around its best square pose (IPPE)."""
    obj = np.array([[-0.5, 0.5, 0], [0.5, 0.5, 0], [0.5, -0.5, 0], [-0.5, -0.5, 0]])
    out = []
    for c in corners:
        _, rv, tv = cv2.solvePnP(obj, c, K, D, flags=cv2.SOLVEPNP_IPPE_SQUARE)
        p = cv2.projectPoints(obj, rv, tv, K, D)[0].reshape(4, 2)
        out.append(np.sqrt(np.mean(np.sum((p - c) ** 2, axis=1))))
    return np.array(out)


def _expected(path):
    """The library's corners of its regression test, ArUco order, OpenCV's convention."""
    rows = []
    for line in path.read_text().splitlines():
        v = line.replace("(", " ").replace(")", " ").replace(",", " ").split()
        if len(v) == 9:
            rows.append(np.array(v[1:], float).reshape(4, 2))
    c = np.array(rows)
    return c[:, md.APRILTAG_TO_ARUCO_ORDER] - md.APRILTAG_PIXEL_OFFSET


@needs_real
@needs_apriltag
def test_default_corners_on_real_tag_photos():
    """On the AprilTag library's three regression photos (36h11 tags of 13-45 px, every tag id
    0, so each is searched in a window around it): the default detector's corners fit a
    square (pinhole of focal length the image width: no intrinsics come with the photos) no
    worse than the library's own corners of the same tags, and lie within half a pixel
    (median) of the corners of the library's regression test."""
    default = make_marker_detector("DICT_APRILTAG_36h11")
    library = md.AprilTagDetector("tag36h11", default.options, edge_refinement=False)
    fit = {"default": [], "library": []}
    agree = []
    for img in sorted((REAL / "apriltag_photos").glob("*.jpg")):
        gray = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE)
        h, w = gray.shape
        K = np.array([[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1]], float)
        for e in _expected(img.with_suffix(".txt")):
            side = np.ptp(e, axis=0).max()
            x0, y0 = np.floor(e.min(axis=0) - side).astype(int)
            x1, y1 = np.ceil(e.max(axis=0) + side).astype(int)
            win = (max(x0, 0), max(y0, 0), min(x1, w), min(y1, h))
            c, _, _ = default.detect_window(gray, win)
            cl, _, _ = library.detect_window(gray, win)
            near = np.linalg.norm(c.mean(axis=1) - e.mean(axis=0), axis=1) < 3 if len(c) else []
            near_l = np.linalg.norm(cl.mean(axis=1) - e.mean(axis=0), axis=1) < 3 if len(cl) else []
            if np.count_nonzero(near) != 1 or np.count_nonzero(near_l) != 1:
                continue
            c, cl = c[near], cl[near_l]
            fit["default"].extend(_square_fit(c, K, None))
            fit["library"].extend(_square_fit(cl, K, None))
            agree.extend(np.linalg.norm(c[0] - e, axis=1))
    assert len(fit["default"]) >= 20, len(fit["default"])
    med = {k: float(np.median(v)) for k, v in fit.items()}
    assert med["default"] <= med["library"] + 1e-6, med
    assert np.median(agree) < 0.5, np.median(agree)


@needs_real
def test_default_corner_method_on_a_real_calibrated_board():
    """On five real photos of a ChArUco board taken with a calibrated camera, starting from
    the AprilTag quad fit's corners (OpenCV's port of the library's; the library cannot read
    the board's ArUco markers): the corners the detector's default corner method gives
    (``DetectorOptions().edge_refinement``) fit each marker's square and the whole board's
    known layout (one PnP on all marker corners) no worse than the quad fit's corners, and
    that pose lies within 0.5 deg and 5 mm of the pose of the board's chessboard corners."""
    folder = REAL / "opencv_aruco_tutorial"
    fs = cv2.FileStorage(str(folder / "tutorial_camera_charuco.yml"), cv2.FILE_STORAGE_READ)
    K, D = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat().ravel()
    fs.release()
    dictionary = cv_compat.get_dictionary("DICT_6X6_250")
    board = cv_compat.charuco_board(5, 7, 0.04, 0.02, dictionary)
    obj = dict(
        zip(cv_compat.board_ids(board).tolist(), cv_compat.board_object_points(board), strict=True)
    )
    chess = cv_compat.charuco_chessboard_corners(board)
    params = cv_compat.detector_parameters(cornerRefinementMethod=cv2.aruco.CORNER_REFINE_APRILTAG)
    markers = cv_compat.MarkerDetector(dictionary, params)
    charuco = cv_compat.CharucoCornerDetector(board)
    refine = DetectorOptions().edge_refinement
    fit = {"default": [], "library": []}
    rms = {"default": [], "library": []}
    for name in CHARUCO_PHOTOS:
        gray = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        corners, ids, _ = markers.detect(gray)
        keep = np.isin(ids, list(obj))
        lib = corners[keep].astype(np.float64) - md.APRILTAG_PIXEL_OFFSET
        ids = ids[keep]
        assert len(ids) >= 8
        dflt = md.refine_tag_edges(gray, lib, 8) if refine else lib
        X = np.concatenate([obj[int(i)] for i in ids])
        cc, cids, _, _ = charuco.detect(gray, K, D)
        _, r_ref, t_ref = cv2.solvePnP(chess[cids], cc.reshape(-1, 1, 2), K, D)
        for k, c in (("default", dflt), ("library", lib)):
            fit[k].extend(_square_fit(c, K, D))
            uv = c.reshape(-1, 1, 2)
            _, rv, tv = cv2.solvePnP(X, uv, K, D)
            p = cv2.projectPoints(X, rv, tv, K, D)[0]
            rms[k].append(np.sqrt(np.mean(np.sum((p - uv) ** 2, axis=2))))
            R, R0 = cv2.Rodrigues(rv)[0], cv2.Rodrigues(r_ref)[0]
            angle = np.degrees(np.arccos(np.clip((np.trace(R.T @ R0) - 1) / 2, -1, 1)))
            apart = np.linalg.norm(-R.T @ tv - (-R0.T @ t_ref))
            assert angle < 0.5 and apart < 0.005, (name, k, angle, apart)
    assert np.median(fit["default"]) <= np.median(fit["library"]) + 1e-6
    assert np.mean(rms["default"]) <= np.mean(rms["library"]) + 1e-6, rms


@needs_real
@needs_apriltag
def test_small_tags_on_real_tag_photos():
    """On the three regression photos (36h11 tags of 13-45 px, 799x533: decimated by 2 by
    default) ``small_tags`` (a coarser pass, then the small-tag look) finds more tags than the
    default decimated pass and at least 0.8x of those a full-resolution pass finds, each of
    them a tag of the library's regression test (no false tag), the look's with corners within
    half a pixel (median) of its corners."""
    det = md.AprilTagDetector("tag36h11", DetectorOptions(small_tags=True))
    full = md.AprilTagDetector("tag36h11", DetectorOptions(quad_decimate=1))
    found = {"default": 0, "small_tags": 0, "full": 0}
    errs = []
    for img in sorted((REAL / "apriltag_photos").glob("*.jpg")):
        gray = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE)
        # (the library's order and convention: the order's permutation is its own inverse)
        exp = (_expected(img.with_suffix(".txt")) + md.APRILTAG_PIXEL_OFFSET)[
            :, md.APRILTAG_TO_ARUCO_ORDER
        ]
        runs = {
            "default": det.raw(gray),  # (the options' decimation: 2 here)
            "small_tags": det.raw_frame(gray),
            "full": full.raw(gray),
        }
        for name, (c, _, ham, mar) in runs.items():
            tags = c[(ham == 0) & (mar >= det.min_decision_margin)]
            d = np.linalg.norm(tags.mean(axis=1)[:, None] - exp.mean(axis=1)[None], axis=2)
            assert (d.min(axis=1) < 3).all(), name  # every tag found is a true one
            found[name] += int((d.min(axis=0) < 3).sum())
        c, _, ham, mar = runs["default"]
        more, _, ham2, mar2 = det.small_tag_look(gray, c)
        more = more[(ham2 == 0) & (mar2 >= det.min_decision_margin)]
        if len(more):
            d = np.linalg.norm(more.mean(axis=1)[:, None] - exp.mean(axis=1)[None], axis=2)
            errs.extend(np.linalg.norm(more - exp[d.argmin(axis=1)], axis=2).ravel())
    assert found["small_tags"] >= found["default"] + 6, found
    assert found["small_tags"] >= 0.9 * found["full"], found
    assert np.median(errs) < 0.5, np.median(errs)


@needs_real
@needs_apriltag
@pytest.mark.parametrize("contrast", [0.6, 0.4])
def test_small_tags_on_dim_real_tag_photos(contrast):
    """The regression photos with their grey levels pulled towards mid-grey (a dim or hazy
    view): ``small_tags``, whose candidates are judged against the image's own grey range,
    still finds at least the tags the default decimated pass finds, and no false tag."""
    det = md.AprilTagDetector("tag36h11", DetectorOptions(small_tags=True))
    found = {"default": 0, "small_tags": 0}
    for img in sorted((REAL / "apriltag_photos").glob("*.jpg")):
        gray = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE).astype(float)
        gray = np.round(128 + contrast * (gray - 128)).astype(np.uint8)
        exp = _expected(img.with_suffix(".txt")) + md.APRILTAG_PIXEL_OFFSET
        for name, (c, _, ham, mar) in (
            ("default", det.raw(gray)),
            ("small_tags", det.raw_frame(gray)),
        ):
            tags = c[(ham == 0) & (mar >= det.min_decision_margin)]
            if len(tags):
                d = np.linalg.norm(tags.mean(axis=1)[:, None] - exp.mean(axis=1)[None], axis=2)
                assert (d.min(axis=1) < 3).all(), name
                found[name] += int((d.min(axis=0) < 3).sum())
    assert found["small_tags"] >= found["default"] > 0, found
