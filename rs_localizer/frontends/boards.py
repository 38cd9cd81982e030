"""Fiducial-board front ends: AprilTag/ArUco tag grids and tag maps, ChArUco boards and plain
checkerboards -> 2D-3D correspondences.

Board models (geometry in the map frame, metres) and the front ends that detect them:

=============================  ==========================  ====================================
model (``type`` in YAML)       front end                   correspondence ids
=============================  ==========================  ====================================
:class:`TagBoard`              :class:`TagFrontend`        ``id_offset + 4 * tag_id + corner``
(``tag_grid``, ``tag_map``)                                (corner 0..3 = TL, TR, BR, BL)
:class:`CharucoBoardModel`     :class:`CharucoFrontend`    ``id_offset + charuco corner id``
(``charuco``)                                              (row-major inner corners)
:class:`CheckerboardModel`     :class:`CheckerboardFrontend`  ``id_offset + row * cols + col``
(``checkerboard``)
=============================  ==========================  ====================================

Every front end has ``process(image, camera=None, encoding="rgb8") -> (points_px (N, 2),
points3d (N, 3), ids (N,) int64)`` like :class:`~rs_localizer.frontends.aruco.ArucoFrontend`:
pixels as measured (distorted), map points in metres, ready for
:func:`rs_localizer.estimate_rs_pose`. :func:`load_board` reads a board from YAML or a dict
(the file format: :mod:`rs_localizer.maps.boards`), :func:`make_board_frontend` builds the
matching front end. Detection goes through :mod:`.cv_compat`, so OpenCV 4.6 (Debian 12,
Ubuntu 24.04) works as well as 4.7+ / 5.x.

**Board frame** (all three kinds, as OpenCV >= 4.6 boards and the AprilTag library's tag
frame): seen from the printed side, x to the right, y down, z = x cross y into the board. The
origin is the top-left corner of the board (tag grid, ChArUco: the outer corner of the first
marker / square) or the first inner corner (checkerboard). ``pose`` (translation + quaternion
or rotation vector) maps the board frame into the map: ``X_map = R X_board + t``.

**Checkerboard orientation.** OpenCV returns the inner corners of a checkerboard in an order
that depends on the view (``findChessboardCornersSB`` and ``findChessboardCorners`` even
disagree by 180 degrees on the same photo). :class:`CheckerboardFrontend` puts them in one
order tied to the board: the grid is made right-handed in the image (a camera in front of the
board sees x to the right of y rotated by +90 degrees), then turned by 180 degrees if needed so
that the outer square at the origin corner is black (equivalently: the square between inner
corners 0, 1, cols and cols + 1 is black). This is unique only for boards with ``cols + rows``
odd (e.g. 9 x 6); others are 180-degree symmetric and rejected.

YAML (all lengths in metres; ``pose`` and ``id_offset`` optional for every type)::

    type: checkerboard        # cols x rows INNER corners (OpenCV patternSize)
    cols: 9
    rows: 6
    square_size: 0.025
    pose: {translation: [0, 0, 0], quaternion: [0, 0, 0, 1]}   # x y z w; or rotvec: [rx, ry, rz]
    id_offset: 0

    type: charuco             # cols x rows SQUARES; first marker in square (1, 0)
    cols: 5
    rows: 7
    square_size: 0.04
    marker_size: 0.02
    dictionary: DICT_6X6_250  # predefined name, or an OpenCV dictionary file (path)
    marker_ids: [...]         # optional, default 0..
    legacy_pattern: false     # pre-4.6 layout of boards with even rows (OpenCV >= 4.8 only)

    type: tag_grid            # cols x rows tags, row-major ids
    dictionary: DICT_APRILTAG_36h11   # the default for tag boards
    cols: 6
    rows: 4
    tag_size: 0.08            # edge of the black square
    tag_spacing: 0.02         # gap between neighbouring tags
    first_id: 0               # or ids: [...]

    type: tag_map             # tags anywhere in the map
    dictionary: DICT_APRILTAG_36h11
    tag_size: 0.16            # default size
    tags:
      - {id: 3, pose: {translation: [1.0, 0, 0.5], rotvec: [0, 0, 0]}}   # tag centre frame
      - {id: 7, size: 0.1, pose: {...}}
      - {id: 9, corners: [[x, y, z], [x, y, z], [x, y, z], [x, y, z]]}  # TL TR BR BL
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np

from ..camera import CameraModel
from ..correspondences import Correspondences, FrontendHooks
from ..maps.boards import BOARD_TYPES, read_board
from . import cv_compat as cvc
from .image import to_gray
from .marker_detection import DetectorOptions, apriltag_family, make_marker_detector

__all__ = [
    "BOARD_TYPES",
    "CharucoBoardModel",
    "CharucoFrontend",
    "CheckerboardFrontend",
    "CheckerboardModel",
    "TagBoard",
    "TagFrontend",
    "board_image",
    "load_board",
    "load_dictionary",
    "make_board_frontend",
    "pose_from_spec",
]


_EMPTY = (np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64))


# ------------------------------------------------------------------------------- geometry
def pose_from_spec(spec: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """Board (or tag) frame -> map frame from a pose spec.

    Args:
        spec: ``None`` (identity) or a dict with ``translation`` (3,) metres and at most one of
            ``quaternion`` (4,) in ROS order ``x y z w`` (normalized here) or ``rotvec`` (3,)
            radians (axis * angle).
    Returns:
        ``(R (3, 3), t (3,))`` with ``X_map = R X_frame + t``.
    Raises:
        ValueError: unknown keys, both rotations, wrong lengths, non-finite values or a zero
            quaternion.
    """
    from scipy.spatial.transform import Rotation

    if spec is None:
        return np.eye(3), np.zeros(3)
    if not isinstance(spec, dict):
        raise ValueError(f"pose must be a mapping, got {type(spec).__name__}")
    unknown = set(spec) - {"translation", "quaternion", "rotvec"}
    if unknown:
        raise ValueError(
            f"unknown pose keys {sorted(unknown)}; expected translation and "
            "quaternion (x y z w) or rotvec"
        )
    if "quaternion" in spec and "rotvec" in spec:
        raise ValueError("give either quaternion or rotvec, not both")
    t = np.asarray(spec.get("translation", [0.0, 0.0, 0.0]), dtype=float)
    if t.shape != (3,) or not np.isfinite(t).all():
        raise ValueError(f"translation must be 3 finite numbers, got {spec.get('translation')}")
    if "quaternion" in spec:
        q = np.asarray(spec["quaternion"], dtype=float)
        if q.shape != (4,) or not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
            raise ValueError(
                f"quaternion must be 4 finite numbers (x y z w), not all zero, got "
                f"{spec['quaternion']}"
            )
        R = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
    elif "rotvec" in spec:
        r = np.asarray(spec["rotvec"], dtype=float)
        if r.shape != (3,) or not np.isfinite(r).all():
            raise ValueError(f"rotvec must be 3 finite numbers, got {spec['rotvec']}")
        R = Rotation.from_rotvec(r).as_matrix()
    else:
        R = np.eye(3)
    return R, t


def load_dictionary(spec: str | dict, base_dir: str | Path | None = None) -> Any:
    """ArUco/AprilTag dictionary from a spec.

    Args:
        spec: a predefined name (``DICT_APRILTAG_36h11``, ``DICT_6X6_250``, ...), a path to an
            OpenCV dictionary file (``nmarkers``, ``markersize``, ``marker_<i>`` bit strings,
            optional ``maxCorrectionBits``: the format of ``Dictionary::writeDictionary``), or a
            dict ``{bits: (M, n, n) 0/1, max_correction_bits: int}``.
        base_dir: directory that relative paths are relative to.
    Raises:
        ValueError: unknown name, unreadable or malformed file.
    """
    if isinstance(spec, dict):
        return cvc.custom_dictionary(spec["bits"], int(spec.get("max_correction_bits", 0)))
    name = str(spec)
    if name.startswith("DICT_"):
        return cvc.get_dictionary(name)
    path = Path(name)
    if base_dir is not None and not path.is_absolute():
        path = Path(base_dir) / path
    if not path.is_file():
        raise ValueError(f"unknown dictionary {spec!r}: neither a DICT_* name nor a file")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        root = fs.root()
        n, size = int(root.getNode("nmarkers").real()), int(root.getNode("markersize").real())
        if n <= 0 or size <= 0:
            raise ValueError(f"{path}: not an OpenCV dictionary (nmarkers/markersize missing)")
        bits = []
        for i in range(n):
            s = root.getNode(f"marker_{i}").string()
            if len(s) != size * size or set(s) - {"0", "1"}:
                raise ValueError(f"{path}: marker_{i} is not {size * size} bits")
            bits.append(np.frombuffer(s.encode(), np.uint8).reshape(size, size) - ord("0"))
        node = root.getNode("maxCorrectionBits")
        mcb = 0 if node.empty() else int(node.real())
    finally:
        fs.release()
    return cvc.custom_dictionary(np.array(bits), mcb)


def _dictionary_size(d) -> int:
    return int(np.asarray(d.bytesList).shape[0])


class _BoardBase:
    """Shared parts: the board -> map pose, ``points`` (N, 3) map, ``ids`` (N,) int64."""

    kind = ""

    def _set_pose(self, pose, id_offset):
        if isinstance(pose, tuple):
            R, t = (
                np.asarray(pose[0], dtype=float).reshape(3, 3),
                np.asarray(pose[1], dtype=float).reshape(3),
            )
            if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                raise ValueError("pose rotation is not a rotation matrix")
        else:
            R, t = pose_from_spec(pose)
        self.rotation, self.translation = R, t
        self.id_offset = int(id_offset)

    def to_map(self, points_board) -> np.ndarray:
        """(N, 3) board-frame points -> map frame."""
        return np.asarray(points_board, dtype=float) @ self.rotation.T + self.translation

    def _finish(self, points_board, local_ids):
        self.points_board = np.asarray(points_board, dtype=float).reshape(-1, 3)
        self.points = self.to_map(self.points_board)
        self.ids = np.asarray(local_ids, dtype=np.int64) + self.id_offset
        self._row = {int(i): k for k, i in enumerate(self.ids)}

    def lookup(self, ids) -> tuple[np.ndarray, np.ndarray]:
        """Rows of ``ids`` in :attr:`points`: ``(rows (K,), found (N,) bool)``."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        rows = np.array([self._row.get(int(i), -1) for i in ids], dtype=np.int64)
        return rows[rows >= 0], rows >= 0

    def __len__(self):
        return len(self.ids)


