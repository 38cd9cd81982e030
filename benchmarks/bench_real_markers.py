"""Marker corners and small tags on real photos: ``python -m benchmarks.bench_real_markers``
(from the repository root; the photos are read from ``../shared/data/real_markers/``, or
``--data``).

Corner methods, each starting from the same detections:

* ``library``: the AprilTag library's corners (``refine_edges`` on), in ArUco order and OpenCV's
  pixel convention; on the ArUco photos OpenCV's port of the library's quad fit
  (``CORNER_REFINE_APRILTAG``, moved to OpenCV's pixel convention like the library's)
  stands in for it (the AprilTag library cannot read ArUco dictionaries);
* ``edge profile``: those corners refined from their edges' grey-level profiles
  (:func:`~rs_localizer.frontends.marker_detection.refine_tag_edges`);
* ``cornerSubPix``: those corners refined by OpenCV's ``cornerSubPix`` in stages
  (:func:`~rs_localizer.frontends.marker_detection.refine_corners`);
* ``default``: what the AprilTag detector returns by default (its ``edge_refinement``).

Photos and metrics:

* ``apriltag_photos/`` (3 photos, 799x533, 36h11 tags of 13-45 px on cubes, no intrinsics):
  tags found at full resolution, the square fit (the RMS px of the 4 corners around the
  square pose that fits them best, ``cv2.SOLVEPNP_IPPE_SQUARE``; the pinhole's focal length
  is taken as the image width and its centre as the principal point: the photos come without
  intrinsics, and for tags this small the fit hardly depends on them), and the median
  distance to the library's own corners of its regression test (``quad_decimate`` 1,
  ``refine_edges`` off) and to the library's corners.
* ``opencv_aruco_tutorial/`` ChArUco photos (640x480, ``DICT_6X6_250``, 5x7 squares of 40 mm
  with markers of 20 mm, the calibrated camera ``tutorial_camera_charuco.yml``): the square
  fit with the calibrated camera; the reprojection RMS of one PnP on all the board's marker
  corners (its layout is known); and that pose against the pose of the board's chessboard
  corners (ChArUco interpolation and ``cornerSubPix`` on the saddle points, which the marker
  corners do not enter): rotation (deg) and position (mm) apart.

Small tags (``--small``): the tags of the ``apriltag_photos`` found by the library at full
resolution, by the detector's default decimation, and by the detector with ``small_tags`` (a
coarser pass and the small-tag look), with the detection time of each (thread CPU, one
thread, interleaved photo by photo, the median of ``--repeats`` rounds) as a ratio to the
default decimation's.

    python -m benchmarks.bench_real_markers [--data DIR] [--small] [--repeats 7] [--camera hd]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from rs_localizer import cv_compat
from rs_localizer.frontends.marker_detection import (
    APRILTAG_PIXEL_OFFSET,
    APRILTAG_TO_ARUCO_ORDER,
    AprilTagDetector,
    DetectorOptions,
    apriltag_binding,
    refine_corners,
    refine_tag_edges,
)

__all__ = [
    "DATA",
    "apriltag_photos",
    "charuco_photos",
    "corner_methods",
    "main",
    "read_expected",
    "small_tags",
    "square_fit_rms",
]

#: the real photos (README there: sources, licences, formats): ``shared/data/real_markers``
#: beside the checkout (or beside the folder of worktrees the checkout is in)
DATA = next(
    (
        p
        for p in (
            Path(__file__).resolve().parents[k] / ".." / "shared" / "data" / "real_markers"
            for k in (1, 2)
        )
        if p.is_dir()
    ),
    Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real_markers",
)

#: black square of a 36h11 tag / a 6x6 ArUco marker, in cells
CELLS = 8

#: the ChArUco photos of ``opencv_aruco_tutorial`` and their board
CHARUCO_PHOTOS = (
    "choriginal.jpg",
    "chocclusion_original.jpg",
    "img_00.jpg",
    "img_02.jpg",
    "img_03.jpg",
)
CHARUCO_BOARD = dict(cols=5, rows=7, square_length=0.04, marker_length=0.02)


def read_expected(path: Path) -> np.ndarray:
    """The AprilTag library's corners of its regression test (``id, (x y), ...`` per line):
    (M, 4, 2) px in ArUco order and OpenCV's pixel convention."""
    rows = []
    for line in path.read_text().splitlines():
        v = line.replace("(", " ").replace(")", " ").replace(",", " ").split()
        if len(v) == 9:
            rows.append(np.array(v[1:], float).reshape(4, 2))
    c = np.array(rows).reshape(-1, 4, 2)
    return c[:, APRILTAG_TO_ARUCO_ORDER, :] - APRILTAG_PIXEL_OFFSET


