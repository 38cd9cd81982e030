"""Marker maps from tag poses: layouts that give each tag as ``(id, size, pose)`` instead of
its four corners, turned into the corners of :mod:`.markers` in the detector's corner order.

Three formats, each with its own tag frame (the frame a tag's pose places; the docs' "Maps from
tag poses" in ``docs/marker_maps.md`` states them with their sources):

* ``poses``: this package's YAML, ``tags: [{id, size, pose: {position: [x, y, z],
  orientation: [qx, qy, qz, qw]}}]`` (optional top-level ``dictionary`` and ``size``). Tag
  frame: origin at the tag's centre, x to the right and y up on the printed face, z out of the
  face towards a viewer (the frame of ``apriltag_ros`` and TagSLAM; ``map-markers``' anchor
  frame).
* ``wpilib``: WPILib's field layout JSON (``{"tags": [{"ID", "pose": {"translation": {x, y,
  z}, "rotation": {"quaternion": {W, X, Y, Z}}}}], "field": {length, width}}``); it gives no
  sizes (``sizes``/``default_size``). Tag frame: x out of the face towards a viewer, y to the
  viewer's right, z up.
* ``apriltag_ros``: ROS 1 ``apriltag_ros``' bundle YAML (``tag_bundles: [{name, layout: [{id,
  size, x, y, z, qw, qx, qy, qz}]}]``, at the top or under a node's namespace); the tag
  frame is the ``poses`` one.

The corners are written in the order the detector returns them (:func:`tag_corners`): for
ArUco dictionaries (and custom ones) the printed marker's top-left, top-right, bottom-right,
bottom-left; for AprilTag families, printed from the AprilTag images (the library's own
rendering, ``apriltag-imgs``), bottom-right, bottom-left, top-left, top-right: OpenCV's
``DICT_APRILTAG_*`` order, whose own marker images (``cv2.aruco.generateImageMarker``) are the
AprilTag images turned by 180 degrees.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .markers import check_marker_corners, write_marker_map

__all__ = [
    "TAG_LAYOUT_FORMATS",
    "TagLayout",
    "is_apriltag_dictionary",
    "layout_corners",
    "read_tag_layout",
    "tag_corners",
    "write_tag_map",
]

#: the layout formats :func:`read_tag_layout` reads
TAG_LAYOUT_FORMATS = ("poses", "wpilib", "apriltag_ros")

#: how far a quaternion's norm may be from 1 (rounded values in a file) before it is refused
QUATERNION_NORM_TOLERANCE = 1e-3

#: WPILib's tag frame (x out of the face, y to the viewer's right, z up) -> the poses' frame (x
#: right, y up, z out of the face): the columns are the poses' axes in WPILib's frame
WPILIB_TO_TAG = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

#: the printed corners in the tag frame (side 1): top-left, top-right, bottom-right, bottom-left
_PRINTED = {
    "TL": (-0.5, 0.5),
    "TR": (0.5, 0.5),
    "BR": (0.5, -0.5),
    "BL": (-0.5, -0.5),
}
#: the detector's corner order per kind of dictionary, as printed corners
CORNER_ORDER = {
    "aruco": ("TL", "TR", "BR", "BL"),
    "apriltag": ("BR", "BL", "TL", "TR"),
}


def is_apriltag_dictionary(dictionary: str) -> bool:
    """Whether ``dictionary`` names an AprilTag family (OpenCV's ``DICT_APRILTAG_*`` or the
    AprilTag library's ``tag*`` names); custom dictionary files and ArUco names are not."""
    d = str(dictionary)
    return d.startswith("DICT_APRILTAG_") or (d.startswith("tag") and "." not in d)


def tag_corners(
    size: float,
    rotation: np.ndarray,
    position: np.ndarray,
    dictionary: str,
    opencv_images: bool = False,
) -> np.ndarray:
    """The four map-frame corners (4, 3) (metres) of a tag of side ``size`` (m) whose frame
    (origin at its centre, x right and y up on the printed face, z out of it) has
    ``rotation`` (3, 3) tag -> map and ``position`` (3,) in the map, in the order the detector
    of ``dictionary`` returns them (module notes). ``opencv_images``: AprilTags printed from
    OpenCV's own marker images, turned by 180 degrees from the AprilTag images."""
    kind = "apriltag" if is_apriltag_dictionary(dictionary) and not opencv_images else "aruco"
    local = np.array([[*_PRINTED[c], 0.0] for c in CORNER_ORDER[kind]]) * float(size)
    return local @ np.asarray(rotation, float).T + np.asarray(position, float)


@dataclass
class TagLayout:
    """Tags by pose, read by :func:`read_tag_layout`.

    Attributes:
        tags: {id: (size (m), rotation (3, 3) tag -> map, position (3,) m)}, tag frame as in
            the ``poses`` format (x right, y up, z out of the face).
        format: the format read (:data:`TAG_LAYOUT_FORMATS`).
        dictionary: the dictionary the file names (``poses`` only), else None.
        notes: what the file said besides the tags (WPILib's field size, the bundle's name).
    """

    tags: dict
    format: str
    dictionary: str | None = None
    notes: dict = field(default_factory=dict)


def _number(value, what: str) -> float:
    if isinstance(value, bool):
        raise ValueError(f"{what} must be a number, got {value!r}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return out


def _rotation(q_xyzw, what: str) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w); refuses a norm off 1 by more than
    :data:`QUATERNION_NORM_TOLERANCE` (normalizes the rest)."""
    from scipy.spatial.transform import Rotation

    q = np.array([_number(v, what) for v in q_xyzw])
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise ValueError(f"{what}: not a unit quaternion (norm {n:.6g})")
    return Rotation.from_quat(q / n).as_matrix()


def _tag_id(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{what}: id must be an integer >= 0, got {value!r}")
    return int(value)


def _size(value, tag: int, sizes: dict, default_size: float | None, where: str) -> float:
    """A tag's side: ``sizes`` (the caller's, by id) first, then the file's, then the default."""
    if tag in sizes:
        value = sizes[tag]
    elif value is None:
        value = default_size
    if value is None:
        raise ValueError(f"{where}tag {tag}: no size (give one in the file or a marker size)")
    s = _number(value, f"{where}tag {tag}: size")
    if not s > 0:
        raise ValueError(f"{where}tag {tag}: size must be > 0 m, got {s:g}")
    return s


