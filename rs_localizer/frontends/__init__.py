"""Image front ends: an image in, 2D-3D correspondences out.

Every front end has ``process(image, camera, encoding)`` returning
:class:`~rs_localizer.correspondences.Correspondences` (``points2d``: distorted pixels (N, 2),
world points in metres (N, 3), int64 ids (N,) and optional match scores; it unpacks as
``points2d, points, ids``),
ready for :func:`rs_localizer.estimate_rs_pose` (the protocols:
:class:`~rs_localizer.correspondences.Frontend`,
:class:`~rs_localizer.correspondences.TrackingFrontend`). :func:`make_frontend` builds one by
name. Outside this package the front-end modules are reached through these names (and the
registry), never imported by path.
"""

import os
from typing import Any

from .aruco import ArucoFrontend, marker_scores
from .features import FeatureFrontend, feature_map_from_views, representative_descriptors
from .image import to_gray
from .registry import FRONTENDS, frontend_kind

__all__ = [
    "FRONTENDS",
    "ArucoFrontend",
    "FeatureFrontend",
    "feature_map_from_views",
    "make_frontend",
    "marker_scores",
    "representative_descriptors",
    "to_gray",
]


def make_frontend(kind: str, map_path: str | os.PathLike, **kw: Any) -> Any:
    """Front end by name (:data:`~rs_localizer.frontends.registry.FRONTEND_KINDS`): ``aruco``
    (``map_path``: marker map YAML, scene YAML or built-in scene name:
    :func:`rs_localizer.maps.load_marker_map`; scored by the map's stated std when it has them)
    or ``features`` (``map_path``: a feature map ``.npz``,
    :meth:`rs_localizer.maps.features.FeatureMap.load`) or ``board`` (``map_path``: a board
    YAML, :func:`rs_localizer.maps.boards.load_board`: checkerboard, ChArUco or tag board);
    ``kw`` go to the front end's constructor.

    Raises:
        ValueError: an unknown kind or a bad map. FileNotFoundError: a missing map.
    """
    k = frontend_kind(kind)
    return k.make(k.load(map_path), **kw)