def corner_methods(gray: np.ndarray, library: np.ndarray, default=None) -> dict:
    """name -> (M, 4, 2) corners of the methods (module notes) from ``library`` corners;
    ``default``: the detector's default corners (None: not listed)."""
    out = {
        "library": library,
        "edge profile": refine_tag_edges(gray, library, CELLS),
        "cornerSubPix": refine_corners(gray, library, CELLS),
    }
    if default is not None:
        out["default"] = default
    return out


def square_fit_rms(corners: np.ndarray, K: np.ndarray, D=None) -> np.ndarray:
    """Per marker (M,) the RMS px of its 4 corners (ArUco order) around the square's pose that
    fits them best (``SOLVEPNP_IPPE_SQUARE``, then reprojected with ``K``, ``D``)."""
    s = 0.5
    obj = np.array([[-s, s, 0], [s, s, 0], [s, -s, 0], [-s, -s, 0]], np.float64)
    D = np.zeros(5) if D is None else np.asarray(D, float)
    out = []
    for c in np.asarray(corners, float):
        ok, rv, tv = cv2.solvePnP(obj, c, K, D, flags=cv2.SOLVEPNP_IPPE_SQUARE)
        if not ok:
            out.append(np.nan)
            continue
        p, _ = cv2.projectPoints(obj, rv, tv, K, D)
        out.append(float(np.sqrt(np.mean(np.sum((p.reshape(4, 2) - c) ** 2, axis=1)))))
    return np.array(out)


def _match(found: np.ndarray, ref: np.ndarray, tol: float = 3.0) -> np.ndarray:
    """For each ``ref`` tag the index of the ``found`` tag with its centre within ``tol`` px
    (-1: none)."""
    if len(found) == 0:
        return np.full(len(ref), -1)
    d = np.linalg.norm(ref.mean(1)[:, None] - found.mean(1)[None], axis=2)
    j = d.argmin(axis=1)
    return np.where(d[np.arange(len(ref)), j] < tol, j, -1)


def _library_corners(det: AprilTagDetector, gray: np.ndarray) -> np.ndarray:
    """The library's kept detections of ``gray`` (every tag of these photos is id 0: repeated
    ids are kept) in ArUco order and OpenCV's pixel convention."""
    c, _, ham, mar = det.raw(gray)
    keep = (ham <= det.options.max_hamming) & (mar >= det.min_decision_margin)
    return c[keep][:, APRILTAG_TO_ARUCO_ORDER, :] - APRILTAG_PIXEL_OFFSET


