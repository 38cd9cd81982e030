"""Image front ends: an image in, 2D-3D correspondences out.

Every front end has ``process(image, camera, encoding)`` returning
:class:`~rs_localizer.correspondences.Correspondences` (distorted pixels (N, 2), world points in
metres (N, 3), int64 ids (N,) and optional match scores; it unpacks as ``pixels, points, ids``),
ready for :func:`rs_localizer.estimate_rs_pose` (the protocols:
:class:`~rs_localizer.correspondences.Frontend`,
:class:`~rs_localizer.correspondences.TrackingFrontend`). :func:`make_frontend` builds one by
name.
"""

import os
from typing import Any

from .aruco import ArucoFrontend, to_gray
from .features import FeatureFrontend, FeatureMap, feature_map_from_views

__all__ = [
    "FRONTENDS",
    "ArucoFrontend",
    "FeatureFrontend",
    "FeatureMap",
    "feature_map_from_views",
    "make_frontend",
    "to_gray",
]

FRONTENDS = ("aruco", "features", "board")


def make_frontend(kind: str, map_path: str | os.PathLike, **kw: Any) -> Any:
    """Front end by name: ``aruco`` (``map_path``: marker map YAML, scene YAML or built-in scene
    name: :func:`rs_localizer.maps.load_marker_map`) or ``features`` (``map_path``: a feature map
    ``.npz``, :meth:`FeatureMap.save`) or ``board`` (``map_path``: a board YAML,
    :func:`rs_localizer.frontends.boards.load_board`: checkerboard, ChArUco or tag board). Raises
    ValueError for an unknown kind or a bad map,
    FileNotFoundError for a missing one."""
    if kind == "aruco":
        return ArucoFrontend.from_file(map_path, **kw)
    if kind == "board":
        from .boards import make_board_frontend

        return make_board_frontend(map_path, **kw)
    if kind == "features":
        return FeatureFrontend.from_file(map_path, **kw)
    raise ValueError(f"unknown front end {kind!r}; expected one of {FRONTENDS}")
