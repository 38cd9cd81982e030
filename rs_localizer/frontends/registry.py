"""The one table of front ends by name (the ``frontend`` parameter's choices): how each reads
its map file (:mod:`rs_localizer.maps`) and builds its front end around the loaded map, for a
single image (:func:`rs_localizer.frontends.make_frontend`) and for the node's video
(:meth:`rs_localizer.frontends.shared.MapCache.frontend`, the map shared by its cameras), and
the keyword arguments of its video front end from the node's parameter values
(:func:`frontend_options`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["FRONTENDS", "FRONTEND_KINDS", "FrontendKind", "frontend_kind", "frontend_options"]


@dataclass(frozen=True)
class FrontendKind:
    """A front end by name.

    Attributes:
        load: ``load(path)`` -> the loaded map (raises ValueError for a bad map,
            FileNotFoundError for a missing one).
        make: ``make(loaded map, **kw)`` -> the per-image front end (``kw``: its constructor's
            options).
        make_video: ``make_video(loaded map, **kw)`` -> the node's front end for a video.
        map_file: what its map file is, for the user (``frontend_map`` missing).
        options: ``options(values)`` -> the keyword arguments of ``make_video`` from the node's
            parameter values by name (``aruco.*``, ``features.*``; raises ValueError naming
            the parameter).
    """

    load: Callable[[str | os.PathLike], Any]
    make: Callable[..., Any]
    make_video: Callable[..., Any]
    map_file: str
    options: Callable[[Mapping[str, Any]], dict] = lambda values: {}  # (no options)


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


def _aruco_options(p: Mapping[str, Any]) -> dict:
    """The ArUco front end's keyword arguments of the ``aruco.*`` parameters."""
    from .marker_detection import DetectorOptions

    try:
        detector = DetectorOptions.from_mapping(p, "aruco.")
    except ValueError as e:
        raise ValueError(f"aruco.detector options: {e}") from None
    return {
        "detector_options": detector,
        "windowed": bool(p["aruco.windowed"]),
        "windowed_min_pixels": int(p["aruco.windowed_min_pixels"]),
        "window_margin_px": float(p["aruco.window_margin_px"]),
        "full_frame_every": int(p["aruco.full_frame_every"]),
    }


def _features_options(p: Mapping[str, Any]) -> dict:
    """The features front end's keyword arguments of the ``features.*`` parameters."""
    matcher = str(p["features.matcher"]).strip().lower()
    if matcher not in ("auto", "bf", "flann"):
        raise ValueError(
            f"unknown features.matcher {p['features.matcher']!r}; expected auto, bf or flann"
        )
    return {
        "tracking": bool(p["features.tracking"]),
        "matcher": None if matcher == "auto" else matcher,
        "flann_checks": int(p["features.flann_checks"]),
        "n_features": int(p["features.max_features"]),
        "refresh_frames": int(p["features.refresh_frames"]),
        "search_radius_px": float(p["features.search_radius_px"]),
        "min_tracked_inliers": int(p["features.min_tracked_inliers"]),
    }


#: name -> :class:`FrontendKind`
FRONTEND_KINDS = {
    "aruco": FrontendKind(
        _load_markers, _aruco, _aruco, "marker map YAML, scene YAML or aruco_room", _aruco_options
    ),
    "features": FrontendKind(
        _load_features, _features, _features_video, "feature map .npz", _features_options
    ),
    "board": FrontendKind(_load_board, _board, _board, "board YAML"),
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


def frontend_options(name: str, values: Mapping[str, Any]) -> dict:
    """The keyword arguments of front end ``name``'s video front end from the node's parameter
    values by name (``aruco.*`` for ``aruco``, ``features.*`` for ``features``; none for
    ``board``); ``{}`` for ``none``.

    Raises:
        ValueError: an unknown name; a value its front end cannot use (the message names the
            parameter).
    """
    return {} if name == "none" else frontend_kind(name).options(values)
