"""Landmark maps: ``id,x,y,z`` CSV (a header line, metres, map frame), the 3D points of the
``keypoints`` input. One writer (:func:`save_landmarks_csv`) and one reader
(:func:`load_landmarks_csv`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .files import open_regular_file, write_text_atomic

__all__ = ["load_landmarks_csv", "save_landmarks_csv"]


def save_landmarks_csv(path: str | os.PathLike, ids: np.ndarray, points: np.ndarray) -> Path:
    """Write a landmark map ``id,x,y,z`` (header line, metres), atomically
    (:func:`write_text_atomic`). Returns the path."""
    rows = [
        f"{int(i)},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in zip(ids, points, strict=False)
    ]
    return write_text_atomic(path, "id,x,y,z\n" + "".join(rows), overwrite=True)


def load_landmarks_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read ``id,x,y,z`` (header optional, ``#`` comments allowed). Returns (ids (M,) int64,
    points (M, 3)). Raises ValueError for malformed rows, no rows, duplicate ids, non-finite
    coordinates or a path that is not a regular file (a FIFO would block the reader), OSError if
    it cannot be opened."""
    ids, pts = [], []
    with open_regular_file(path) as f:
        for lineno, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = [s.strip() for s in line.split(",")]
            if lineno == 1 and parts[0].lower() == "id":
                continue
            if len(parts) != 4:
                raise ValueError(f"{path}:{lineno}: expected 'id,x,y,z', got {line!r}")
            try:
                ids.append(int(parts[0]))
                pts.append([float(s) for s in parts[1:]])
            except ValueError as e:
                raise ValueError(f"{path}:{lineno}: {e}") from None
    if not ids:
        raise ValueError(f"{path}: no landmarks")
    ids = np.asarray(ids, dtype=np.int64)
    if len(np.unique(ids)) != len(ids):
        raise ValueError(f"{path}: duplicate landmark ids")
    pts = np.asarray(pts, dtype=float).reshape(-1, 3)
    if not np.isfinite(pts).all():
        raise ValueError(f"{path}: non-finite coordinates")
    return ids, pts