def apriltag_photos(data: Path) -> dict:
    """The corner methods on ``apriltag_photos`` at full resolution, on the tags the library
    finds there that its regression test has: ``{"methods": {method: {"fit" (N,) px square
    fit, "agree" (4 N,) px corner distance to the regression test's corners, "lib" (4 N,) px
    to the library's corners, "tags" int}}, "expected": tags in the regression test}``."""
    folder = data / "apriltag_photos"
    full = AprilTagDetector(
        "tag36h11", DetectorOptions(nthreads=1, quad_decimate=1), edge_refinement=False
    )
    default = AprilTagDetector("tag36h11", DetectorOptions(nthreads=1, quad_decimate=1))
    res: dict = {}
    n_exp = 0
    for img in sorted(folder.glob("*.jpg")):
        gray = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE)
        exp = read_expected(img.with_suffix(".txt"))
        n_exp += len(exp)
        h, w = gray.shape
        K = np.array([[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1]], float)
        lib = _library_corners(full, gray)
        ref = _match(lib, exp)
        lib_m, exp_m = lib[ref[ref >= 0]], exp[ref >= 0]
        dflt = default_corners(default, gray, lib_m)
        methods = {"regression test's": exp_m, **corner_methods(gray, lib_m, dflt)}
        for name, c in methods.items():
            o = res.setdefault(name, {"fit": [], "agree": [], "lib": [], "tags": 0})
            o["fit"].extend(square_fit_rms(c, K).tolist())
            o["agree"].extend(np.linalg.norm(c - exp_m, axis=2).ravel().tolist())
            o["lib"].extend(np.linalg.norm(c - lib_m, axis=2).ravel().tolist())
            o["tags"] += len(c)
    out = {
        n: {k: np.asarray(v) if k != "tags" else v for k, v in o.items()} for n, o in res.items()
    }
    return {"methods": out, "expected": n_exp}


def default_corners(det: AprilTagDetector, gray: np.ndarray, like: np.ndarray) -> np.ndarray:
    """The default detector's corners of the tags ``like`` (matched by centre; a tag it
    misses keeps NaN)."""
    mine = _default_detect(det, gray)
    j = _match(mine, like)
    out = np.full_like(like, np.nan)
    out[j >= 0] = mine[j[j >= 0]]
    return out


def _default_detect(det: AprilTagDetector, gray: np.ndarray) -> np.ndarray:
    """``det``'s corners of ``gray`` with repeated ids kept (these photos' tags are all id 0:
    ``detect`` would drop them): the library's, refined when ``det`` refines them."""
    lib = _library_corners(det, gray)
    if det.edge_cells is None or len(lib) == 0:
        return lib
    return refine_tag_edges(gray, lib, det.edge_cells)


def _camera(path: Path) -> tuple[np.ndarray, np.ndarray]:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    D = fs.getNode("distortion_coefficients").mat().ravel()
    fs.release()
    return K, D


