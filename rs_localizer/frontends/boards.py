"""Fiducial-board front ends: AprilTag/ArUco tag grids and tag maps, ChArUco boards and plain
checkerboards -> 2D-3D correspondences.

The boards (their geometry in the map frame, metres, their YAML and the correspondence ids) are
:mod:`rs_localizer.maps.boards`; the front end of each:

========================================  =============================
model (``type`` in YAML)                  front end
========================================  =============================
``TagBoard`` (``tag_grid``, ``tag_map``)  :class:`TagFrontend`
``CharucoBoardModel`` (``charuco``)       :class:`CharucoFrontend`
``CheckerboardModel`` (``checkerboard``)  :class:`CheckerboardFrontend`
========================================  =============================

Every front end has ``process(image, camera=None, encoding="rgb8") -> (points2d (N, 2),
points3d (N, 3), ids (N,) int64)`` like :class:`~rs_localizer.frontends.aruco.ArucoFrontend`:
pixels as measured (distorted), map points in metres, ready for
:func:`rs_localizer.estimate_rs_pose`. :func:`make_board_frontend` builds the front end of a
board model, a board YAML or a dict (:func:`rs_localizer.maps.boards.load_board`). Detection
goes through :mod:`rs_localizer.cv_compat`, so OpenCV 4.6 (Debian 12, Ubuntu 24.04) works as
well as 4.7+ / 5.x.

**Checkerboard orientation.** OpenCV returns the inner corners of a checkerboard in an order
that depends on the view (``findChessboardCornersSB`` and ``findChessboardCorners`` even
disagree by 180 degrees on the same photo). :class:`CheckerboardFrontend` puts them in one
order tied to the board: the grid is made right-handed in the image (a camera in front of the
board sees x to the right of y rotated by +90 degrees), then turned by 180 degrees if needed so
that the outer square at the origin corner is black (equivalently: the square between inner
corners 0, 1, cols and cols + 1 is black). This is unique only for boards with ``cols + rows``
odd (e.g. 9 x 6); others are 180-degree symmetric and rejected.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np

from .. import cv_compat as cvc
from ..camera import CameraModel
from ..correspondences import Correspondences, FrontendHooks
from ..maps.boards import CharucoBoardModel, CheckerboardModel, TagBoard, load_board
from .image import to_gray
from .marker_detection import (
    AprilTagDetector,
    DetectorOptions,
    OpenCVDetector,
    apriltag_family,
    make_marker_detector,
)

__all__ = [
    "CharucoFrontend",
    "CheckerboardFrontend",
    "TagFrontend",
    "make_board_frontend",
]


class _BoardFrontend(FrontendHooks):
    """``process`` shared by the board front ends: detections -> map points by id."""

    name = ""
    board_class = None

    def __init__(self, board):
        if not isinstance(board, self.board_class):
            raise TypeError(
                f"{type(self).__name__} needs a {self.board_class.__name__}, got "
                f"{type(board).__name__}"
            )
        self.board = board
        self.last_rejected = 0
        self.last_scores = None  # no match scores (FeatureFrontend has them)

    @classmethod
    def from_file(cls, path, **kw):
        """From a board YAML (:func:`~rs_localizer.maps.boards.load_board`). Raises TypeError
        for another board type."""
        return cls(load_board(path), **kw)

    def _detect_ids(self, gray, camera):
        raise NotImplementedError

    def _groups(self, ids: np.ndarray) -> np.ndarray | None:
        """(N,) each correspondence's group (:attr:`~rs_localizer.correspondences.
        Correspondences.groups`) of the board's correspondence ``ids`` (N,), or None: each
        corner's image error its own (a chessboard corner is found alone)."""
        return None

    def process(
        self,
        image: np.ndarray,
        camera: CameraModel | None = None,
        encoding: str = "rgb8",
    ) -> Correspondences:
        """Correspondences of one image (:class:`~rs_localizer.correspondences.Correspondences`,
        unpacks as ``(points2d (N, 2) distorted pixels, points3d (N, 3) map metres, ids (N,)
        int64)``; no scores; ``groups`` (N,) a tag board's corners' tag ids, None for the
        chessboard corners of a checkerboard or ChArUco board); detections whose id is not on
        the board are dropped.
        ``camera`` is optional (the ChArUco front end uses it to interpolate corners);
        every image alone."""
        uv, ids = self._detect_ids(to_gray(image, encoding), camera)
        if len(ids) == 0:
            return Correspondences.empty()
        rows, found = self.board.lookup(ids)
        if not found.any():
            return Correspondences.empty()
        ids = ids[found]
        return Correspondences(uv[found], self.board.points[rows], ids, None, self._groups(ids))


class CheckerboardFrontend(_BoardFrontend):
    """Inner corners of a plain checkerboard, in the board's own order (module notes).

    Args:
        board: :class:`~rs_localizer.maps.boards.CheckerboardModel`.
        method: ``classic`` (``cv2.findChessboardCorners`` with fast check +
            ``cv2.cornerSubPix``), ``sb`` (``cv2.findChessboardCornersSB``, sector-based,
            subpixel by itself, more tolerant of blur) or ``auto`` (``classic``, then ``sb`` if
            it finds nothing). On OpenCV's 640 x 480 ``left01.jpg`` classic takes 10-20 ms,
            SB 70-110 ms (one thread, OpenCV 4.6 / 5.0).
        subpix_window: half size (px) of the ``cornerSubPix`` window (``classic``); at most
            0.4 of the smallest corner spacing is used.
        sb_flags: flags of ``findChessboardCornersSB`` (default ``CALIB_CB_NORMALIZE_IMAGE``;
            without it the SB detector misses the board in 2 of OpenCV's 13 ``left*.jpg``).
    Raises:
        ValueError: unknown method.

    The board must be seen whole (OpenCV's detectors find all corners or none).
    """

    name = "checkerboard"
    board_class = CheckerboardModel

    def __init__(
        self,
        board: CheckerboardModel,
        method: str = "auto",
        subpix_window: int = 5,
        sb_flags: int | None = None,
    ):
        super().__init__(board)
        if method not in ("sb", "classic", "auto"):
            raise ValueError(
                f"unknown checkerboard method {method!r}; expected sb, classic or auto"
            )
        self.method = method
        self.subpix_window = int(subpix_window)
        self.sb_flags = cv2.CALIB_CB_NORMALIZE_IMAGE if sb_flags is None else int(sb_flags)
        self.last_method = None

    def _find(self, gray, method):
        size = self.board.pattern_size
        if method == "sb":
            ok, c = cv2.findChessboardCornersSB(gray, size, flags=self.sb_flags)
            return c if ok else None
        flags = (
            cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        )
        ok, c = cv2.findChessboardCorners(gray, size, flags=flags)
        if not ok:
            return None
        grid = c.reshape(size[1], size[0], 2)
        spacing = min(
            np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
            np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
        )
        w = int(max(2, min(self.subpix_window, np.floor(0.4 * spacing))))
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
        return cv2.cornerSubPix(gray, c.astype(np.float32), (w, w), (-1, -1), crit)

    def detect(self, image: np.ndarray, encoding: str = "rgb8") -> tuple[np.ndarray, np.ndarray]:
        """``(corners (cols*rows, 2) pixels, local ids (cols*rows,))`` in the board's order
        (id ``r * cols + c``, no offset), or empty arrays when the board is not found or its
        orientation cannot be told (no contrast between the two square colours)."""
        gray = to_gray(image, encoding)
        methods = ("classic", "sb") if self.method == "auto" else (self.method,)
        self.last_method = None
        for mth in methods:
            c = self._find(gray, mth)
            if c is not None:
                self.last_method = mth
                grid = _canonical_checkerboard(
                    c.reshape(self.board.rows, self.board.cols, 2).astype(np.float64), gray
                )
                if grid is None:
                    break
                return grid.reshape(-1, 2), np.arange(self.board.cols * self.board.rows)
        return np.zeros((0, 2)), np.zeros(0, np.int64)

    def _detect_ids(self, gray, camera):
        uv, local = self.detect(gray)
        return uv, local + self.board.id_offset


def _canonical_checkerboard(grid: np.ndarray, gray: np.ndarray, min_contrast: float = 10.0):
    """(rows, cols, 2) detected corners -> the board's order (module notes), or None when the
    two square colours differ by less than ``min_contrast`` grey levels."""
    # 1. right-handed: the corner polygon TL -> TR -> BR -> BL runs clockwise on screen
    #    (positive shoelace sum with v pointing down)
    quad = np.array([grid[0, 0], grid[0, -1], grid[-1, -1], grid[-1, 0]])
    area = np.sum(quad[:, 0] * np.roll(quad[:, 1], -1) - np.roll(quad[:, 0], -1) * quad[:, 1])
    if area < 0:
        grid = grid[:, ::-1]
    # 2. the square between corners (r, c), (r, c+1), (r+1, c), (r+1, c+1) is black for r + c
    #    even; a 180-degree turn swaps the classes when cols + rows is odd
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1], grid[1:, 1:]
    centre = 0.25 * (a + b + c + d)
    samples = [centre] + [0.5 * (centre + q) for q in (a, b, c, d)]
    pts = np.stack(samples, axis=0).astype(np.float32)  # (5, rows-1, cols-1, 2)
    vals = cv2.remap(
        gray,
        pts[..., 0].reshape(-1, 1),
        pts[..., 1].reshape(-1, 1),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    vals = vals.reshape(pts.shape[:3]).astype(float).mean(axis=0)
    rr, cc = np.mgrid[0 : vals.shape[0], 0 : vals.shape[1]]
    even = (rr + cc) % 2 == 0
    black, white = vals[even].mean(), vals[~even].mean()
    if abs(white - black) < min_contrast:
        return None
    return grid if black < white else grid[::-1, ::-1]


class CharucoFrontend(_BoardFrontend):
    """ChArUco chessboard corners with their ids (OpenCV ``CharucoDetector`` /
    ``interpolateCornersCharuco``).

    Args:
        board: :class:`~rs_localizer.maps.boards.CharucoBoardModel`.
        min_markers: adjacent markers a corner needs (1 or 2).
        use_camera: pass the camera's intrinsics and distortion (``process(..., camera)``) to
            the corner interpolation (better under distortion); not for ``equidistant``.
        refine_markers: second marker pass using the board layout.
        subpix_window: half size (px) of the marker corner refinement window.
        corner_window: largest half size (px) of the final chessboard-corner
            ``cornerSubPix`` that removes the half-pixel bias OpenCV had from 4.5.4 until
            the fix of opencv/opencv#25539 (4.6 has it, 5.0 not; see
            :mod:`rs_localizer.cv_compat`); 0 keeps OpenCV's corners.

    ``last_markers`` holds the marker ids seen in the last image.
    """

    name = "charuco"
    board_class = CharucoBoardModel

    def __init__(
        self,
        board: CharucoBoardModel,
        min_markers: int = 2,
        use_camera: bool = True,
        refine_markers: bool = True,
        subpix_window: int = 3,
        corner_window: int = 12,
    ):
        super().__init__(board)
        params = cvc.detector_parameters(
            cornerRefinementMethod=cv2.aruco.CORNER_REFINE_SUBPIX,
            cornerRefinementWinSize=int(subpix_window),
        )
        self.detector = cvc.CharucoCornerDetector(
            board.cv_board, params, min_markers, refine_markers, corner_window
        )
        self.use_camera = bool(use_camera)
        self.last_markers = np.zeros(0, np.int64)

    def detect(
        self, image: np.ndarray, camera: CameraModel | None = None, encoding: str = "rgb8"
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(corners (N, 2) pixels, charuco ids (N,) without offset)``."""
        K = D = None
        if camera is not None and self.use_camera and camera.distortion_model != "equidistant":
            K, D = camera.K, (camera.D if len(camera.D) else np.zeros(5))
        cc, cids, _, mids = self.detector.detect(to_gray(image, encoding), K, D)
        self.last_markers = mids
        return cc, cids

    def _detect_ids(self, gray, camera):
        uv, ids = self.detect(gray, camera)
        return uv, ids + self.board.id_offset


class TagFrontend(_BoardFrontend):
    """AprilTag (or ArUco) corners of a :class:`~rs_localizer.maps.boards.TagBoard` (grid
    board or tag map).

    Args:
        board: :class:`~rs_localizer.maps.boards.TagBoard`.
        refinement: corner refinement ``subpix`` (default), ``apriltag``, ``contour`` or
            ``none`` (OpenCV ``cornerRefinementMethod``).
        subpix_window: half size (px) of the subpixel window (at most one tag cell is used
            where OpenCV >= 4.9 supports ``relativeCornerRefinmentWinSize``).
        min_marker_perimeter: smallest tag perimeter as a fraction of the image's larger side.
        detector_options: :class:`~rs_localizer.frontends.marker_detection.DetectorOptions`
            of a board of a predefined AprilTag family (``DICT_APRILTAG_36h11``...), detected
            with the AprilTag 3 library when it is installed (the module's notes); the
            arguments above apply to OpenCV's detector (ArUco and custom dictionaries,
            ``detector="opencv"``, or no AprilTag library).
    Raises:
        ValueError: unknown refinement.

    Tags whose id is not on the board are ignored (``last_unknown`` counts them). Each tag's
    4 corners are one group (:attr:`~rs_localizer.correspondences.Correspondences.groups`, the
    tag's id): the detector fits each tag's quad alone, so its corners share a part of their
    image error, whether the tags are printed on one board or placed one by one.
    """

    name = "tags"
    board_class = TagBoard

    _REFINE: ClassVar[dict[str, str]] = {
        "subpix": "CORNER_REFINE_SUBPIX",
        "apriltag": "CORNER_REFINE_APRILTAG",
        "contour": "CORNER_REFINE_CONTOUR",
        "none": "CORNER_REFINE_NONE",
    }

    def __init__(
        self,
        board: TagBoard,
        refinement: str = "subpix",
        subpix_window: int = 3,
        min_marker_perimeter: float = 0.02,
        detector_options: DetectorOptions | None = None,
    ):
        super().__init__(board)
        if refinement not in self._REFINE:
            raise ValueError(f"unknown refinement {refinement!r}; expected {list(self._REFINE)}")
        params = cvc.detector_parameters(
            cornerRefinementMethod=getattr(cv2.aruco, self._REFINE[refinement]),
            cornerRefinementWinSize=int(subpix_window),
            cornerRefinementMaxIterations=50,
            cornerRefinementMinAccuracy=0.01,
            relativeCornerRefinmentWinSize=1.0,
            minMarkerPerimeterRate=float(min_marker_perimeter),
        )
        name = getattr(board, "dictionary_name", None)
        if name is not None and apriltag_family(name) is not None:
            self.detector = make_marker_detector(name, detector_options, params)
        else:
            self.detector = cvc.MarkerDetector(board.dictionary, params)
        self.last_unknown = 0

    def marker_detector_note(self) -> tuple[str, bool] | None:
        """``(the marker detector's line for the log, whether it stands in for a missing
        AprilTag library)`` of an AprilTag family's board; None for one of OpenCV's own
        dictionaries."""
        det = self.detector
        if isinstance(det, (AprilTagDetector, OpenCVDetector)):
            return det.describe(), bool(det.fallback)
        return None

    def detect(self, image: np.ndarray, encoding: str = "rgb8") -> tuple[np.ndarray, np.ndarray]:
        """All tags found: ``(corners (M, 4, 2) pixels, tag ids (M,))``."""
        corners, ids, self.last_rejected = self.detector.detect(to_gray(image, encoding))
        return corners, ids

    def _detect_ids(self, gray, camera):
        corners, tids = self.detect(gray)
        on_board = np.isin(tids, self.board.tag_ids)
        self.last_unknown = int(np.count_nonzero(~on_board))
        corners, tids = corners[on_board], tids[on_board]
        ids = (4 * tids[:, None] + np.arange(4)[None, :]).ravel() + self.board.id_offset
        return corners.reshape(-1, 2), ids

    def _groups(self, ids: np.ndarray) -> np.ndarray:
        """Each corner's tag id (its id is ``id_offset + 4 * tag_id + corner``)."""
        return (np.asarray(ids, np.int64) - self.board.id_offset) // 4


_FRONTENDS = {
    CheckerboardModel: CheckerboardFrontend,
    CharucoBoardModel: CharucoFrontend,
    TagBoard: TagFrontend,
}


def make_board_frontend(
    board: CheckerboardModel | CharucoBoardModel | TagBoard | str | Path | dict, **kw: Any
) -> CheckerboardFrontend | CharucoFrontend | TagFrontend:
    """Front end for a board model, a board YAML path or a board dict
    (:func:`~rs_localizer.maps.boards.load_board`);
    ``kw`` go to the front end's constructor."""
    if not isinstance(board, tuple(_FRONTENDS)):
        board = load_board(board)
    return _FRONTENDS[type(board)](board, **kw)
