"""Marker maps from tag poses (``rs-localizer tag-map``, :mod:`rs_localizer.maps.tag_poses`)
and the corner order the docs state, checked against real detections: TagSLAM's test_23 (a
RealSense D435 watching a 3x3 board of tag36h11 tags, 0.049 m, pitch 1.5 sides; TagSLAM's own
solution as the reference). The real-data tests skip when ``shared/data/real_markers`` is
absent."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.paths import ROOT
from scipy.spatial.transform import Rotation

from rs_localizer import CameraModel, estimate_rs_pose
from rs_localizer.cli import main
from rs_localizer.frontends.marker_detection import APRILTAG_PIXEL_OFFSET, APRILTAG_TO_ARUCO_ORDER
from rs_localizer.maps import load_marker_map
from rs_localizer.maps.tag_poses import read_tag_layout, tag_corners

REAL = next(
    (
        p
        for p in (
            ROOT / ".." / "shared" / "data" / "real_markers",
            ROOT / ".." / ".." / "shared" / "data" / "real_markers",
        )
        if p.is_dir()
    ),
    None,
)
T23 = REAL / "tagslam" / "test_23" if REAL is not None else None
needs_real = pytest.mark.skipif(
    T23 is None or not T23.is_dir(), reason="shared/data/real_markers is absent"
)

SIZE = 0.049
PITCH = SIZE * 1.5  # (tagslam.yaml: tag_spacing 0.5 of the size)
#: TagSLAM's board: tag row * 3 + col, rows up; the body frame at the centre tag
BOARD = {
    r * 3 + c: np.array([(c - 1) * PITCH, (r - 1) * PITCH, 0.0]) for r in range(3) for c in range(3)
}


def _docs_corners(order: tuple) -> dict:
    """The board's map written by hand as docs/marker_maps.md's corner table says: tag frame x
    right, y up on the printed face, z out of it; ``order``: the printed corners in the
    detector's order."""
    h = SIZE / 2
    printed = {"TL": (-h, h), "TR": (h, h), "BR": (h, -h), "BL": (-h, -h)}
    return {k: np.array([[*printed[c], 0.0] for c in order]) + t for k, t in BOARD.items()}


def _frames(step: int) -> list:
    """Every ``step``-th frame of test_23: (pixel corners {id: (4, 2)} as this package's
    detector returns them, the reference pose of the camera in the board frame (R cam ->
    board, centre))."""

    def pose(q, t):
        M = np.eye(4)
        M[:3, :3] = Rotation.from_quat(q).as_matrix()
        M[:3, 3] = t
        return M

    tf = {
        (t["parent"], t["child"]): t
        for t in json.loads((T23 / "json/reference_final_tf.json").read_text())
    }
    rig, cam = tf[("map", "rig")], tf[("rig", "cam0")]
    map_cam = pose(rig["quat_xyzw"], rig["translation"]) @ pose(
        cam["quat_xyzw"], cam["translation"]
    )
    odom = {
        round(o["stamp"], 4): o
        for o in map(json.loads, (T23 / "json/reference_odom.jsonl").read_text().splitlines())
    }
    out = []
    lines = (T23 / "json/detections.jsonl").read_text().splitlines()
    for line in lines[::step]:
        d = json.loads(line)
        o = odom[round(d["stamp"], 4)]
        board_cam = np.linalg.inv(pose(o["quat_xyzw"], o["position"])) @ map_cam
        # (the AprilTag library's corners, converted as the detector converts them)
        px = {
            t["id"]: np.array(t["corners"])[list(APRILTAG_TO_ARUCO_ORDER)] - APRILTAG_PIXEL_OFFSET
            for t in d["tags"]
        }
        out.append((px, board_cam[:3, :3], board_cam[:3, 3]))
    return out


