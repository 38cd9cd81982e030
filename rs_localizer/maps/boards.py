"""Board files: the YAML of a fiducial board (``type``: ``checkerboard``, ``charuco``,
``tag_grid`` or ``tag_map``; its geometry in metres, an optional ``pose`` board frame -> map
frame and ``id_offset``; the format in :mod:`rs_localizer.frontends.boards`).

:func:`read_board` is the one reader: it parses the file (or a dict) and checks the keys of its
type (the required ones present, no unknown ones, defaults filled in). The board models and
their detectors, built from what it returns, are the front end's
(:func:`rs_localizer.frontends.boards.load_board`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["BOARD_KEYS", "BOARD_TYPES", "BoardSpec", "read_board"]

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