def _xyz(value, what: str) -> np.ndarray:
    if isinstance(value, dict):
        value = [value.get(k) for k in ("x", "y", "z")]
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ValueError(f"{what} must be [x, y, z], got {value!r}")
    return np.array([_number(v, what) for v in value])


def _add(tags: dict, tag: int, entry: tuple, where: str) -> None:
    if tag in tags:
        raise ValueError(f"{where}tag id {tag} appears twice")
    tags[tag] = entry


def _read_poses(data: dict, sizes: dict, default_size, where: str) -> TagLayout:
    entries = data.get("tags")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{where}'tags' must be a non-empty list of {{id, size, pose}}")
    file_size = data.get("size")
    if file_size is not None:
        default_size = file_size if default_size is None else default_size
    tags: dict = {}
    for k, e in enumerate(entries):
        if not isinstance(e, dict) or "id" not in e or "pose" not in e:
            raise ValueError(f"{where}tag #{k} needs 'id' and 'pose'")
        tag = _tag_id(e["id"], f"{where}tag #{k}")
        pose = e["pose"]
        if not isinstance(pose, dict) or "position" not in pose or "orientation" not in pose:
            raise ValueError(
                f"{where}tag {tag}: pose needs 'position' [x, y, z] and 'orientation' "
                "[qx, qy, qz, qw]"
            )
        q = pose["orientation"]
        if isinstance(q, dict):
            q = [q.get(c) for c in ("x", "y", "z", "w")]
        if not isinstance(q, (list, tuple)) or len(q) != 4:
            raise ValueError(f"{where}tag {tag}: orientation must be [qx, qy, qz, qw]")
        size = _size(e.get("size"), tag, sizes, default_size, where)
        entry = (
            size,
            _rotation(q, f"{where}tag {tag}: orientation"),
            _xyz(pose["position"], f"{where}tag {tag}: position"),
        )
        _add(tags, tag, entry, where)
    dictionary = data.get("dictionary")
    if dictionary is not None and not isinstance(dictionary, str):
        raise ValueError(f"{where}'dictionary' must be a name, got {dictionary!r}")
    return TagLayout(tags, "poses", dictionary)