def _localize(corners: dict, frames: list) -> np.ndarray:
    """Per frame (position error mm, rotation error deg) of the camera localized on the map
    ``corners`` against TagSLAM's reference; inf where no pose is found. The board barely moves
    (no visible rolling-shutter effect): the global-shutter solver of the package."""
    cam = CameraModel(
        K=np.array([[612.569, 0, 319.370], [0, 612.861, 241.992], [0, 0, 1]]), width=640, height=480
    )
    errs = []
    for px, R_ref, c_ref in frames:
        ids = sorted(px)
        est = estimate_rs_pose(
            np.concatenate([px[i] for i in ids]),
            np.concatenate([corners[i] for i in ids]),
            cam,
            solver="p3p",
            implementation="numpy",
        )
        if not est.success or est.num_inliers < 4 * len(ids) - 2:
            errs.append((np.inf, np.inf))
            continue
        d_rot = Rotation.from_matrix(est.pose.orientation.T @ R_ref).magnitude()
        errs.append((1e3 * np.linalg.norm(est.pose.position - c_ref), np.degrees(d_rot)))
    return np.array(errs)


@needs_real
def test_documented_apriltag_corner_order_localizes_real_detections():
    """A map written as the docs say (AprilTag corners: the printed tag's bottom-right,
    bottom-left, top-left, top-right) puts the real camera where TagSLAM does, within 10 mm and
    0.5 deg (measured: 3.5 mm, 0.17 deg median); the order the docs used to state (top-left
    first: the tags turned by 180 degrees about their centres) does not."""
    frames = _frames(37)
    good = _localize(_docs_corners(("BR", "BL", "TL", "TR")), frames)
    assert np.all(np.isfinite(good)), good
    assert np.median(good[:, 0]) < 10 and np.median(good[:, 1]) < 0.5, good
    wrong = _localize(_docs_corners(("TL", "TR", "BR", "BL")), frames)
    assert not np.any((wrong[:, 0] < 50) & (wrong[:, 1] < 5)), wrong


def _on_white(image: np.ndarray, cell: int = 30) -> np.ndarray:
    """``image`` (one pixel a cell) scaled to ``cell`` px a cell on a white page, 100 px margin."""
    import cv2

    h, w = image.shape
    big = cv2.resize(image, (w * cell, h * cell), interpolation=cv2.INTER_NEAREST)
    return np.pad(big, 100, constant_values=255)


def _apriltag_library_image(family: str, idx: int) -> np.ndarray | None:
    """The AprilTag library's own image of ``family`` tag ``idx``, one pixel a cell, row 0 at
    the top (the layout of its ``apriltag_to_image``: a one-cell white ring, the code's bits at
    the family's ``bit_x``, ``bit_y`` cells), from the family tables of the library
    pupil_apriltags bundles; None without it."""
    import ctypes

    try:
        import pupil_apriltags
    except ImportError:
        return None
    libs = sorted(Path(pupil_apriltags.__file__).parent.glob("lib*/libapriltag.so*"))
    if not libs:
        return None

    class Family(ctypes.Structure):
        _fields_ = [
            ("ncodes", ctypes.c_uint32),
            ("codes", ctypes.POINTER(ctypes.c_uint64)),
            ("width_at_border", ctypes.c_int),
            ("total_width", ctypes.c_int),
            ("reversed_border", ctypes.c_bool),
            ("nbits", ctypes.c_uint32),
            ("bit_x", ctypes.POINTER(ctypes.c_int32)),
            ("bit_y", ctypes.POINTER(ctypes.c_int32)),
        ]

    create = getattr(ctypes.CDLL(str(libs[0])), f"{family}_create")
    create.restype = ctypes.POINTER(Family)
    fam = create().contents
    tw = fam.total_width
    img = np.zeros((tw, tw), np.uint8)
    ring = fam.width_at_border + (0 if fam.reversed_border else 2)
    s = (tw - ring) // 2
    img[s, s : s + ring] = img[s + ring - 1, s : s + ring] = 255
    img[s : s + ring, s] = img[s : s + ring, s + ring - 1] = 255
    b = (tw - fam.width_at_border) // 2
    for i in range(fam.nbits):
        if fam.codes[idx] >> (fam.nbits - i - 1) & 1:
            img[fam.bit_y[i] + b, fam.bit_x[i] + b] = 255
    return img


