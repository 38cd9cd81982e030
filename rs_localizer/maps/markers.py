"""ArUco marker maps: YAML with the ``dictionary`` name and per marker its ``id`` and the four
3D ``corners`` (map frame, metres, in the order the detector returns them: for ArUco
dictionaries the printed marker's top-left, top-right, bottom-right, bottom-left; for AprilTag
families printed from the AprilTag images bottom-right, bottom-left, top-left, top-right, see
``docs/marker_maps.md``, "Corner order"), optionally ``scene`` (the scene
it was rendered from) or, from ``map-markers``, the ``anchor``, the ``frame`` and per marker
``std_position``, ``std_rotation`` and ``observations``.

One writer (:func:`write_marker_map`, for the renderer and ``map-markers`` alike), one reader
(:func:`load_marker_map`, which also reads scene YAMLs and built-in scene names) with its
validation (:func:`check_marker_corners`), and :func:`load_marker_std` for the stated position
std the ArUco front end scores correspondences by.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from .files import write_text_atomic
from .scenes import scene_marker_corners, scene_path

__all__ = [
    "MARKER_SQUARE_TOLERANCE",
    "check_marker_corners",
    "load_marker_map",
    "load_marker_std",
    "marker_dictionary",
    "write_marker_map",
]

#: the first line of every marker map written
MARKER_MAP_HEADER = (
    "# marker map: corners in the detector's order (docs/marker_maps.md, Corner order), metres\n"
)


#: relative tolerance on a marker's sides and diagonals (:func:`check_marker_corners`)
MARKER_SQUARE_TOLERANCE = 0.05


def check_marker_corners(corners: np.ndarray, size: float | None = None, what: str = "") -> None:
    """Check that ``corners`` (4, 3) (metres, ArUco order) form a square: finite, the four sides
    and the two diagonals (``sqrt(2)`` sides) equal within :data:`MARKER_SQUARE_TOLERANCE`,
    coplanar within that tolerance of the side, a side > 1 mm, and, if ``size`` is given, a
    side of that length within the tolerance.

    Raises:
        ValueError: naming ``what`` and the first violation.
    """
    c = np.asarray(corners, dtype=float)
    if c.shape != (4, 3) or not np.isfinite(c).all():
        raise ValueError(f"{what}needs 4 finite 3D corners")
    sides = np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1)
    diag = np.array([np.linalg.norm(c[2] - c[0]), np.linalg.norm(c[3] - c[1])])
    side = float(np.mean(sides))
    tol = MARKER_SQUARE_TOLERANCE
    if not side > 1e-3:
        raise ValueError(f"{what}degenerate corners (side {side:.3g} m)")
    if np.abs(sides - side).max() > tol * side or np.abs(diag - np.sqrt(2) * side).max() > (
        tol * side
    ):
        raise ValueError(
            f"{what}corners are not a square (sides {np.round(sides, 4).tolist()} m, "
            f"diagonals {np.round(diag, 4).tolist()} m)"
        )
    n = np.cross(c[1] - c[0], c[3] - c[0])
    n = n / np.linalg.norm(n)
    if abs(float((c[2] - c[0]) @ n)) > tol * side:
        raise ValueError(f"{what}corners are not coplanar")
    if size is not None and abs(side - float(size)) > tol * float(size):
        raise ValueError(f"{what}side {side:.4f} m, the map states {float(size):.4f} m")


def marker_dictionary(name: str) -> Any:
    """cv2.aruco dictionary by name (e.g. ``DICT_4X4_250``) or a custom dictionary file
    (OpenCV's dictionary YAML, a path ending ``.yml``/``.yaml``):
    :func:`rs_localizer.cv_compat.get_dictionary`.

    Raises ValueError for a name OpenCV does not know or a file that is not a dictionary."""
    from ..cv_compat import get_dictionary

    return get_dictionary(name)


def write_marker_map(
    path: str | os.PathLike,
    dictionary: str,
    corners: dict,
    scene: str | None = None,
    *,
    anchor: int | None = None,
    frame: dict | None = None,
    readout: dict | None = None,
    marker_fields: dict | None = None,
    overwrite: bool = True,
) -> Path:
    """Write a marker map as YAML, atomically (:func:`~rs_localizer.maps.files.write_text_atomic`):
    a comment line, then ``dictionary``, ``scene`` (when given), ``anchor``, ``frame`` and
    ``readout`` (when given) and ``markers``: per marker, by increasing id, ``id``,
    ``corners`` (rounded to 1 um) and its ``marker_fields`` entries.

    Args:
        path: the YAML to write (its directory is created).
        dictionary: OpenCV predefined dictionary name (e.g. ``DICT_4X4_250``), an AprilTag
            family (``tag36h11``) or a custom dictionary file (OpenCV's dictionary YAML).
        corners: {marker id: (4, 3) map-frame corners in the detector's order (module notes),
            metres}.
        scene: name of the scene the map was rendered from.
        anchor: id of the marker whose frame is the map's (``map-markers``).
        frame: how the map frame is fixed and its own uncertainty (``map-markers``: ``kind``,
            ``anchors``, ``rotation_std_deg``, ``position_std_mm``...), written as given.
        readout: the line delay the map was built with (``map-markers``: ``line_delay_s``,
            ``readout_time_s``, and with ``--calibrate-readout`` ``line_delay_std_s``,
            ``observable``, ``reason``; :func:`load_marker_readout`), written as given.
        marker_fields: {marker id: {key: plain YAML value}} written after the marker's corners
            (``map-markers``: ``std_position`` (3,) m, ``std_rotation`` (3,) rad,
            ``observations``).
        overwrite: replace an existing file.
    Returns:
        The path written.
    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is False. OSError: it cannot be
        written.
    """
    import yaml

    fields = marker_fields or {}
    data = {"dictionary": dictionary}
    if scene is not None:
        data["scene"] = scene
    if anchor is not None:
        data["anchor"] = int(anchor)
    if frame is not None:
        data["frame"] = frame
    if readout is not None:
        data["readout"] = readout
    data["markers"] = [
        {"id": int(k), "corners": np.round(c, 6).tolist(), **fields.get(k, {})}
        for k, c in sorted(corners.items())
    ]
    return write_text_atomic(
        path,
        MARKER_MAP_HEADER + yaml.safe_dump(data, default_flow_style=None, sort_keys=False),
        overwrite=overwrite,
    )


def load_marker_map(path: str | os.PathLike) -> tuple[str, dict[int, np.ndarray]]:
    """Read a marker map (:func:`write_marker_map`), or a scene YAML / built-in scene name
    (``aruco_room``: the corners of its markers). Returns ``(dictionary name, {id: (4, 3)
    corners in the detector's order, metres})``; a custom dictionary file the map names
    (``.yml``/``.yaml``, OpenCV's dictionary YAML) relative to its own directory is returned
    with that directory.

    Raises:
        FileNotFoundError: no such file or built-in scene. ValueError: neither a marker map nor
        a scene, no markers, a marker without an integer id >= 0 or 4 finite 3D corners, an id
        given twice, corners that are not a square (:func:`check_marker_corners`; of the
        marker's ``size`` or the map's ``marker_size`` in metres when given). Other keys
        (per-marker uncertainty, observations, the anchor) are read by their own users and
        ignored here.
    """
    import yaml

    p = scene_path(path)
    data = yaml.safe_load(p.read_text())
    if isinstance(data, dict) and "quads" in data:
        return str(data.get("dictionary", "DICT_4X4_250")), scene_marker_corners(data)
    if not isinstance(data, dict) or "markers" not in data:
        raise ValueError(f"{p}: neither a marker map nor a scene")
    markers = data["markers"]
    if not isinstance(markers, list) or not markers:
        raise ValueError(f"{p}: the map has no markers")
    dictionary = data.get("dictionary", "DICT_4X4_250")
    if not isinstance(dictionary, str):
        raise ValueError(f"{p}: 'dictionary' must be a name, got {dictionary!r}")
    dictionary = _dictionary_path(dictionary, p)
    size = data.get("marker_size")
    corners = {}
    for k, m in enumerate(markers):
        if not isinstance(m, dict) or "id" not in m or "corners" not in m:
            raise ValueError(f"{p}: marker #{k} needs 'id' and 'corners'")
        mid = m["id"]
        if isinstance(mid, bool) or not isinstance(mid, int) or mid < 0:
            raise ValueError(f"{p}: marker #{k}: id must be an integer >= 0, got {mid!r}")
        if mid in corners:
            raise ValueError(f"{p}: marker id {mid} appears twice")
        try:
            c = np.asarray(m["corners"], dtype=float)
            msize = m.get("size", size)
            msize = None if msize is None else float(msize)
        except (TypeError, ValueError):
            raise ValueError(f"{p}: marker {mid}: corners and size must be numbers") from None
        check_marker_corners(c, msize, f"{p}: marker {mid}: ")
        corners[mid] = c
    return dictionary, corners


def _dictionary_path(dictionary: str, map_path: Path) -> str:
    """A custom dictionary file (``.yml``/``.yaml``) named by a map, relative to the map's
    directory when it is there (else as given: relative to the working directory)."""
    if not dictionary.lower().endswith((".yml", ".yaml")) or os.path.isabs(dictionary):
        return dictionary
    beside = map_path.parent / dictionary
    return str(beside) if beside.is_file() else dictionary


def load_marker_std(path: str | os.PathLike) -> dict:
    """The stated position std of a marker map's markers: {marker id: the largest of its
    ``std_position`` entries (m)} (maps written by ``map-markers``); {} for a map without them
    (older maps, scenes) or a name that is not a file (a built-in scene). Markers without a
    finite ``std_position`` are left out. Validation is :func:`load_marker_map`'s.
    """
    import yaml

    p = Path(str(path))
    if not p.is_file():
        return {}
    data = yaml.safe_load(p.read_text())
    out = {}
    for m in (data or {}).get("markers", []) if isinstance(data, dict) else []:
        std = m.get("std_position") if isinstance(m, dict) else None
        if std is not None and np.all(np.isfinite(np.asarray(std, dtype=float))):
            out[int(m["id"])] = float(np.max(std))
    return out


def load_marker_readout(path: str | os.PathLike) -> dict:
    """The ``readout`` entry of a marker map written by ``map-markers``
    (:func:`write_marker_map`): ``line_delay_s`` (s per line), ``readout_time_s`` (s per
    frame), ``calibrated`` (estimated with ``--calibrate-readout``: then also
    ``line_delay_std_s``, ``observable`` and ``reason``, empty when observable). {} for a map
    without it (older maps, scenes) or a name that is not a file. Validation of the markers
    is :func:`load_marker_map`'s.
    """
    import yaml

    p = Path(str(path))
    if not p.is_file():
        return {}
    data = yaml.safe_load(p.read_text())
    out = data.get("readout") if isinstance(data, dict) else None
    return dict(out) if isinstance(out, dict) else {}
