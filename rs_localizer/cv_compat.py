"""One ``cv2.aruco`` API for OpenCV 4.6 and OpenCV >= 4.7 (4.x and 5.x).

OpenCV 4.7 moved ArUco from contrib to the main modules and replaced the functional API
(``cv2.aruco.detectMarkers``, ``interpolateCornersCharuco``, ``CharucoBoard_create``,
``DetectorParameters_create``, ``board.draw``, ``drawMarker``) by detector objects
(``ArucoDetector``, ``CharucoDetector``) and constructors (``CharucoBoard(...)``,
``GridBoard(...)``, ``Board(...)``, ``generateImage``, ``generateImageMarker``). Debian 12 and
Ubuntu 24.04 ship OpenCV 4.6 (``python3-opencv``, contrib included); pip wheels are 4.7+.
Each helper here uses the new API when ``cv2.aruco`` has it and the 4.6 API otherwise.

Known 4.6 differences handled here:

* ``cv2.aruco.DetectorParameters()`` constructs an object on 4.6.0 whose first attribute
  access crashes the interpreter (segfault, checked with opencv-contrib-python-headless
  4.6.0.66); only ``DetectorParameters_create()`` is safe there. :func:`detector_parameters`
  picks the right one.
* ChArUco boards with an even number of rows changed their layout in OpenCV 4.6.0; 4.6 cannot
  make the old ("legacy") layout, 4.8+ can (``setLegacyPattern``). :func:`charuco_board`
  raises ValueError for ``legacy_pattern=True`` where it is unavailable.
* ``relativeCornerRefinmentWinSize`` (sic) exists only from 4.9: set when present.
* ChArUco corners come out shifted by about +0.5 px in x and y from OpenCV 4.5.4 (contrib PR
  3024 shifts the points by half a pixel around ``cornerSubPix``) until the fix of
  opencv/opencv#25539 (opencv/opencv#28380, January 2026; the 5.0.0 wheel has no offset). On a
  rendered board 4.6.0's corners are off by (+0.50, +0.50) px on average, up to 0.77 px.
  :class:`CharucoCornerDetector` therefore refines OpenCV's corners once more with
  ``cv2.cornerSubPix`` (which converges to the saddle point from any nearby start), so all
  versions give the same corners (< 0.1 px from the truth on the same render).

The board coordinate frames agree between 4.6 and 5.x (origin at the top-left corner of the
board image, x to the right, y down, z into the board); checked in
``test/frontends/test_boards.py``.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

__all__ = [
    "NEW_ARUCO_API",
    "CharucoCornerDetector",
    "MarkerDetector",
    "board",
    "board_ids",
    "board_image",
    "board_object_points",
    "charuco_board",
    "charuco_chessboard_corners",
    "custom_dictionary",
    "detector_parameters",
    "get_dictionary",
    "grid_board",
    "has_aruco",
    "is_dictionary_file",
    "marker_image",
    "read_dictionary",
]

#: True when cv2.aruco has the detector objects of OpenCV >= 4.7
NEW_ARUCO_API = hasattr(getattr(cv2, "aruco", None), "ArucoDetector")


def has_aruco() -> bool:
    """Whether this OpenCV build has the ArUco module (4.6: contrib builds only)."""
    return hasattr(cv2, "aruco")


def _require_aruco():
    if not has_aruco():
        raise ImportError(
            f"OpenCV {cv2.__version__} has no cv2.aruco (install "
            "opencv-contrib-python(-headless) for OpenCV < 4.7)"
        )


#: file name endings of a custom dictionary (OpenCV's dictionary YAML)
DICTIONARY_FILE_SUFFIXES = (".yml", ".yaml")


def is_dictionary_file(name: Any) -> bool:
    """Whether ``name`` names a custom dictionary file (ends with ``.yml`` or ``.yaml``)."""
    return isinstance(name, str) and name.lower().endswith(DICTIONARY_FILE_SUFFIXES)


def get_dictionary(name: str) -> Any:
    """Predefined dictionary by name (``DICT_4X4_50`` ... ``DICT_APRILTAG_36h11``), or a
    custom dictionary from OpenCV's dictionary YAML (a path ending ``.yml``/``.yaml``:
    :func:`read_dictionary`).

    Raises:
        ValueError: unknown name; a dictionary file that is not one. OSError: a file that
        cannot be read.
    """
    _require_aruco()
    if is_dictionary_file(name):
        return read_dictionary(name)
    if not isinstance(name, str) or not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        raise ValueError(f"unknown ArUco dictionary {name!r}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def read_dictionary(path: Any) -> Any:
    """A custom dictionary from OpenCV's dictionary YAML, the file
    ``cv2.aruco.Dictionary.readDictionary`` reads and ``writeDictionary`` writes:
    ``nmarkers``, ``markersize`` (bits per side, without the black border), optionally
    ``maxCorrectionBits`` (default 0) and ``marker_0`` ... ``marker_{nmarkers-1}``, each a
    string of ``markersize**2`` ``0``/``1`` characters, row by row from the marker's top-left.

    Raises:
        FileNotFoundError: no such file. ValueError (naming the file and the entry): a
        missing or malformed entry.
    """
    from pathlib import Path

    _require_aruco()
    p = Path(str(path))
    if not p.is_file():
        raise FileNotFoundError(f"no dictionary file {p}")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except cv2.error:
        raise ValueError(f"{p}: not an OpenCV YAML dictionary file") from None
    try:
        root = fs.root()

        def integer(key: str, default: int | None = None) -> int:
            node = root.getNode(key)
            if node.empty():
                if default is None:
                    raise ValueError(f"{p}: no '{key}' (an OpenCV dictionary YAML needs it)")
                return default
            v = node.real()
            if not (node.isInt() or node.isReal()) or v != int(v) or v < 0:
                raise ValueError(f"{p}: '{key}' must be an integer >= 0")
            return int(v)

        n, size = integer("nmarkers"), integer("markersize")
        correction = integer("maxCorrectionBits", 0)
        if n < 1 or size < 1:
            raise ValueError(f"{p}: nmarkers and markersize must be >= 1")
        bits = np.zeros((n, size, size), np.uint8)
        for k in range(n):
            text = root.getNode(f"marker_{k}").string()
            if len(text) != size * size or set(text) - {"0", "1"}:
                raise ValueError(
                    f"{p}: marker_{k} must be {size * size} characters 0/1, got {text!r}"
                )
            bits[k] = np.frombuffer(text.encode(), np.uint8).reshape(size, size) - ord("0")
    finally:
        fs.release()
    return custom_dictionary(bits, correction)


def custom_dictionary(bits: np.ndarray, max_correction_bits: int = 0) -> Any:
    """Dictionary from marker bit patterns.

    Args:
        bits: (M, n, n) array of 0/1, marker ``i`` row-major without the black border.
        max_correction_bits: erroneous bits the detector may correct (0: exact codes only;
            OpenCV's ``readDictionary`` default).
    Raises:
        ValueError: bits not (M, n, n) with 0/1 entries.
    """
    _require_aruco()
    b = np.asarray(bits)
    if b.ndim != 3 or b.shape[1] != b.shape[2] or b.shape[0] == 0 or not np.isin(b, (0, 1)).all():
        raise ValueError(f"marker bits must be (M, n, n) of 0/1, got shape {b.shape}")
    n = int(b.shape[1])
    get_bytes = (
        getattr(cv2.aruco, "Dictionary_getByteListFromBits", None)
        or cv2.aruco.Dictionary.getByteListFromBits
    )
    byte_list = np.concatenate([get_bytes(m.astype(np.uint8)) for m in b])
    if NEW_ARUCO_API:
        return cv2.aruco.Dictionary(byte_list, n, int(max_correction_bits))
    # 4.6: no public constructor; the fields are read-write properties
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    d.bytesList = byte_list
    d.markerSize = n
    d.maxCorrectionBits = int(max_correction_bits)
    return d


def detector_parameters(**overrides: Any) -> Any:
    """``cv2.aruco.DetectorParameters`` with OpenCV defaults, then ``overrides`` set by
    attribute name. Names this OpenCV lacks are skipped (e.g.
    ``relativeCornerRefinmentWinSize`` before 4.9)."""
    _require_aruco()
    p = cv2.aruco.DetectorParameters() if NEW_ARUCO_API else cv2.aruco.DetectorParameters_create()
    for k, v in overrides.items():
        if hasattr(p, k):
            setattr(p, k, v)
    return p


class MarkerDetector:
    """Square-marker detection with one call on every OpenCV version.

    ``detect(gray) -> (corners (M, 4, 2) float64 pixels, ids (M,) int64, rejected count)``;
    corners in ArUco order (top-left, top-right, bottom-right, bottom-left of the printed
    marker).
    """

    def __init__(self, dictionary: Any, params: Any = None):
        self.dictionary = dictionary
        self.params = params if params is not None else detector_parameters()
        self._det = cv2.aruco.ArucoDetector(dictionary, self.params) if NEW_ARUCO_API else None

    def detect(self, gray: np.ndarray) -> tuple[Any, Any]:
        if self._det is not None:
            corners, ids, rejected = self._det.detectMarkers(gray)
        else:
            corners, ids, rejected = cv2.aruco.detectMarkers(
                gray, self.dictionary, parameters=self.params
            )
        n_rej = 0 if rejected is None else len(rejected)
        if ids is None or len(ids) == 0:
            return np.zeros((0, 4, 2)), np.zeros(0, np.int64), n_rej
        return (
            np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2),
            np.asarray(ids, dtype=np.int64).ravel(),
            n_rej,
        )


def grid_board(
    cols: int,
    rows: int,
    marker_length: float,
    separation: float,
    dictionary: Any,
    ids: np.ndarray | None = None,
) -> Any:
    """``cv2.aruco.GridBoard``: ``cols`` x ``rows`` markers of side ``marker_length`` with
    ``separation`` between them; ``ids`` (cols*rows,) row-major, default ``0..``."""
    _require_aruco()
    ids = None if ids is None else np.asarray(ids, dtype=np.int32).ravel()
    if NEW_ARUCO_API:
        if ids is None:
            return cv2.aruco.GridBoard(
                (int(cols), int(rows)), float(marker_length), float(separation), dictionary
            )
        return cv2.aruco.GridBoard(
            (int(cols), int(rows)), float(marker_length), float(separation), dictionary, ids
        )
    b = cv2.aruco.GridBoard_create(
        int(cols), int(rows), float(marker_length), float(separation), dictionary
    )
    if ids is not None:
        b.setIds(ids)
    return b


def charuco_board(
    cols: int,
    rows: int,
    square_length: float,
    marker_length: float,
    dictionary: Any,
    ids: np.ndarray | None = None,
    legacy_pattern: bool = False,
) -> Any:
    """``cv2.aruco.CharucoBoard`` of ``cols`` x ``rows`` squares.

    Raises:
        ValueError: ``legacy_pattern=True`` on an OpenCV without ``setLegacyPattern`` (< 4.8).
    """
    _require_aruco()
    ids = None if ids is None else np.asarray(ids, dtype=np.int32).ravel()
    if NEW_ARUCO_API:
        args = ((int(cols), int(rows)), float(square_length), float(marker_length), dictionary)
        b = cv2.aruco.CharucoBoard(*args) if ids is None else cv2.aruco.CharucoBoard(*args, ids)
    else:
        b = cv2.aruco.CharucoBoard_create(
            int(cols), int(rows), float(square_length), float(marker_length), dictionary
        )
        if ids is not None:
            b.setIds(ids)
    if legacy_pattern:
        if not hasattr(b, "setLegacyPattern"):
            raise ValueError(
                f"OpenCV {cv2.__version__} cannot make the legacy (pre-4.6) "
                "ChArUco layout; it needs OpenCV >= 4.8"
            )
        b.setLegacyPattern(True)
    return b


def board(obj_points: list[np.ndarray], dictionary: Any, ids: np.ndarray) -> Any:
    """``cv2.aruco.Board`` from per-marker (4, 3) corners (float32) and ids."""
    _require_aruco()
    pts = [np.asarray(p, dtype=np.float32).reshape(4, 3) for p in obj_points]
    ids = np.asarray(ids, dtype=np.int32).ravel()
    if NEW_ARUCO_API:
        return cv2.aruco.Board(pts, dictionary, ids)
    return cv2.aruco.Board_create(pts, dictionary, ids)


def charuco_chessboard_corners(b: Any) -> np.ndarray:
    """(K, 3) chessboard corners of a ChArUco board in its frame (charuco id = row index)."""
    c = b.getChessboardCorners() if hasattr(b, "getChessboardCorners") else b.chessboardCorners
    return np.asarray(c, dtype=np.float64).reshape(-1, 3)


def board_ids(b: Any) -> np.ndarray:
    """(M,) marker ids of a board."""
    ids = b.getIds() if hasattr(b, "getIds") else b.ids
    return np.asarray(ids, dtype=np.int64).ravel()


def board_object_points(b: Any) -> np.ndarray:
    """(M, 4, 3) marker corners of a board in its frame."""
    op = b.getObjPoints() if hasattr(b, "getObjPoints") else b.objPoints
    return np.asarray(op, dtype=np.float64).reshape(-1, 4, 3)


class CharucoCornerDetector:
    """ChArUco corners of one board: markers, then corners interpolated between them.

    Args:
        board: a ChArUco board (:func:`charuco_board`).
        params: ArUco detector parameters (:func:`detector_parameters`).
        min_markers: a corner needs this many adjacent markers (1 or 2; OpenCV default 2).
        refine_markers: also look for board markers missed by the first pass
            (``refineDetectedMarkers`` with the board layout).
        corner_window: largest half size (px) of the final ``cornerSubPix`` on every corner
            (the half-pixel bias workaround, module notes); per corner half its distance to the
            nearest marker corner, so no marker enters the window (at least 2). 0 disables it.

    ``detect(gray, K=None, D=None) -> (corners (N, 2), charuco ids (N,), marker corners
    (M, 4, 2), marker ids (M,))``. With ``K``/``D`` OpenCV interpolates the corners through an
    approximate board pose (better under lens distortion), else through a local homography of
    each marker; both then refine every corner with ``cornerSubPix``.
    """

    def __init__(
        self,
        board: Any,
        params: Any = None,
        min_markers: int = 2,
        refine_markers: bool = True,
        corner_window: int = 12,
    ):
        self.board = board
        self.params = params if params is not None else detector_parameters()
        self.min_markers = int(min_markers)
        self.refine_markers = bool(refine_markers)
        self.corner_window = int(corner_window)
        self._det = {}

    def _detector(self, K, D):
        key = (
            None
            if K is None
            else (
                np.asarray(K, float).tobytes(),
                np.asarray(D if D is not None else [], float).tobytes(),
            )
        )
        det = self._det.get(key)
        if det is None:
            cp = cv2.aruco.CharucoParameters()
            cp.minMarkers = self.min_markers
            cp.tryRefineMarkers = self.refine_markers
            if K is not None:
                cp.cameraMatrix = np.asarray(K, dtype=np.float64)
                cp.distCoeffs = np.asarray(D if D is not None else np.zeros(5), dtype=np.float64)
            det = cv2.aruco.CharucoDetector(self.board, cp, self.params)
            if len(self._det) > 8:
                self._det.clear()
            self._det[key] = det
        return det

    def detect(
        self, gray: np.ndarray, K: np.ndarray | None = None, D: np.ndarray | None = None
    ) -> tuple[Any, Any]:
        empty2 = np.zeros((0, 2))
        if NEW_ARUCO_API:
            cc, cids, mc, mids = self._detector(K, D).detectBoard(gray)
        else:
            dictionary = self.board.dictionary
            mc, mids, rejected = cv2.aruco.detectMarkers(gray, dictionary, parameters=self.params)
            if self.refine_markers and mids is not None and len(mids):
                kw = (
                    {}
                    if K is None
                    else dict(
                        cameraMatrix=np.asarray(K, float),
                        distCoeffs=np.asarray(D if D is not None else np.zeros(5), float),
                    )
                )
                mc, mids, rejected, _ = cv2.aruco.refineDetectedMarkers(
                    gray, self.board, mc, mids, rejected, parameters=self.params, **kw
                )
            cc = cids = None
            if mids is not None and len(mids):
                kw = (
                    {}
                    if K is None
                    else dict(
                        cameraMatrix=np.asarray(K, float),
                        distCoeffs=np.asarray(D if D is not None else np.zeros(5), float),
                    )
                )
                _n, cc, cids = cv2.aruco.interpolateCornersCharuco(
                    mc, mids, gray, self.board, minMarkers=self.min_markers, **kw
                )
        if mids is None or len(mids) == 0:
            mc_out, mids_out = np.zeros((0, 4, 2)), np.zeros(0, np.int64)
        else:
            mc_out = np.asarray(mc, dtype=np.float64).reshape(-1, 4, 2)
            mids_out = np.asarray(mids, dtype=np.int64).ravel()
        if cids is None or len(cids) == 0:
            return empty2, np.zeros(0, np.int64), mc_out, mids_out
        cc = np.asarray(cc, dtype=np.float64).reshape(-1, 2)
        if self.corner_window > 0 and len(mc_out):
            cc = _resubpix(gray, cc, mc_out.reshape(-1, 2), self.corner_window)
        return cc, np.asarray(cids, dtype=np.int64).ravel(), mc_out, mids_out


def _resubpix(gray, corners, marker_corners, max_window: int) -> np.ndarray:
    """``cv2.cornerSubPix`` on chessboard corners (N, 2), the half window of each half its
    distance to the nearest marker corner (that corner stays outside the square window)."""
    d = np.linalg.norm(corners[:, None, :] - marker_corners[None, :, :], axis=2).min(axis=1)
    win = np.clip(np.floor(0.5 * d), 2, max(2, max_window)).astype(int)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
    out = corners.copy()
    for w in np.unique(win):
        sel = win == w
        pts = corners[sel].astype(np.float32).reshape(-1, 1, 2)
        out[sel] = cv2.cornerSubPix(gray, pts, (int(w), int(w)), (-1, -1), crit).reshape(-1, 2)
    return out


def board_image(b: Any, size: tuple[int, int], margin: int = 0, border_bits: int = 1) -> np.ndarray:
    """(H, W) uint8 image of a board (``size`` = (W, H) pixels, ``margin`` white pixels)."""
    size = (int(size[0]), int(size[1]))
    if hasattr(b, "generateImage"):
        return b.generateImage(size, marginSize=int(margin), borderBits=int(border_bits))
    return b.draw(size, marginSize=int(margin), borderBits=int(border_bits))


def marker_image(dictionary: Any, marker_id: int, side: int, border_bits: int = 1) -> np.ndarray:
    """(side, side) uint8 image of one marker (black border included, no quiet zone)."""
    if hasattr(cv2.aruco, "generateImageMarker"):
        return cv2.aruco.generateImageMarker(
            dictionary, int(marker_id), int(side), borderBits=int(border_bits)
        )
    return cv2.aruco.drawMarker(dictionary, int(marker_id), int(side), borderBits=int(border_bits))