def test_aruco_corner_order_on_printed_image():
    """ArUco (OpenCV's marker image): corner 0 is the printed top-left, then clockwise."""
    from rs_localizer.cv_compat import get_dictionary, marker_image
    from rs_localizer.frontends.marker_detection import make_marker_detector

    # 8 cells (6 bits + the black border) and a white cell around: the black square spans
    # 130..370 px of the page
    aruco = np.pad(marker_image(get_dictionary("DICT_6X6_50"), 3, 8), 1, constant_values=255)
    c, ids, _ = make_marker_detector("DICT_6X6_50").detect(_on_white(aruco))
    assert ids.tolist() == [3]
    np.testing.assert_allclose(c[0], [[130, 130], [369, 130], [369, 369], [130, 369]], atol=1.5)


#: the AprilTag families pupil_apriltags builds, and OpenCV's names of those it has
_OPENCV_NAMES = {"tag16h5": "16h5", "tag25h9": "25h9", "tag36h11": "36h11"}


@pytest.mark.parametrize(
    "family",
    [
        "tag16h5",
        "tag25h9",
        "tag36h11",
        "tagStandard41h12",
        "tagCircle21h7",
        # (the library builds these three families' decoding tables in 25-40 s each)
        pytest.param("tagStandard52h13", marks=pytest.mark.slow),
        pytest.param("tagCircle49h12", marks=pytest.mark.slow),
        pytest.param("tagCustom48h12", marks=pytest.mark.slow),
    ],
)
def test_apriltag_corner_order_on_printed_image(family):
    """AprilTag families (the library's own image): corner 0 is the printed bottom-right, then
    bottom-left, top-left, top-right, with either detector; OpenCV's image of the same tag is
    the library's turned by 180 degrees."""
    from rs_localizer.cv_compat import get_dictionary, marker_image
    from rs_localizer.frontends.marker_detection import (
        DetectorOptions,
        apriltag_binding,
        make_marker_detector,
    )

    official = _apriltag_library_image(family, 3)
    if official is None or apriltag_binding() is None:
        pytest.skip("the AprilTag library (pupil_apriltags) is not installed")
    page = _on_white(official)
    names = [(family, "apriltag")]
    if family in _OPENCV_NAMES:
        cv_name = f"DICT_APRILTAG_{_OPENCV_NAMES[family]}"
        inner = official[1:-1, 1:-1]
        opencv = marker_image(get_dictionary(cv_name), 3, inner.shape[0])
        np.testing.assert_array_equal(opencv > 127, np.rot90(inner, 2) > 127)
        names.append((cv_name, "opencv"))
    for name, det in names:
        c, ids, _ = make_marker_detector(name, DetectorOptions(detector=det)).detect(page)
        assert ids.tolist() == [3], name
        # (image x right, y down: bottom-right is (+, +))
        signs = np.sign(c[0] - c[0].mean(axis=0))
        np.testing.assert_array_equal(signs, [[1, 1], [-1, 1], [-1, -1], [1, -1]], err_msg=name)


def _board_layouts(tmp_path: Path) -> dict:
    """test_23's board in the three formats, each in its own tag frame convention."""
    poses = {
        "dictionary": "tag36h11",
        "tags": [
            {"id": k, "size": SIZE, "pose": {"position": t.tolist(), "orientation": [0, 0, 0, 1]}}
            for k, t in BOARD.items()
        ],
    }
    bundle = {
        "tag_bundles": [
            {
                "name": "board",
                "layout": [
                    {
                        "id": k,
                        "size": SIZE,
                        "x": float(t[0]),
                        "y": float(t[1]),
                        "z": 0.0,
                        "qw": 1.0,
                        "qx": 0.0,
                        "qy": 0.0,
                        "qz": 0.0,
                    }
                    for k, t in BOARD.items()
                ],
            }
        ]
    }
    # WPILib's tag frame: x out of the face (board +z), y to the viewer's right (board +x), z up
    # (board +y): the columns of the tag -> board rotation
    R = np.column_stack([[0, 0, 1], [1, 0, 0], [0, 1, 0]]).astype(float)
    qx, qy, qz, qw = Rotation.from_matrix(R).as_quat()
    wpilib = {
        "tags": [
            {
                "ID": k,
                "pose": {
                    "translation": dict(zip("xyz", t.tolist(), strict=True)),
                    "rotation": {"quaternion": {"W": qw, "X": qx, "Y": qy, "Z": qz}},
                },
            }
            for k, t in BOARD.items()
        ],
        "field": {"length": 16.54, "width": 8.21},
    }
    paths = {
        "poses": tmp_path / "board.yaml",
        "apriltag_ros": tmp_path / "tags.yaml",
        "wpilib": tmp_path / "field.json",
    }
    paths["poses"].write_text(yaml.safe_dump(poses))
    paths["apriltag_ros"].write_text(yaml.safe_dump(bundle))
    paths["wpilib"].write_text(json.dumps(wpilib))
    return paths