class CheckerboardModel(_BoardBase):
    """Plain checkerboard of ``cols`` x ``rows`` inner corners (OpenCV ``patternSize``).

    Board frame origin at inner corner 0; corner ``(c, r)`` at ``(c, r, 0) * square_size``
    with id ``id_offset + r * cols + c``; the outer square at the origin corner is black (see
    the module notes for how detections are put in this order).

    Args:
        cols, rows: inner corners along x and y (each >= 2, ``cols + rows`` odd).
        square_size: square edge (m, > 0).
        pose: board -> map: ``None``, a pose spec (:func:`pose_from_spec`) or ``(R, t)``.
        id_offset: added to every id (to keep several boards apart).
    Raises:
        ValueError: bad sizes, or a 180-degree symmetric board (``cols + rows`` even).
    """

    kind = "checkerboard"

    def __init__(
        self,
        cols: int,
        rows: int,
        square_size: float,
        pose: dict | None = None,
        id_offset: int = 0,
    ):
        cols, rows, sq = int(cols), int(rows), float(square_size)
        if cols < 2 or rows < 2 or not np.isfinite(sq) or sq <= 0:
            raise ValueError(
                f"checkerboard needs cols, rows >= 2 and square_size > 0, got "
                f"{cols} x {rows}, {square_size}"
            )
        if (cols + rows) % 2 == 0:
            raise ValueError(
                f"a {cols} x {rows} inner-corner checkerboard looks the same turned "
                "by 180 degrees, so its pose is ambiguous; use cols + rows odd "
                "(e.g. 9 x 6)"
            )
        self.cols, self.rows, self.square_size = cols, rows, sq
        self._set_pose(pose, id_offset)
        r, c = np.mgrid[0:rows, 0:cols]
        P = np.stack([c.ravel() * sq, r.ravel() * sq, np.zeros(cols * rows)], axis=1)
        self._finish(P, np.arange(cols * rows))

    @property
    def pattern_size(self) -> tuple[int, int]:
        return self.cols, self.rows


