"""ArUco front end: marker corners -> 2D-3D correspondences.

OpenCV's ``cv2.aruco.ArucoDetector`` finds the markers (subpixel corner refinement); each corner
``k`` (top-left, top-right, bottom-right, bottom-left) of marker ``id`` found in the marker map
becomes a correspondence with id ``4 * id + k`` and the corner's 3D position. Markers not in the
map are ignored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..camera import CameraModel
from ..correspondences import Correspondences
from . import cv_compat

__all__ = ["ArucoFrontend", "marker_scores", "marker_std_from_file", "to_gray"]

#: a marker whose stated position std is this (m) scores 0.5 (:func:`marker_scores`)
SCORE_STD_M = 0.005


def marker_scores(std: np.ndarray) -> np.ndarray:
    """Match scores (N,) in (0, 1] from the markers' stated position std (N,) m (largest axis
    in the map): ``1 / (1 + (std / SCORE_STD_M)^2)``, higher for better-fixed markers; the
    estimator draws its RANSAC samples from the best-scored correspondences first
    (PROSAC-style ordering), so a frame's hypotheses come from its best-mapped markers."""
    s = np.asarray(std, dtype=float) / SCORE_STD_M
    return 1.0 / (1.0 + s * s)


def marker_std_from_file(path: str | Path) -> dict:
    """id -> the largest of a marker's ``std_position`` entries (m) in a marker map written by
    ``map-markers``; {} for a map without them (older maps, scenes, a name that is not a
    file)."""
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


def to_gray(image: np.ndarray, encoding: str = "rgb8") -> np.ndarray:
    """(H, W) uint8 grayscale from mono8 / rgb8 / bgr8 / rgba8 / bgra8 arrays."""
    img = np.asarray(image)
    if img.ndim == 2:
        return np.ascontiguousarray(img, dtype=np.uint8)
    if img.ndim == 3 and img.shape[2] == 1:
        return np.ascontiguousarray(img[:, :, 0], dtype=np.uint8)
    enc = encoding.lower()
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"expected an (H, W), (H, W, 3) or (H, W, 4) image, got {img.shape}")
    code = {
        ("bgr", 3): cv2.COLOR_BGR2GRAY,
        ("bgr", 4): cv2.COLOR_BGRA2GRAY,
        ("rgb", 3): cv2.COLOR_RGB2GRAY,
        ("rgb", 4): cv2.COLOR_RGBA2GRAY,
    }
    kind = "bgr" if enc.startswith("bgr") else "rgb"
    return cv2.cvtColor(np.ascontiguousarray(img, dtype=np.uint8), code[(kind, img.shape[2])])


class ArucoFrontend:
    """Detect ArUco markers and emit correspondences to their mapped 3D corners.

    Args:
        marker_corners: {marker id: (4, 3) world corners in ArUco order}.
        dictionary: cv2.aruco predefined dictionary name (e.g. ``DICT_4X4_250``).
        subpix_window: half size (px) of the subpixel corner refinement window (at most one
            marker cell is used).
        min_marker_perimeter: smallest marker perimeter as a fraction of the image's larger
            side (OpenCV ``minMarkerPerimeterRate``).
        marker_std: {marker id: stated position std (m)} of the map: each correspondence
            gets the score of its marker (:func:`marker_scores`, in ``last_scores``); a marker
            without one scores 1. None: no scores.

    ``process(image, camera) -> (points_px (N, 2), points3d (N, 3), ids (N,) int64)``.
    """

    name = "aruco"

    def __init__(
        self,
        marker_corners: dict,
        dictionary: str = "DICT_4X4_250",
        subpix_window: int = 3,
        min_marker_perimeter: float = 0.02,
        marker_std: dict | None = None,
    ):
        from ..maps import marker_dictionary

        self.dictionary = dictionary
        self.marker_corners = {
            int(k): np.asarray(v, dtype=float).reshape(4, 3) for k, v in marker_corners.items()
        }
        # relativeCornerRefinmentWinSize (sic, OpenCV >= 4.9, skipped before): window up to one
        # marker cell (default 0.3 cell: ~0.27 px median error on rendered 30-40 px markers;
        # 1.0: ~0.22 px)
        params = cv_compat.detector_parameters(
            cornerRefinementMethod=cv2.aruco.CORNER_REFINE_SUBPIX,
            cornerRefinementWinSize=int(subpix_window),
            cornerRefinementMaxIterations=50,
            cornerRefinementMinAccuracy=0.01,
            relativeCornerRefinmentWinSize=1.0,
            minMarkerPerimeterRate=float(min_marker_perimeter),
        )
        self.params = params
        self.detector = cv_compat.MarkerDetector(marker_dictionary(dictionary), params)
        self.last_rejected = 0
        self.marker_std = (
            None if marker_std is None else {int(k): float(v) for k, v in marker_std.items()}
        )
        self.last_scores = None  # per correspondence, from marker_std

    @classmethod
    def from_scene(cls, scene: Any, **kw: Any) -> ArucoFrontend:
        return cls(scene.marker_corners(), scene.dictionary, **kw)

    @classmethod
    def from_file(cls, path: str | Path, **kw: Any) -> ArucoFrontend:
        """From a marker map YAML (:func:`rs_localizer.maps.load_marker_map`) or a scene
        YAML / built-in scene name; the map's stated std, when it has them, score the
        correspondences (``marker_std``)."""
        from ..maps import load_marker_map

        dictionary, corners = load_marker_map(Path(str(path)))
        kw.setdefault("marker_std", marker_std_from_file(path) or None)
        return cls(corners, dictionary, **kw)

    def detect(self, image: np.ndarray, encoding: str = "rgb8") -> tuple[np.ndarray, np.ndarray]:
        """Raw detections: (corners (M, 4, 2) pixels, marker ids (M,)), all markers found."""
        corners, ids, self.last_rejected = self.detector.detect(to_gray(image, encoding))
        return corners, ids

    def process(
        self, image: np.ndarray, camera: CameraModel | None = None, encoding: str = "rgb8"
    ) -> Correspondences:
        """Correspondences of one image: :class:`~rs_localizer.correspondences.Correspondences`
        (``pixels`` (N, 2), ``points`` (N, 3), ``ids`` (N,), ``scores`` (N,) from the map's
        stated std when it has them (``marker_std``), else None; unpacks as
        ``(points_px, points3d, ids)``) with ``ids = 4 * marker_id + corner``. ``camera`` is
        not needed (pixels stay distorted, as the estimator expects) but accepted for a uniform
        front-end API."""
        corners, mids = self.detect(image, encoding)
        keep = [i for i, m in enumerate(mids) if int(m) in self.marker_corners]
        if not keep:
            self.last_scores = None if self.marker_std is None else np.zeros(0)
            return Correspondences.empty()
        self.last_scores = None
        if self.marker_std is not None:
            std = [self.marker_std.get(int(mids[i]), 0.0) for i in keep]
            self.last_scores = np.repeat(marker_scores(np.asarray(std)), 4)
        uv = corners[keep].reshape(-1, 2)
        X = np.concatenate([self.marker_corners[int(mids[i])] for i in keep])
        ids = (4 * mids[keep][:, None] + np.arange(4)[None, :]).ravel()
        return Correspondences(uv, X, ids.astype(np.int64), self.last_scores)