@needs_real
@pytest.mark.parametrize("fmt", ["poses", "apriltag_ros", "wpilib"])
def test_tag_map_command_localizes_real_detections(tmp_path, fmt, capsys):
    """``rs-localizer tag-map`` on test_23's board in each format writes the map the docs'
    corner table gives, and the real detections localize on it where TagSLAM puts the camera
    (within 10 mm, 0.5 deg)."""
    layout = _board_layouts(tmp_path)[fmt]
    out = tmp_path / f"{fmt}_map.yaml"
    argv = ["tag-map", str(layout), "-o", str(out), "--dictionary", "tag36h11"]
    if fmt == "wpilib":
        argv += ["--marker-size", str(SIZE)]
    assert main(argv) == 0
    assert "9 tags" in capsys.readouterr().out
    dictionary, corners = load_marker_map(out)
    assert dictionary == "tag36h11"
    docs = _docs_corners(("BR", "BL", "TL", "TR"))
    for k in BOARD:
        np.testing.assert_allclose(corners[k], docs[k], atol=2e-6)
    errs = _localize(corners, _frames(61))
    assert np.all(np.isfinite(errs)) and np.median(errs[:, 0]) < 10, errs
    assert np.median(errs[:, 1]) < 0.5, errs


def test_tag_corners_orders_and_frames():
    """ArUco dictionaries: TL, TR, BR, BL of the printed marker; AprilTag families: BR, BL, TL,
    TR (or TL first with --opencv-images); a tag turned 90 deg about its normal moves its
    corners with it."""
    h = 0.05
    aruco = tag_corners(0.1, np.eye(3), np.zeros(3), "DICT_4X4_50")
    np.testing.assert_allclose(aruco[:, :2], [[-h, h], [h, h], [h, -h], [-h, -h]])
    april = tag_corners(0.1, np.eye(3), np.zeros(3), "DICT_APRILTAG_36h11")
    np.testing.assert_allclose(april[:, :2], [[h, -h], [-h, -h], [-h, h], [h, h]])
    np.testing.assert_allclose(tag_corners(0.1, np.eye(3), np.zeros(3), "tag36h11"), april)
    np.testing.assert_allclose(
        tag_corners(0.1, np.eye(3), np.zeros(3), "tag36h11", opencv_images=True), aruco
    )
    Rz = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    t = np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(tag_corners(0.1, Rz, t, "DICT_4X4_50"), aruco @ Rz.T + t)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "tags: [{id: 1, size: 0.1, pose: {position: [0, 0, 0], orientation: [0, 0, 0, 1]}}, "
            "{id: 1, size: 0.1, pose: {position: [1, 0, 0], orientation: [0, 0, 0, 1]}}]",
            "appears twice",
        ),
        (
            "tags: [{id: 1, size: 0.1, pose: {position: [0, 0, 0], orientation: [0, 0, 0, 2]}}]",
            "not a unit quaternion",
        ),
        ("tags: [{id: 1, pose: {position: [0, 0, 0], orientation: [0, 0, 0, 1]}}]", "no size"),
        (
            "tags: [{id: 1, size: -1, pose: {position: [0, 0, 0], orientation: [0, 0, 0, 1]}}]",
            "size must be > 0",
        ),
        (
            "tags: [{id: 1, size: 0.1, pose: {position: [0, 0], orientation: [0, 0, 0, 1]}}]",
            "position",
        ),
        (
            "tag_bundles: [{name: a, layout: [{id: 1, size: 0.1}]}, "
            "{name: b, layout: [{id: 2, size: 0.1}]}]",
            "name one",
        ),
        ("foo: 1", "not a tag layout"),
    ],
)
def test_tag_map_refuses_bad_layouts(tmp_path, capsys, text, message):
    """A bad layout is refused with one line naming the problem, and no map is written."""
    layout = tmp_path / "layout.yaml"
    layout.write_text(text + "\n")
    out = tmp_path / "map.yaml"
    assert main(["tag-map", str(layout), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists() and not list(tmp_path.glob(".map.yaml*"))


def test_tag_map_sizes_by_id_range(tmp_path):
    """WPILib's layout has no sizes: ``--marker-sizes`` by id range (and a default) gives
    them; tags outside every range take ``--marker-size``."""
    tags = [
        {
            "ID": k,
            "pose": {
                "translation": {"x": k, "y": 0, "z": 1},
                "rotation": {"quaternion": {"W": 1, "X": 0, "Y": 0, "Z": 0}},
            },
        }
        for k in range(1, 6)
    ]
    layout = tmp_path / "field.json"
    layout.write_text(json.dumps({"tags": tags}))
    lay = read_tag_layout(layout, sizes={1: 0.3, 2: 0.3}, default_size=0.1651)
    assert {k: v[0] for k, v in lay.tags.items()} == {
        1: 0.3,
        2: 0.3,
        3: 0.1651,
        4: 0.1651,
        5: 0.1651,
    }
    out = tmp_path / "map.yaml"
    assert (
        main(
            [
                "tag-map",
                str(layout),
                "-o",
                str(out),
                "--marker-sizes",
                "1-2:0.3",
                "--marker-size",
                "0.1651",
            ]
        )
        == 0
    )
    _, corners = load_marker_map(out)
    sides = {k: np.linalg.norm(c[1] - c[0]) for k, c in corners.items()}
    np.testing.assert_allclose(
        [sides[k] for k in range(1, 6)], [0.3, 0.3, 0.1651, 0.1651, 0.1651], atol=1e-5
    )
    # WPILib's identity pose faces the tag along +x (its corners lie in the plane x = ID), z up;
    # seen from +x looking back, the viewer's right is +y: corner 0, the printed bottom-right of
    # an AprilTag, is at (+h, -h) in (y, z) from the centre
    np.testing.assert_allclose(corners[3][:, 0], 3.0)
    h = 0.1651 / 2
    np.testing.assert_allclose(corners[3][0], [3.0, h, 1 - h], atol=1e-6)
    np.testing.assert_allclose(corners[3][2], [3.0, -h, 1 + h], atol=1e-6)
    # without any size the tags are refused
    assert main(["tag-map", str(layout), "-o", str(tmp_path / "m2.yaml"), "--overwrite"]) == 2


@pytest.mark.skipif(
    REAL is None or not (REAL / "opencv_aruco_tutorial").is_dir(),
    reason="shared/data/real_markers is absent",
)
@pytest.mark.parametrize("photo", ["choriginal.jpg", "chocclusion_original.jpg"])
def test_documented_aruco_corner_order_localizes_real_photo(photo):
    """OpenCV's tutorial photos of a ChArUco board (5x7 squares of 0.04 m, 0.02 m markers of
    DICT_6X6_250, calibrated camera): its markers written as the docs say (ArUco: the printed
    top-left first, clockwise; marker k in the k-th white square row by row from the printed
    top-left) fit every detected corner, and the camera lies within 5 mm and 0.5 deg of the
    pose of the board's chessboard corners (OpenCV's ChArUco interpolation and solvePnP:
    measured 1.1 mm, 0.17 deg); the AprilTag order on the same markers does not fit."""
    import cv2

    from rs_localizer.cv_compat import (
        CharucoCornerDetector,
        board_image,
        charuco_board,
        charuco_chessboard_corners,
        get_dictionary,
    )
    from rs_localizer.frontends.marker_detection import make_marker_detector

    d = REAL / "opencv_aruco_tutorial"
    fs = cv2.FileStorage(str(d / "tutorial_camera_charuco.yml"), cv2.FILE_STORAGE_READ)
    K, dist = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
    board = charuco_board(5, 7, 0.04, 0.02, get_dictionary("DICT_6X6_250"))
    page = board_image(board, (500, 700))  # (the printed board, 100 px a square)
    white = [(r, c) for r in range(7) for c in range(5) if page[r * 100 + 5, c * 100 + 5] > 127]
    assert len(white) == 17
    h = 0.01
    printed = {"TL": (-h, h), "TR": (h, h), "BR": (h, -h), "BL": (-h, -h)}

    def board_map(order):  # (x right, y up on the board, origin at its top-left)
        return {
            k: np.array(
                [
                    [c * 0.04 + 0.02 + px, -(r * 0.04 + 0.02) + py, 0.0]
                    for px, py in map(printed.get, order)
                ]
            )
            for k, (r, c) in enumerate(white)
        }

    gray = cv2.imread(str(d / photo), cv2.IMREAD_GRAYSCALE)
    px, ids, _ = make_marker_detector("DICT_6X6_250").detect(gray)
    cam = CameraModel(K=K, D=dist.ravel(), width=640, height=480)

    def localize(corners):
        return estimate_rs_pose(
            np.concatenate(list(px)),
            np.concatenate([corners[i] for i in ids]),
            cam,
            solver="p3p",
            implementation="numpy",
        )

    est = localize(board_map(("TL", "TR", "BR", "BL")))
    assert est.success and est.num_inliers == 4 * len(ids) >= 52
    cc, cids, _, _ = CharucoCornerDetector(board).detect(gray, K, dist)
    ok, rvec, tvec = cv2.solvePnP(charuco_chessboard_corners(board)[cids], cc, K, dist)
    assert ok
    R = cv2.Rodrigues(rvec)[0]
    flip = np.diag([1.0, -1.0, -1.0])  # OpenCV's board frame (y down, z into it) -> the map's
    np.testing.assert_allclose(est.pose.position, flip @ (-R.T @ tvec.ravel()), atol=5e-3)
    assert np.degrees(Rotation.from_matrix(est.pose.orientation.T @ flip @ R.T).magnitude()) < 0.5
    wrong = localize(board_map(("BR", "BL", "TL", "TR")))
    assert not wrong.success or wrong.num_inliers < 2 * len(ids)


def test_tag_map_with_a_custom_dictionary_file(tmp_path):
    """``--dictionary`` a dictionary file: the map names it relative to itself, loads it from
    any working directory, and its corners are in ArUco order (top-left first)."""
    import cv2

    from rs_localizer.cv_compat import get_dictionary

    (tmp_path / "dicts").mkdir()
    fs = cv2.FileStorage(str(tmp_path / "dicts" / "mine.yml"), cv2.FILE_STORAGE_WRITE)
    get_dictionary("DICT_5X5_50").writeDictionary(fs)
    fs.release()
    layout = tmp_path / "tags.yaml"
    pose = {"position": [0, 0, 0], "orientation": [0, 0, 0, 1]}
    layout.write_text(yaml.safe_dump({"tags": [{"id": 4, "size": 0.1, "pose": pose}]}))
    out = tmp_path / "maps" / "map.yaml"
    argv = [
        "tag-map",
        str(layout),
        "-o",
        str(out),
        "--dictionary",
        str(tmp_path / "dicts" / "mine.yml"),
    ]
    assert main(argv) == 0
    assert yaml.safe_load(out.read_text())["dictionary"] == "../dicts/mine.yml"
    dictionary, corners = load_marker_map(out)
    assert Path(dictionary).resolve() == (tmp_path / "dicts" / "mine.yml").resolve()
    np.testing.assert_allclose(corners[4][0], [-0.05, 0.05, 0.0])
    bad = tmp_path / "bad.yml"
    bad.write_text("%YAML:1.0\nnmarkers: 1\n")
    assert (
        main(["tag-map", str(layout), "-o", str(tmp_path / "m2.yaml"), "--dictionary", str(bad)])
        == 2
    )
    assert not (tmp_path / "m2.yaml").exists()