class CharucoBoardModel(_BoardBase):
    """ChArUco board of ``cols`` x ``rows`` squares (OpenCV ``CharucoBoard``).

    Correspondences are the ``(cols - 1) * (rows - 1)`` inner chessboard corners: charuco id
    ``k`` at ``((k % (cols-1) + 1), (k // (cols-1) + 1), 0) * square_size`` (OpenCV's layout,
    identical in 4.6 and 5.x), id ``id_offset + k``. :attr:`marker_corners` gives the markers'
    corners in the map too.

    Args:
        cols, rows: squares along x and y (each >= 2).
        square_size, marker_size: square and marker edges (m, 0 < marker < square).
        dictionary: dictionary spec (:func:`load_dictionary`) or a cv2 dictionary.
        marker_ids: (cols * rows // 2,) ids of the markers, default ``0..``.
        legacy_pattern: the layout of OpenCV < 4.6 for boards with an even ``rows``.
        pose, id_offset: as :class:`CheckerboardModel`.
        base_dir: directory of a relative dictionary path.
    Raises:
        ValueError: bad sizes, wrong number of / out-of-range marker ids, unknown dictionary,
            ``legacy_pattern`` on OpenCV < 4.8.
    """

    kind = "charuco"

    def __init__(
        self,
        cols: int,
        rows: int,
        square_size: float,
        marker_size: float,
        dictionary: str | dict,
        marker_ids: np.ndarray | None = None,
        legacy_pattern: bool = False,
        pose: dict | None = None,
        id_offset: int = 0,
        base_dir: str | Path | None = None,
    ):
        cols, rows = int(cols), int(rows)
        sq, mk = float(square_size), float(marker_size)
        if cols < 2 or rows < 2 or not (np.isfinite(sq) and np.isfinite(mk)) or not 0 < mk < sq:
            raise ValueError(
                f"charuco needs cols, rows >= 2 and 0 < marker_size < square_size, "
                f"got {cols} x {rows}, {square_size}, {marker_size}"
            )
        self.cols, self.rows, self.square_size, self.marker_size = cols, rows, sq, mk
        self.dictionary = (
            load_dictionary(dictionary, base_dir)
            if isinstance(dictionary, (str, dict, Path))
            else dictionary
        )
        n_markers = cols * rows // 2
        if marker_ids is not None:
            marker_ids = np.asarray(marker_ids, dtype=np.int64).ravel()
            if len(marker_ids) != n_markers or len(np.unique(marker_ids)) != n_markers:
                raise ValueError(
                    f"a {cols} x {rows} charuco board has {n_markers} markers; "
                    f"marker_ids must be {n_markers} distinct ids"
                )
        ids_chk = np.arange(n_markers) if marker_ids is None else marker_ids
        if ids_chk.min() < 0 or ids_chk.max() >= _dictionary_size(self.dictionary):
            raise ValueError(f"marker ids must be in [0, {_dictionary_size(self.dictionary)})")
        self.cv_board = cvc.charuco_board(
            cols, rows, sq, mk, self.dictionary, marker_ids, bool(legacy_pattern)
        )
        self.legacy_pattern = bool(legacy_pattern)
        self.marker_ids = cvc.board_ids(self.cv_board)
        self._set_pose(pose, id_offset)
        r, c = np.mgrid[1:rows, 1:cols]
        P = np.stack([c.ravel() * sq, r.ravel() * sq, np.zeros(c.size)], axis=1)
        self._finish(P, np.arange(c.size))

    @property
    def marker_corners(self) -> dict:
        """{marker id: (4, 3) map corners TL, TR, BR, BL} (from OpenCV's board layout)."""
        op = cvc.board_object_points(self.cv_board)
        return {int(m): self.to_map(c) for m, c in zip(self.marker_ids, op, strict=False)}