def _read_wpilib(data: dict, sizes: dict, default_size, where: str) -> TagLayout:
    entries = data.get("tags")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{where}'tags' must be a non-empty list")
    tags: dict = {}
    for k, e in enumerate(entries):
        try:
            tag = _tag_id(e["ID"], f"{where}tag #{k}")
            t = e["pose"]["translation"]
            q = e["pose"]["rotation"]["quaternion"]
            q_xyzw = [q["X"], q["Y"], q["Z"], q["W"]]
        except (KeyError, TypeError):
            raise ValueError(
                f"{where}tag #{k} needs ID, pose.translation {{x, y, z}} and "
                "pose.rotation.quaternion {W, X, Y, Z}"
            ) from None
        R = _rotation(q_xyzw, f"{where}tag {tag}: quaternion") @ WPILIB_TO_TAG
        size = _size(e.get("size"), tag, sizes, default_size, where)
        _add(tags, tag, (size, R, _xyz(t, f"{where}tag {tag}: translation")), where)
    notes = {}
    fld = data.get("field")
    if isinstance(fld, dict) and {"length", "width"} <= set(fld):
        notes["field_length"] = _number(fld["length"], f"{where}field length")
        notes["field_width"] = _number(fld["width"], f"{where}field width")
    return TagLayout(tags, "wpilib", None, notes)


def _find_bundles(data):
    """The ``tag_bundles`` list of an apriltag_ros YAML, at the top or under namespaces."""
    if isinstance(data, dict):
        if "tag_bundles" in data:
            return data["tag_bundles"]
        for v in data.values():
            found = _find_bundles(v)
            if found is not None:
                return found
    return None


def _read_apriltag_ros(
    data, sizes: dict, default_size, where: str, bundle: str | None
) -> TagLayout:
    bundles = _find_bundles(data)
    if not isinstance(bundles, list) or not bundles:
        raise ValueError(f"{where}no 'tag_bundles' list")
    names = [b.get("name") if isinstance(b, dict) else None for b in bundles]
    if bundle is None:
        if len(bundles) > 1:
            raise ValueError(f"{where}{len(bundles)} bundles ({names}): name one (bundle)")
        chosen = bundles[0]
    elif bundle in names:
        chosen = bundles[names.index(bundle)]
    else:
        raise ValueError(f"{where}no bundle {bundle!r}; the file has {names}")
    layout = chosen.get("layout") if isinstance(chosen, dict) else None
    if not isinstance(layout, list) or not layout:
        raise ValueError(f"{where}bundle {chosen.get('name')!r}: 'layout' must be a list")
    tags: dict = {}
    for k, e in enumerate(layout):
        if not isinstance(e, dict) or "id" not in e:
            raise ValueError(f"{where}layout entry #{k} needs 'id'")
        tag = _tag_id(e["id"], f"{where}layout entry #{k}")
        # (apriltag_ros: x, y, z default to 0, qw to 1, qx, qy, qz to 0)
        q = [e.get("qx", 0.0), e.get("qy", 0.0), e.get("qz", 0.0), e.get("qw", 1.0)]
        p = [e.get("x", 0.0), e.get("y", 0.0), e.get("z", 0.0)]
        size = _size(e.get("size"), tag, sizes, default_size, where)
        entry = (size, _rotation(q, f"{where}tag {tag}: quaternion"), _xyz(p, f"{where}tag {tag}"))
        _add(tags, tag, entry, where)
    return TagLayout(tags, "apriltag_ros", None, {"bundle": chosen.get("name")})


