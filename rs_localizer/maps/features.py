"""Feature maps: 3D landmarks with ORB or SIFT descriptors, the map of the ``features`` front
end, stored as a compressed ``.npz`` (arrays ``points`` (M, 3) map frame in metres,
``descriptors`` (M, D), ``landmark_ids`` (M,), ``kind``; optionally ``track_length``,
``reprojection_error``, ``metric``). One writer (:meth:`FeatureMap.save`), one reader
(:meth:`FeatureMap.load`) with its validation (:func:`check_feature_map`).
"""

from __future__ import annotations

import os
import tempfile
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .files import file_mode

__all__ = ["DESCRIPTOR_FORMATS", "FeatureMap", "check_feature_map"]


@dataclass
class FeatureMap:
    """3D landmarks with descriptors: ``points`` (M, 3) world (m), ``descriptors`` (M, D)
    (uint8 ORB / float32 SIFT), ``landmark_ids`` (M,) int64 (several descriptors, seen from
    different views, may share one landmark and its 3D point), ``kind`` ``orb``/``sift``.

    Optional quality of each row (maps from a reconstruction, e.g.
    :func:`rs_localizer.mapping.colmap.feature_map_from_colmap`; None for maps without it):
    ``track_length`` (M,) int64 images that observed the point, ``reprojection_error`` (M,)
    mean reprojection error (px) of its observations. ``metric`` is False when the points are
    in an arbitrary scale (a reconstruction neither scaled nor aligned: positions, and
    velocities, are then not in metres), True when known to be metric, None if not recorded.
    """

    points: np.ndarray
    descriptors: np.ndarray
    landmark_ids: np.ndarray
    kind: str = "orb"
    track_length: np.ndarray | None = None
    reprojection_error: np.ndarray | None = None
    metric: bool | None = None

    def __len__(self):
        return len(self.points)

    @property
    def num_landmarks(self) -> int:
        return int(len(np.unique(self.landmark_ids)))

    def _optional_arrays(self) -> dict:
        out = {}
        if self.track_length is not None:
            out["track_length"] = np.asarray(self.track_length, np.int64)
        if self.reprojection_error is not None:
            out["reprojection_error"] = np.asarray(self.reprojection_error, np.float64)
        if self.metric is not None:
            out["metric"] = np.array(bool(self.metric))
        return out

    def subset(self, keep: np.ndarray) -> FeatureMap:
        """The rows ``keep`` (bool mask (M,) or indices) with their quality arrays."""
        opt = {
            k: (None if getattr(self, k) is None else getattr(self, k)[keep])
            for k in ("track_length", "reprojection_error")
        }
        return FeatureMap(
            self.points[keep],
            self.descriptors[keep],
            self.landmark_ids[keep],
            self.kind,
            metric=self.metric,
            **opt,
        )

    def save(self, path: str | Path) -> Path:
        """Write the compressed ``.npz`` whole or not at all: a temporary file in the same
        directory, renamed over ``path`` (an existing map is replaced), with the user's umask
        mode (:func:`~rs_localizer.maps.files.file_mode`). ``.npz`` is appended to a name
        without it. Optional fields are stored only when set (older readers ignore them).

        Returns:
            The path written.
        Raises:
            OSError: the directory does not exist or cannot be written (nothing is left
                behind).
        """
        path = Path(path)
        out = path if path.suffix == ".npz" else path.with_suffix(path.suffix + ".npz")
        fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
        try:
            os.fchmod(fd, file_mode())  # (mkstemp's 0600 -> the umask's: readable by others)
            with os.fdopen(fd, "wb") as fh:
                np.savez_compressed(
                    fh,
                    points=self.points,
                    descriptors=self.descriptors,
                    landmark_ids=self.landmark_ids,
                    kind=np.array(self.kind),
                    **self._optional_arrays(),
                )
            os.replace(tmp, out)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return out

    @classmethod
    def load(cls, path: str | Path) -> FeatureMap:
        """Read a feature map ``.npz`` (:meth:`save`).

        Raises:
            ValueError: a file that is not a feature map (not a NumPy ``.npz``, arrays missing,
                not numeric, or holding Python objects, which are never unpickled), or one no
                front end can use (:func:`check_feature_map`); the message names the file.
            OSError: it cannot be read.
        """
        z = _read_arrays(Path(path))
        raw_ids = z["landmark_ids"]
        fm = cls(
            z["points"].astype(float),
            z["descriptors"],
            np.nan_to_num(raw_ids).astype(np.int64),
            str(z["kind"]),
            track_length=z["track_length"].astype(np.int64) if "track_length" in z else None,
            reprojection_error=(
                z["reprojection_error"].astype(float) if "reprojection_error" in z else None
            ),
            metric=bool(z["metric"]) if "metric" in z else None,
        )
        n = len(fm.points)
        if fm.points.shape != (len(fm.descriptors), 3) or len(fm.landmark_ids) != n:
            raise ValueError(f"{path}: inconsistent feature map arrays")
        for q in (fm.track_length, fm.reprojection_error):
            if q is not None and q.shape != (n,):
                raise ValueError(f"{path}: inconsistent feature map quality arrays")
        check_feature_map(fm, raw_ids, str(path))
        return fm