class TagBoard(_BoardBase):
    """Square tags (AprilTag 36h11 by default, or any ArUco dictionary) with known corners.

    Build with :meth:`grid` (a printed grid board, OpenCV ``GridBoard`` layout) or
    :meth:`from_tags` (tags placed one by one). Each tag gives 4 correspondences, corner
    ``k`` (0..3 = top-left, top-right, bottom-right, bottom-left of the printed tag, OpenCV's
    order) with id ``id_offset + 4 * tag_id + k``.

    Args:
        corners_board: {tag id: (4, 3) corners in the board frame}.
        dictionary: dictionary spec (:func:`load_dictionary`) or a cv2 dictionary.
        pose, id_offset, base_dir: as :class:`CharucoBoardModel`.
        grid: ``(cols, rows, tag_size, tag_spacing, ids)`` when the tags form a grid board
            (:meth:`grid` sets it; used by :func:`board_image`), else ``None``.
    Raises:
        ValueError: no tags, corners not (4, 3) finite, tag ids outside the dictionary.
    """

    kind = "tags"

    def __init__(
        self,
        corners_board: dict,
        dictionary: str | dict = "DICT_APRILTAG_36h11",
        pose: dict | None = None,
        id_offset: int = 0,
        base_dir: str | Path | None = None,
        grid: tuple | None = None,
    ):
        if not corners_board:
            raise ValueError("a tag board needs at least one tag")
        # a predefined dictionary's name (the marker detector's choice), else None
        self.dictionary_name = (
            dictionary if isinstance(dictionary, str) and dictionary.startswith("DICT_") else None
        )
        self.dictionary = (
            load_dictionary(dictionary, base_dir)
            if isinstance(dictionary, (str, dict, Path))
            else dictionary
        )
        n_dict = _dictionary_size(self.dictionary)
        tags = {}
        for k, v in corners_board.items():
            c = np.asarray(v, dtype=float)
            if c.shape != (4, 3) or not np.isfinite(c).all():
                raise ValueError(f"tag {k}: corners must be (4, 3) finite, got {c.shape}")
            if not 0 <= int(k) < n_dict:
                raise ValueError(f"tag id {k} outside the dictionary (0..{n_dict - 1})")
            tags[int(k)] = c
        self.grid = grid
        self._set_pose(pose, id_offset)
        self.tag_ids = np.array(sorted(tags), dtype=np.int64)
        P = np.concatenate([tags[i] for i in self.tag_ids])
        self._finish(P, (4 * self.tag_ids[:, None] + np.arange(4)).ravel())
        self.tag_corners = {
            int(i): self.points[4 * k : 4 * k + 4] for k, i in enumerate(self.tag_ids)
        }

    @classmethod
    def grid(
        cls,
        cols: int,
        rows: int,
        tag_size: float,
        tag_spacing: float,
        dictionary: str | dict = "DICT_APRILTAG_36h11",
        first_id: int = 0,
        ids: np.ndarray | None = None,
        **kw: Any,
    ) -> TagBoard:
        """``cols`` x ``rows`` tags, row-major from the top-left; tag ``(c, r)`` has its
        top-left corner at ``(c, r, 0) * (tag_size + tag_spacing)``. ``ids`` (cols*rows,)
        or ``first_id + 0..``. Raises ValueError for bad sizes or a wrong number of ids."""
        cols, rows, s, g = int(cols), int(rows), float(tag_size), float(tag_spacing)
        if cols < 1 or rows < 1 or not (np.isfinite(s) and np.isfinite(g)) or s <= 0 or g < 0:
            raise ValueError(
                f"tag grid needs cols, rows >= 1, tag_size > 0, tag_spacing >= 0, "
                f"got {cols} x {rows}, {tag_size}, {tag_spacing}"
            )
        ids = (
            np.arange(cols * rows) + int(first_id)
            if ids is None
            else np.asarray(ids, dtype=np.int64).ravel()
        )
        if len(ids) != cols * rows or len(np.unique(ids)) != len(ids):
            raise ValueError(f"a {cols} x {rows} tag grid needs {cols * rows} distinct ids")
        unit = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float) * s
        corners = {}
        for k, i in enumerate(ids):
            r, c = divmod(k, cols)
            corners[int(i)] = unit + np.array([c, r, 0.0]) * (s + g)
        return cls(corners, dictionary, grid=(cols, rows, s, g, ids), **kw)

    @classmethod
    def from_tags(
        cls,
        tags: list[dict],
        dictionary: str | dict = "DICT_APRILTAG_36h11",
        tag_size: float | None = None,
        **kw: Any,
    ) -> TagBoard:
        """Tags placed one by one. ``tags``: list of dicts with ``id`` and either ``corners``
        (4, 3) or ``pose`` (tag centre frame -> board frame, :func:`pose_from_spec`) plus
        ``size`` (default ``tag_size``). In the tag frame the corners are
        ``(-s/2, -s/2, 0), (s/2, -s/2, 0), (s/2, s/2, 0), (-s/2, s/2, 0)``: x right, y down,
        z into the tag (the AprilTag library's convention; OpenCV's single-marker pose uses
        y up, z out instead). Raises ValueError for duplicate ids or a tag without corners,
        pose or size."""
        corners = {}
        for t in tags:
            if "id" not in t:
                raise ValueError(f"tag without id: {t}")
            i = int(t["id"])
            if i in corners:
                raise ValueError(f"tag id {i} given twice")
            if "corners" in t:
                if "pose" in t:
                    raise ValueError(f"tag {i}: give corners or pose, not both")
                corners[i] = np.asarray(t["corners"], dtype=float)
                continue
            size = t.get("size", tag_size)
            if size is None or not float(size) > 0:
                raise ValueError(f"tag {i} needs a size > 0 (or a default tag_size)")
            h = 0.5 * float(size)
            local = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
            if "pose" not in t:
                raise ValueError(f"tag {i} needs corners or a pose")
            R, tr = pose_from_spec(t["pose"])
            corners[i] = local @ R.T + tr
        return cls(corners, dictionary, **kw)