def _rotation_deg(r1: np.ndarray, r2: np.ndarray) -> float:
    R1, _ = cv2.Rodrigues(r1)
    R2, _ = cv2.Rodrigues(r2)
    c = (np.trace(R1.T @ R2) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


def charuco_photos(data: Path) -> dict:
    """The corner methods on the ChArUco photos (module notes): {method: {"fit" (N,) px,
    "ref" (4 N,) px from the corners the chessboard corners' pose projects,
    "rms" (P,) px board PnP, "rot" (P,) deg, "pos" (P,) mm}}, P photos."""
    folder = data / "opencv_aruco_tutorial"
    K, D = _camera(folder / "tutorial_camera_charuco.yml")
    dictionary = cv_compat.get_dictionary("DICT_6X6_250")
    b = CHARUCO_BOARD
    board = cv_compat.charuco_board(
        b["cols"], b["rows"], b["square_length"], b["marker_length"], dictionary
    )
    obj = dict(
        zip(cv_compat.board_ids(board).tolist(), cv_compat.board_object_points(board), strict=True)
    )
    chess = cv_compat.charuco_chessboard_corners(board)
    params = cv_compat.detector_parameters(cornerRefinementMethod=cv2.aruco.CORNER_REFINE_APRILTAG)
    markers = cv_compat.MarkerDetector(dictionary, params)
    charuco = cv_compat.CharucoCornerDetector(board)
    res: dict = {}
    for name in CHARUCO_PHOTOS:
        gray = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        corners, ids, _ = markers.detect(gray)
        keep = np.isin(ids, list(obj))
        # (OpenCV's port keeps the library's pixel convention, half a pixel off OpenCV's)
        corners = corners[keep].astype(np.float64) - APRILTAG_PIXEL_OFFSET
        ids = ids[keep]
        cc, cids, _, _ = charuco.detect(gray, K, D)
        _, r_ref, t_ref = cv2.solvePnP(chess[cids], cc.reshape(-1, 1, 2), K, D)
        X = np.concatenate([obj[int(i)] for i in ids])
        ref = cv2.projectPoints(X, r_ref, t_ref, K, D)[0].reshape(-1, 2)
        for method, c in corner_methods(gray, corners).items():
            o = res.setdefault(method, {"fit": [], "ref": [], "rms": [], "rot": [], "pos": []})
            o["fit"].extend(square_fit_rms(c, K, D).tolist())
            o["ref"].extend(np.linalg.norm(c.reshape(-1, 2) - ref, axis=1).tolist())
            uv = c.reshape(-1, 1, 2)
            _, rv, tv = cv2.solvePnP(X, uv, K, D)
            p, _ = cv2.projectPoints(X, rv, tv, K, D)
            o["rms"].append(float(np.sqrt(np.mean(np.sum((p - uv) ** 2, axis=2)))))
            o["rot"].append(_rotation_deg(rv, r_ref))
            # camera centres apart
            R, _ = cv2.Rodrigues(rv)
            R0, _ = cv2.Rodrigues(r_ref)
            d = (-R.T @ tv) - (-R0.T @ t_ref)
            o["pos"].append(float(np.linalg.norm(d)) * 1e3)
    return {n: {k: np.asarray(v) for k, v in o.items()} for n, o in res.items()}


def _stats(v: np.ndarray) -> str:
    v = v[np.isfinite(v)]
    if not len(v):
        return "-"
    return f"{np.median(v):.3f} / {np.percentile(v, 90):.3f}"


def print_apriltag(r: dict) -> None:
    print(
        f"\napriltag_photos: 36h11 tags at full resolution ({r['expected']} in the library's "
        "regression test); square fit with f = image width"
    )
    print(
        f"{'corners':<20} {'tags':>5} {'square fit px med/p90':>22} "
        f"{'to regression px med/p90':>25} {'to library px med/p90':>22}"
    )
    for name, o in r["methods"].items():
        n = int(np.isfinite(o["fit"]).sum())
        print(
            f"{name:<20} {n:>5} {_stats(o['fit']):>22} {_stats(o['agree']):>25} "
            f"{_stats(o['lib']):>22}"
        )


def print_charuco(r: dict) -> None:
    print(
        "\nopencv_aruco_tutorial ChArUco photos (5, calibrated camera): square fit per marker, "
        "board PnP on all marker corners, its pose against the chessboard corners' pose"
    )
    print(
        f"{'corners':<14} {'markers':>7} {'square fit px med/p90':>22} {'board RMS px':>13} "
        f"{'rot deg':>8} {'pos mm':>7} {'to chessboard pose px med/p90':>30}"
    )
    for name, o in r.items():
        print(
            f"{name:<14} {len(o['fit']):>7} {_stats(o['fit']):>22} {np.mean(o['rms']):>13.3f} "
            f"{np.mean(o['rot']):>8.3f} {np.mean(o['pos']):>7.2f} {_stats(o['ref']):>30}"
        )


def _found(det: AprilTagDetector, gray: np.ndarray) -> np.ndarray:
    """``det``'s kept tags of ``gray`` (repeated ids kept), its small-tag look included,
    in the library's convention."""
    c, _, ham, mar = det.raw_frame(gray)
    return c[(ham <= det.options.max_hamming) & (mar >= det.min_decision_margin)]


#: the renders' camera presets (``--camera``) -> their size
RENDER_SIZES = {"vga": "640x480", "hd": "1280x720"}

#: the detectors of the small-tag table: name -> options
SMALL_ROWS = {
    "full resolution (quad_decimate 1)": DetectorOptions(nthreads=1, quad_decimate=1),
    "quad_decimate 1.5": DetectorOptions(nthreads=1, quad_decimate=1.5),
    "default (by image size)": DetectorOptions(nthreads=1),
    "default + small_tags": DetectorOptions(nthreads=1, small_tags=True),
}


def small_tags(data: Path, repeats: int, render_frames: int = 0, camera: str = "vga") -> dict:
    """Tags found and detection time (``detect``, thread CPU, one thread) of the
    :data:`SMALL_ROWS` detectors, interleaved image by image over ``repeats`` rounds:
    ``{"photos": {name: (found, expected, cpu (R,) s per round)}, "renders": ...}``; renders:
    ``render_frames`` frames of ``bench_markers``' room with its ``camera`` preset (``vga``
    640x480, ``hd`` 1280x720; fully visible tags found)."""
    dets = {n: AprilTagDetector("tag36h11", o) for n, o in SMALL_ROWS.items()}
    photos = []
    for img in sorted((data / "apriltag_photos").glob("*.jpg")):
        gray = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE)
        photos.append((gray, read_expected(img.with_suffix(".txt")) + APRILTAG_PIXEL_OFFSET))
    out = {
        "photos": {},
        "images": {"photos": len(photos), "renders": render_frames},
        "camera": camera,
    }
    for n, det in dets.items():
        found = sum(int((_match(_found(det, g), e) >= 0).sum()) for g, e in photos)
        out["photos"][n] = [found, sum(len(e) for _, e in photos), []]
    frames = []
    if render_frames:
        from .bench_markers import video_truth

        frames = [(g, vis) for g, _, vis in video_truth(camera, render_frames)]
        out["renders"] = {}
        for n, det in dets.items():
            found = sum(len(set(det.detect(g)[1].tolist()) & vis) for g, vis in frames)
            out["renders"][n] = [found, sum(len(v) for _, v in frames), []]
    for _ in range(repeats):
        for key, images in (
            ("photos", [g for g, _ in photos]),
            ("renders", [g for g, _ in frames]),
        ):
            if key not in out:
                continue
            cpu = dict.fromkeys(dets, 0.0)
            for g in images:
                for n, det in dets.items():
                    t0 = time.thread_time()
                    det.detect(g)
                    cpu[n] += time.thread_time() - t0
            for n in dets:
                out[key][n][2].append(cpu[n])
    return out


