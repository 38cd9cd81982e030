"""Board files and board models: the YAML of a fiducial board (``type``: ``checkerboard``,
``charuco``, ``tag_grid`` or ``tag_map``; its geometry in metres, an optional ``pose`` board
frame -> map frame and ``id_offset``) and the board it describes, its points in the map frame.

:func:`read_board` is the one reader: it parses the file (or a dict) and checks the keys of its
type (the required ones present, no unknown ones, defaults filled in); :func:`load_board` builds
the board model from it. The models and their correspondence ids (the detectors that find them
are the front end's, :mod:`rs_localizer.frontends.boards`):

=============================  ======================================================
model (``type`` in YAML)       correspondence ids
=============================  ======================================================
:class:`TagBoard`              ``id_offset + 4 * tag_id + corner``
(``tag_grid``, ``tag_map``)    (corner 0..3 = TL, TR, BR, BL)
:class:`CharucoBoardModel`     ``id_offset + charuco corner id``
(``charuco``)                  (row-major inner corners)
:class:`CheckerboardModel`     ``id_offset + row * cols + col``
(``checkerboard``)
=============================  ======================================================

OpenCV's boards and dictionaries are made through :mod:`rs_localizer.cv_compat`, so OpenCV 4.6
(Debian 12, Ubuntu 24.04) works as well as 4.7+ / 5.x.

**Board frame** (all three kinds, as OpenCV >= 4.6 boards and the AprilTag library's tag
frame): seen from the printed side, x to the right, y down, z = x cross y into the board. The
origin is the top-left corner of the board (tag grid, ChArUco: the outer corner of the first
marker / square) or the first inner corner (checkerboard). ``pose`` (translation + quaternion
or rotation vector) maps the board frame into the map: ``X_map = R X_board + t``.

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

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .. import cv_compat as cvc

__all__ = [
    "BOARD_KEYS",
    "BOARD_TYPES",
    "BoardSpec",
    "CharucoBoardModel",
    "CheckerboardModel",
    "TagBoard",
    "load_board",
    "load_dictionary",
    "pose_from_spec",
    "read_board",
]

#: per value of ``type``: (required keys, {optional key: default}) besides ``pose`` and
#: ``id_offset`` (every type)
BOARD_KEYS = {
    "checkerboard": (("cols", "rows", "square_size"), {}),
    "charuco": (
        ("cols", "rows", "square_size", "marker_size", "dictionary"),
        {"marker_ids": None, "legacy_pattern": False},
    ),
    "tag_grid": (
        ("cols", "rows", "tag_size", "tag_spacing"),
        {"dictionary": "DICT_APRILTAG_36h11", "first_id": 0, "ids": None},
    ),
    "tag_map": (("tags",), {"dictionary": "DICT_APRILTAG_36h11", "tag_size": None}),
}

#: values of ``type`` in a board YAML
BOARD_TYPES = tuple(BOARD_KEYS)


@dataclass
class BoardSpec:
    """A board file as read: ``kind`` (one of :data:`BOARD_TYPES`), ``args`` (the type's keys,
    defaults filled in, values as written), ``pose`` (the pose spec or None), ``id_offset``
    (as written, default 0) and ``base_dir`` (directory for relative dictionary paths, or
    None)."""

    kind: str
    args: dict[str, Any]
    pose: Any
    id_offset: Any
    base_dir: Path | None


def read_board(source: str | Path | dict, base_dir: str | Path | None = None) -> BoardSpec:
    """Read a board YAML file (or a dict of its contents) and check its keys.

    Args:
        source: path to a YAML file, or a dict with ``type`` in :data:`BOARD_TYPES`.
        base_dir: directory for relative dictionary paths (default: the YAML's directory;
            None for a dict).
    Returns:
        :class:`BoardSpec`. The values themselves are checked by the board model built from it.
    Raises:
        ValueError: not a mapping, an unknown type, missing or unknown keys.
        FileNotFoundError: no such file.
    """
    import yaml

    if isinstance(source, dict):
        data = dict(source)
    else:
        path = Path(str(source))
        data = yaml.safe_load(path.read_text())
        if base_dir is None:
            base_dir = path.parent
        if not isinstance(data, dict):
            raise ValueError(f"{path}: a board YAML must be a mapping")
    kind = str(data.pop("type", "")).lower()
    pose, id_offset = data.pop("pose", None), data.pop("id_offset", 0)
    if kind not in BOARD_KEYS:
        raise ValueError(f"unknown board type {kind!r}; expected one of {BOARD_TYPES}")
    required, optional = BOARD_KEYS[kind]
    missing = [k for k in required if k not in data]
    if missing:
        raise ValueError(f"{kind} board needs {missing}")
    args = {k: data.pop(k) for k in required}
    args.update({k: data.pop(k, v) for k, v in optional.items()})
    if data:
        raise ValueError(f"unknown keys for a {kind} board: {sorted(data)}")
    return BoardSpec(kind, args, pose, id_offset, None if base_dir is None else Path(base_dir))


# ------------------------------------------------------------------------------- models
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
    with id ``id_offset + r * cols + c``; the outer square at the origin corner is black (how
    detections are put in this order: :mod:`rs_localizer.frontends.boards`).

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
            (:meth:`grid` sets it; used by :func:`rs_localizer.sim.render.boards.board_image`),
            else ``None``.
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
    keys checked by :func:`read_board`).

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