def load_board(
    source: str | Path | dict, base_dir: str | Path | None = None
) -> CheckerboardModel | CharucoBoardModel | TagBoard:
    """Board model from a YAML file or a dict (format in the module docstring; read and its
    keys checked by :func:`rs_localizer.maps.boards.read_board`).

    Args:
        source: path to a YAML file, or a dict with ``type`` in :data:`BOARD_TYPES`.
        base_dir: directory for relative dictionary paths (default: the YAML's directory).
    Returns:
        :class:`CheckerboardModel`, :class:`CharucoBoardModel` or :class:`TagBoard`.
    Raises:
        ValueError: unknown type, missing or unknown keys, invalid values.
        FileNotFoundError: no such file.
    """
    spec = read_board(source, base_dir)
    a, common = spec.args, dict(pose=spec.pose, id_offset=spec.id_offset)
    if spec.kind == "checkerboard":
        return CheckerboardModel(**a, **common)
    if spec.kind == "charuco":
        return CharucoBoardModel(**a, base_dir=spec.base_dir, **common)
    if spec.kind == "tag_grid":
        return TagBoard.grid(**a, base_dir=spec.base_dir, **common)
    return TagBoard.from_tags(**a, base_dir=spec.base_dir, **common)


def board_image(
    board: CheckerboardModel | CharucoBoardModel | TagBoard,
    pixels_per_metre: float,
    margin_px: int = 0,
) -> np.ndarray:
    """Printable image of a planar board (also the texture of the synthetic tests).

    Args:
        board: :class:`CheckerboardModel` (full outer squares drawn), :class:`CharucoBoardModel`
            or a :class:`TagBoard` made by :meth:`TagBoard.grid`.
        pixels_per_metre: scale; the board's extent times it must be an integer (to 1e-6).
        margin_px: white margin (pixels) around the board.
    Returns:
        ``(image (H, W) uint8, A (3, 3))`` with ``A @ [x, y, 1]`` the pixel (centre convention:
        pixel ``(0, 0)`` covers ``[-0.5, 0.5]^2``) of board-frame point ``(x, y, 0)``.
    Raises:
        ValueError: a tag map (not a grid), or an extent that is not a whole number of pixels.
    """
    ppm, m = float(pixels_per_metre), int(margin_px)

    def whole(x, what):
        v = x * ppm
        if abs(v - round(v)) > 1e-6 or round(v) <= 0:
            raise ValueError(f"{what} of {x} m is {v} px at {ppm} px/m; need a whole number")
        return int(round(v))

    if isinstance(board, CheckerboardModel):
        sq = whole(board.square_size, "square")
        nx, ny = board.cols + 1, board.rows + 1
        cells = ((np.add.outer(np.arange(ny), np.arange(nx)) % 2) * 255).astype(np.uint8)
        img = np.kron(cells, np.ones((sq, sq), np.uint8))
        img = cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
        origin = m - 0.5 + sq  # inner corner 0 is one square in
    elif isinstance(board, CharucoBoardModel):
        w = whole(board.cols * board.square_size, "board width")
        h = whole(board.rows * board.square_size, "board height")
        whole(board.marker_size, "marker")
        img = cvc.board_image(board.cv_board, (w + 2 * m, h + 2 * m), m)
        origin = m - 0.5
    elif isinstance(board, TagBoard) and board.grid is not None:
        cols, rows, s, g, ids = board.grid
        w = whole(cols * s + (cols - 1) * g, "board width")
        h = whole(rows * s + (rows - 1) * g, "board height")
        whole(s, "tag")
        cvb = cvc.grid_board(cols, rows, s, g, board.dictionary, ids)
        img = cvc.board_image(cvb, (w + 2 * m, h + 2 * m), m)
        origin = m - 0.5
    else:
        raise ValueError("board_image needs a checkerboard, a charuco board or a tag grid")
    A = np.array([[ppm, 0, origin], [0, ppm, origin], [0, 0, 1.0]])
    return img, A