def print_small(r: dict) -> None:
    ref = "default (by image size)"
    for key, what in (
        (
            "photos",
            "apriltag_photos (799x533, 36h11 tags of 13-45 px; found: of the regression test's)",
        ),
        (
            "renders",
            f"{RENDER_SIZES.get(r.get('camera'), r.get('camera'))} renders of apriltag_room "
            "(found: fully visible tags)",
        ),
    ):
        if key not in r:
            continue
        print(f"\nsmall tags, {what}; CPU: median of the rounds, ratio to the default")
        print(f"{'detector':<36} {'found':>9} {'CPU ms / image':>15} {'ratio':>6}")
        base = np.median(r[key][ref][2])
        for name, (found, total, cpu) in r[key].items():
            per = np.median(cpu) * 1e3 / r["images"][key]
            print(f"{name:<36} {found:>4}/{total:<4} {per:>15.1f} {np.median(cpu) / base:>6.2f}")


def main(argv: list | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DATA, help="the real_markers folder")
    ap.add_argument("--small", action="store_true", help="also the small tags' recall and time")
    ap.add_argument("--repeats", type=int, default=7, help="timing rounds (--small)")
    ap.add_argument(
        "--render-frames", type=int, default=10, help="rendered frames (--small; 0: none)"
    )
    ap.add_argument(
        "--camera",
        choices=sorted(RENDER_SIZES),
        default="vga",
        help="the renders' camera (--small)",
    )
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    if not a.data.is_dir():
        print(f"no real photos at {a.data}")
        return 1
    if apriltag_binding() is None:
        print("no AprilTag binding installed")
        return 1
    print_apriltag(apriltag_photos(a.data))
    print_charuco(charuco_photos(a.data))
    if a.small:
        print_small(small_tags(a.data, a.repeats, a.render_frames, a.camera))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