#: the arrays of a feature map ``.npz`` (:meth:`FeatureMap.save`): required, then optional
_REQUIRED = ("points", "descriptors", "landmark_ids", "kind")
_OPTIONAL = ("track_length", "reprojection_error", "metric")

#: what reading a member of a corrupt ``.npz`` may raise (beside OSError: cannot be read)
_CORRUPT = (
    ValueError,
    EOFError,
    KeyError,
    TypeError,
    NotImplementedError,
    zipfile.BadZipFile,
    zlib.error,
)


def _read_arrays(path: Path) -> dict:
    """The arrays of a feature map ``.npz`` at ``path`` (required and present optional ones),
    read without unpickling anything (``allow_pickle=False``). Raises ValueError naming
    ``path`` for a file that is not a feature map: not a NumPy ``.npz``, arrays missing or not
    arrays, holding Python objects, or non-numeric where numbers are expected; OSError when
    it cannot be read."""

    def refuse(why: str) -> ValueError:
        return ValueError(
            f"{path}: not a feature map ({why}); a feature map is the .npz that "
            "rs-localizer map-features writes"
        )

    try:
        z = np.load(path, allow_pickle=False)
    except _CORRUPT:
        # (numpy takes anything that is neither a zip nor a .npy for a pickle: never load it)
        raise refuse("not a NumPy .npz archive") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise refuse("a single NumPy array, not a .npz archive of named arrays")
    with z:
        missing = [k for k in _REQUIRED if k not in z.files]
        if missing:
            raise refuse(f"missing {missing}")
        out = {}
        for k in (*_REQUIRED, *_OPTIONAL):
            if k not in z.files:
                continue
            try:
                a = z[k]
            except _CORRUPT as e:
                why = "holds Python objects" if "bject" in str(e) else "cannot be read"
                raise refuse(f"array {k!r} {why}") from None
            if not isinstance(a, np.ndarray):
                raise refuse(f"{k!r} is not a NumPy array")
            numeric = "biu" if k == "metric" else "U" if k == "kind" else "iuf"
            if a.dtype.kind not in numeric or (k in ("kind", "metric") and a.size != 1):
                raise refuse(f"array {k!r} is {a.dtype} {a.shape}")
            out[k] = a
    return out


#: per descriptor kind: (dtype, width) the OpenCV detector produces (ORB: 32 bytes, SIFT: 128
#: floats); a map's descriptors must match the front end's detector to be matched at all
DESCRIPTOR_FORMATS = {"orb": (np.dtype(np.uint8), 32), "sift": (np.dtype(np.float32), 128)}


def check_feature_map(fm: FeatureMap, raw_ids: np.ndarray | None = None, what: str = "") -> None:
    """Check that a feature map can work with its front end: a known ``kind``
    (:data:`DESCRIPTOR_FORMATS`), descriptors of that kind's dtype and width (an ORB map with
    float32 descriptors would fail every match), at least one row, finite points, integral
    finite landmark ids (``raw_ids``: the ids as stored, before conversion).

    Raises:
        ValueError: naming ``what`` and the first problem.
    """
    kind = str(fm.kind).lower()
    if kind not in DESCRIPTOR_FORMATS:
        raise ValueError(f"{what}: kind {fm.kind!r} is not one of {sorted(DESCRIPTOR_FORMATS)}")
    dtype, width = DESCRIPTOR_FORMATS[kind]
    d = np.asarray(fm.descriptors)
    if d.ndim != 2 or d.dtype != dtype or d.shape[1] != width:
        raise ValueError(
            f"{what}: {kind} descriptors must be (M, {width}) {dtype}, got {d.shape} {d.dtype}"
        )
    if len(fm.points) == 0:
        raise ValueError(f"{what}: the map has no landmarks")
    if not np.isfinite(fm.points).all():
        raise ValueError(f"{what}: non-finite landmark points")
    ids = fm.landmark_ids if raw_ids is None else np.asarray(raw_ids)
    if ids.dtype.kind == "f" and not (np.isfinite(ids).all() and (ids == np.round(ids)).all()):
        raise ValueError(f"{what}: landmark ids must be finite integers")
    if ids.dtype.kind not in "iuf":
        raise ValueError(f"{what}: landmark ids must be integers, got {ids.dtype}")