# ------------------------------------------------------------------------------- front ends
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
        """From a board YAML (:func:`load_board`). Raises TypeError for another board type."""
        return cls(load_board(path), **kw)

    def _detect_ids(self, gray, camera):
        raise NotImplementedError

    def process(
        self,
        image: np.ndarray,
        camera: CameraModel | None = None,
        encoding: str = "rgb8",
    ) -> Correspondences:
        """Correspondences of one image (:class:`~rs_localizer.correspondences.Correspondences`,
        unpacks as ``(points_px (N, 2) distorted pixels, points3d (N, 3) map metres, ids (N,)
        int64)``; no scores); detections whose id is not on the board are dropped.
        ``camera`` is optional (the ChArUco front end uses it to interpolate corners);
        every image alone."""
        uv, ids = self._detect_ids(to_gray(image, encoding), camera)
        if len(ids) == 0:
            return Correspondences.empty()
        rows, found = self.board.lookup(ids)
        if not found.any():
            return Correspondences.empty()
        return Correspondences(uv[found], self.board.points[rows], ids[found])


class CheckerboardFrontend(_BoardFrontend):
    """Inner corners of a plain checkerboard, in the board's own order (module notes).

    Args:
        board: :class:`CheckerboardModel`.
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
        board: :class:`CharucoBoardModel`.
        min_markers: adjacent markers a corner needs (1 or 2).
        use_camera: pass the camera's intrinsics and distortion (``process(..., camera)``) to
            the corner interpolation (better under distortion); not for ``equidistant``.
        refine_markers: second marker pass using the board layout.
        subpix_window: half size (px) of the marker corner refinement window.
        corner_window: largest half size (px) of the final chessboard-corner
            ``cornerSubPix`` that removes the half-pixel bias OpenCV had from 4.5.4 until
            the fix of opencv/opencv#25539 (4.6 has it, 5.0 not; see :mod:`.cv_compat`); 0
            keeps OpenCV's corners.

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
    """AprilTag (or ArUco) corners of a :class:`TagBoard` (grid board or tag map).

    Args:
        board: :class:`TagBoard`.
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

    Tags whose id is not on the board are ignored (``last_unknown`` counts them).
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


_FRONTENDS = {
    CheckerboardModel: CheckerboardFrontend,
    CharucoBoardModel: CharucoFrontend,
    TagBoard: TagFrontend,
}


def make_board_frontend(
    board: CheckerboardModel | CharucoBoardModel | TagBoard | str | Path | dict, **kw: Any
) -> CheckerboardFrontend | CharucoFrontend | TagFrontend:
    """Front end for a board model, a board YAML path or a board dict (:func:`load_board`);
    ``kw`` go to the front end's constructor."""
    if not isinstance(board, _BoardBase):
        board = load_board(board)
    return _FRONTENDS[type(board)](board, **kw)
