"""The map files of a configuration, loaded: the landmark table of ``landmarks_file`` and the
image front end built around the map of ``frontend_map``.

:class:`~rs_localizer.ros.config.LocalizerConfig` holds values and paths only; the node and
``rs-localizer replay`` load what they name with :func:`load_maps` where they build their
:class:`~rs_localizer.ros.pipeline.FramePipeline` (and again when a parameter names another
file), and hand the :class:`LoadedMaps` to it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..frontends.shared import SHARED_MAPS
from ..maps import check_regular_file
from .config import LocalizerConfig
from .params import ConfigError

__all__ = ["LoadedMaps", "load_maps"]


@dataclass(frozen=True, eq=False)
class LoadedMaps:
    """What :func:`load_maps` loaded for a configuration.

    Attributes:
        landmarks: ``(sorted ids (N,), points (N, 3) m)`` of ``landmarks_file``, or None.
        frontend: the image front end (a
            :class:`~rs_localizer.correspondences.VideoFrontend`) around the map of
            ``frontend_map``, or None (``frontend`` none).
        frontend_kind, frontend_map: what ``frontend`` was built for.
    """

    landmarks: tuple[np.ndarray, np.ndarray] | None = None
    frontend: Any = None
    frontend_kind: str = "none"
    frontend_map: str = ""


def load_maps(
    cfg: LocalizerConfig, *, owner: object | None = None, current: LoadedMaps | None = None
) -> LoadedMaps:
    """The maps ``cfg`` names: the landmark table of ``landmarks_file`` and the front end of
    ``frontend_map``, loaded through :data:`~rs_localizer.frontends.shared.SHARED_MAPS` on
    behalf of ``owner`` (one copy per process, released with ``SHARED_MAPS.release(owner)``).
    The front end of ``current`` is reused when its kind and map are unchanged.

    Raises:
        ConfigError: a landmark table or front-end map that does not load (missing, not a
            regular file, malformed), naming the parameter.
    """
    landmarks, frontend = None, None
    path = cfg.landmarks_file
    if path:
        try:  # (loaded once per process: cameras naming the same file share it)
            landmarks = SHARED_MAPS.landmarks(path, owner=owner)
        except (OSError, ValueError) as e:
            raise ConfigError(f"cannot load landmarks_file {path!r}: {e}") from None
    kind, fmap = cfg.frontend_kind, cfg.frontend_map
    if kind != "none":
        if current is not None and (kind, fmap) == (current.frontend_kind, current.frontend_map):
            frontend = current.frontend
        else:
            try:
                if os.path.lexists(os.path.expanduser(fmap)):  # (not a built-in name)
                    check_regular_file(os.path.expanduser(fmap))  # a FIFO would block
                # (the map is loaded once per process and shared by cameras naming it)
                frontend = SHARED_MAPS.frontend(
                    kind, os.path.expanduser(fmap), owner=owner, **cfg.frontend_options
                )
            except Exception as e:
                raise ConfigError(
                    f"cannot load frontend_map {fmap!r} ({kind}): {type(e).__name__}: {e}"
                ) from None
    return LoadedMaps(landmarks, frontend, kind, fmap)
