"""The one table of front ends by name (the ``frontend`` parameter's choices): how each reads
its map file (:mod:`rs_localizer.maps`) and builds its front end around the loaded map, for a
single image (:func:`rs_localizer.frontends.make_frontend`) and for the node's video
(:meth:`rs_localizer.frontends.shared.MapCache.frontend`, the map shared by its cameras).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["FRONTENDS", "FRONTEND_KINDS", "FrontendKind", "frontend_kind"]


@dataclass(frozen=True)
class FrontendKind:
    """A front end by name.

    Attributes:
        load: ``load(path)`` -> the loaded map (raises ValueError for a bad map,
            FileNotFoundError for a missing one).
        make: ``make(loaded map, **kw)`` -> the per-image front end (``kw``: its constructor's
            options).
        make_video: ``make_video(loaded map, **kw)`` -> the node's front end for a video.
    """

    load: Callable[[str | os.PathLike], Any]
    make: Callable[..., Any]
    make_video: Callable[..., Any]


def _load_markers(path: str | os.PathLike) -> tuple:
    """(dictionary, {id: (4, 3) corners}, {id: stated position std (m)}) of a marker map."""
    from ..maps.markers import load_marker_map, load_marker_std

    dictionary, corners = load_marker_map(Path(str(path)))
    return dictionary, corners, load_marker_std(path)


def _aruco(loaded: tuple, **kw: Any) -> Any:
    """ArUco front end (per image and the node's alike) scoring each marker's corners by the
    map's stated std when it has them (a map from ``map-markers``)."""
    from .aruco import ArucoFrontend

    return ArucoFrontend.from_map(*loaded, **kw)


def _load_features(path: str | os.PathLike) -> Any:
    from ..maps.features import FeatureMap

    return FeatureMap.load(path)


def _features(fm: Any, **kw: Any) -> Any:
    from .features import FeatureFrontend

    return FeatureFrontend(fm, **kw)


def _features_video(fm: Any, **kw: Any) -> Any:
    from .tracking import TrackingFeatureFrontend  # (tracking=False: per frame)

    return TrackingFeatureFrontend(fm, **kw)


def _load_board(path: str | os.PathLike) -> Any:
    from ..maps.boards import load_board

    return load_board(path)


def _board(board: Any, **kw: Any) -> Any:
    from .boards import make_board_frontend

    return make_board_frontend(board, **kw)


#: name -> :class:`FrontendKind`
FRONTEND_KINDS = {
    "aruco": FrontendKind(_load_markers, _aruco, _aruco),  # marker map or scene YAML
    "features": FrontendKind(_load_features, _features, _features_video),  # feature map .npz
    "board": FrontendKind(_load_board, _board, _board),  # board YAML
}

#: the front ends' names
FRONTENDS = tuple(FRONTEND_KINDS)


def frontend_kind(name: str) -> FrontendKind:
    """The :class:`FrontendKind` of ``name``.

    Raises:
        ValueError: an unknown name.
    """
    if name not in FRONTEND_KINDS:
        raise ValueError(f"unknown front end {name!r}; expected one of {FRONTENDS}")
    return FRONTEND_KINDS[name]