def _detect_format(data) -> str:
    if isinstance(data, dict) and isinstance(data.get("tags"), list):
        first = data["tags"][0] if data["tags"] else {}
        return "wpilib" if isinstance(first, dict) and "ID" in first else "poses"
    if _find_bundles(data) is not None:
        return "apriltag_ros"
    raise ValueError(
        "not a tag layout: expected 'tags' (poses YAML, WPILib JSON) or 'tag_bundles' "
        "(apriltag_ros)"
    )


def read_tag_layout(
    path: str | os.PathLike,
    fmt: str = "auto",
    sizes: dict | None = None,
    default_size: float | None = None,
    bundle: str | None = None,
) -> TagLayout:
    """Read a layout of tags by pose (module notes: ``poses`` YAML, WPILib JSON, apriltag_ros
    bundle YAML).

    Args:
        path: the file (YAML or JSON).
        fmt: ``auto`` (from the file's keys) or one of :data:`TAG_LAYOUT_FORMATS`.
        sizes: {tag id: side (m)}, over the file's sizes.
        default_size: side (m) of the tags the file and ``sizes`` give none.
        bundle: the apriltag_ros bundle to read (needed when the file has several).
    Returns:
        The :class:`TagLayout`, tags in the ``poses`` tag frame.
    Raises:
        ValueError (naming the file and the tag): an unknown format, no tags, an id given
        twice, a tag without a size, a size <= 0, a quaternion whose norm is off 1 by more
        than :data:`QUATERNION_NORM_TOLERANCE`, a value that is not a finite number.
        OSError: the file cannot be read.
    """
    import yaml

    p = Path(path)
    where = f"{p}: "
    text = p.read_text()
    try:
        data = json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
    except (ValueError, yaml.YAMLError) as e:
        raise ValueError(f"{where}not YAML/JSON ({' '.join(str(e).split())[:120]})") from None
    if fmt == "auto":
        fmt = _detect_format(data)
    elif fmt not in TAG_LAYOUT_FORMATS:
        raise ValueError(f"unknown tag layout format {fmt!r}; known: {TAG_LAYOUT_FORMATS}")
    sizes = dict(sizes or {})
    if fmt == "poses":
        if not isinstance(data, dict):
            raise ValueError(f"{where}expected a mapping with 'tags'")
        return _read_poses(data, sizes, default_size, where)
    if fmt == "wpilib":
        if not isinstance(data, dict):
            raise ValueError(f"{where}expected WPILib's layout (a mapping with 'tags')")
        return _read_wpilib(data, sizes, default_size, where)
    return _read_apriltag_ros(data, sizes, default_size, where, bundle)


def layout_corners(
    layout: TagLayout, dictionary: str, opencv_images: bool = False
) -> dict[int, np.ndarray]:
    """{id: (4, 3) map-frame corners in the detector's order} of ``layout`` (:func:`tag_corners`),
    each checked to be a square of its size."""
    out = {}
    for tag, (size, R, t) in sorted(layout.tags.items()):
        c = tag_corners(size, R, t, dictionary, opencv_images)
        check_marker_corners(c, size, f"tag {tag}: ")
        out[tag] = c
    return out


def write_tag_map(
    path: str | os.PathLike,
    layout: TagLayout,
    dictionary: str,
    opencv_images: bool = False,
    overwrite: bool = False,
) -> Path:
    """Write ``layout`` as a marker map (:func:`~rs_localizer.maps.markers.write_marker_map`,
    atomic: a bad layout or an error leaves no file): per tag its corners in the detector's
    order for ``dictionary`` and its ``size``; the map's ``frame`` entry names the layout's
    format (``kind: tag-poses``).

    Raises:
        ValueError: a tag whose corners are not a square (never for a valid layout).
        FileExistsError: ``path`` exists and ``overwrite`` is False. OSError: not writable.
    """
    corners = layout_corners(layout, dictionary, opencv_images)
    frame = {"kind": "tag-poses", "source_format": layout.format, **layout.notes}
    if opencv_images:
        frame["opencv_images"] = True
    fields = {tag: {"size": round(float(s), 6)} for tag, (s, _, _) in layout.tags.items()}
    return write_marker_map(
        path, dictionary, corners, frame=frame, marker_fields=fields, overwrite=overwrite
    )
