"""Maps shared by several cameras in one process (the node's ``cameras`` parameter).

A feature map (descriptors and 3D points, possibly tens of MB), a marker map, a board or a
landmark table is loaded once per file and shared by every camera that names the same file;
each camera still gets its own front-end object (its detector, matcher and per-image state), so
cameras can process images concurrently. A file that changed on disk (modification time or
size) is loaded again.

Lifetime: a caller passes ``owner`` (e.g. the node); each owner holds at most one front-end map
and one landmark table (a new one replaces its previous one), and :meth:`MapCache.release`
drops its holds. A map no owner holds leaves the cache (it is freed once the last front end
using it is gone). Without ``owner`` a map stays cached for the life of the process.

:meth:`MapCache.load_maps` loads what a camera's configuration names (its landmark table and
its front end around its map) as :class:`LoadedMaps`: the node and ``rs-localizer replay`` do
so through :func:`rs_localizer.ros.config.load_maps`.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..maps import check_regular_file
from .registry import frontend_kind

__all__ = ["SHARED_MAPS", "LoadedMaps", "MapCache"]


@dataclass(frozen=True, eq=False)
class LoadedMaps:
    """What :meth:`MapCache.load_maps` loaded for a camera.

    Attributes:
        landmarks: ``(sorted ids (N,), points (N, 3) m)`` of the landmark table, or None.
        frontend: the image front end (a
            :class:`~rs_localizer.correspondences.VideoFrontend`) around the front end's map,
            or None (no front end).
        frontend_kind, frontend_map: what ``frontend`` was built for.
    """

    landmarks: tuple[np.ndarray, np.ndarray] | None = None
    frontend: Any = None
    frontend_kind: str = "none"
    frontend_map: str = ""


class MapCache:
    """Loaded maps by ``(kind, file identity)``; thread-safe."""

    def __init__(self):
        self._maps = {}
        self._holds = {}  # id(owner) -> {slot: key}
        self._pinned = set()  # keys loaded without an owner
        self._lock = threading.Lock()
        self.loads = 0  # maps actually read from disk (the rest were shared)

    def __len__(self):
        return len(self._maps)

    def _hold(self, owner, slot, key):  # (under the lock)
        if owner is None:
            self._pinned.add(key)
            return
        old = self._holds.setdefault(id(owner), {}).get(slot)
        self._holds[id(owner)][slot] = key
        if old is not None and old != key:
            self._drop_unheld(old)

    def _drop_unheld(self, key):  # (under the lock)
        if key in self._pinned or any(key in h.values() for h in self._holds.values()):
            return
        self._maps.pop(key, None)

    def release(self, owner: object) -> None:
        """Drop every hold of ``owner``; maps nobody else holds leave the cache."""
        with self._lock:
            for key in self._holds.pop(id(owner), {}).values():
                self._drop_unheld(key)

    @staticmethod
    def _key(kind: str, path) -> tuple:
        p = Path(os.path.expanduser(str(path)))
        try:
            st = p.stat()
        except OSError:  # a built-in scene name (aruco_room) or a missing file (load raises)
            return (kind, str(path))
        return (kind, str(p.resolve()), st.st_mtime_ns, st.st_size)

    def get(
        self,
        kind: str,
        path: str | os.PathLike,
        load: Callable[[str], Any],
        owner: object = None,
        slot: str | None = None,
    ) -> Any:
        """The map of ``path`` for ``kind``, calling ``load(path)`` only when no loaded copy
        is cached (exceptions of ``load`` propagate and nothing is cached); ``owner`` holds it
        in ``slot`` (default: ``kind``)."""
        key = self._key(kind, path)
        with self._lock:
            if key in self._maps:
                self._hold(owner, slot or kind, key)
                return self._maps[key]
        value = load(path)
        with self._lock:
            self.loads += 1
            value = self._maps.setdefault(key, value)
            self._hold(owner, slot or kind, key)
            return value

    def frontend(
        self, kind: str, map_path: str | os.PathLike, owner: object = None, **kw: Any
    ) -> Any:
        """A new front end for a video (``make_video`` of the kind in
        :data:`~rs_localizer.frontends.registry.FRONTEND_KINDS`) around the shared map of
        ``map_path``.

        Raises:
            ValueError: unknown kind or a bad map. FileNotFoundError: a missing map.
        """
        k = frontend_kind(kind)  # (an unknown kind loads nothing)
        return k.make_video(self.get(kind, map_path, k.load, owner, "frontend"), **kw)

    def landmarks(
        self, path: str | os.PathLike, owner: object = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(ids sorted (M,), points (M, 3))`` of a landmark CSV
        (:func:`rs_localizer.maps.load_landmarks_csv`), shared.

        Raises:
            OSError, ValueError: as ``load_landmarks_csv``.
        """
        import numpy as np

        from ..maps import load_landmarks_csv

        def load(p):
            ids, pts = load_landmarks_csv(os.path.expanduser(str(p)))
            order = np.argsort(ids, kind="stable")
            return ids[order], pts[order]

        return self.get("landmarks", path, load, owner)

    def load_maps(
        self,
        landmarks_file: str = "",
        kind: str = "none",
        frontend_map: str = "",
        frontend_options: Mapping[str, Any] | None = None,
        *,
        owner: object | None = None,
        current: LoadedMaps | None = None,
    ) -> LoadedMaps:
        """The maps a camera names, loaded through this cache on behalf of ``owner`` (one copy
        per process, released with :meth:`release`): the landmark table of ``landmarks_file``
        ("" none; :meth:`landmarks`) and the front end ``kind`` ("none": none) around the map
        of ``frontend_map`` with ``frontend_options`` (:meth:`frontend`). The front end of
        ``current`` is reused when its kind and map are unchanged.

        Raises:
            ValueError: a landmark table or front-end map that does not load (missing, not a
                regular file, malformed), naming the parameter (``landmarks_file``,
                ``frontend_map``).
        """
        landmarks, frontend = None, None
        path = landmarks_file
        if path:
            try:  # (loaded once per process: cameras naming the same file share it)
                landmarks = self.landmarks(path, owner=owner)
            except (OSError, ValueError) as e:
                raise ValueError(f"cannot load landmarks_file {path!r}: {e}") from None
        fmap = frontend_map
        if kind != "none":
            if current is not None and (kind, fmap) == (
                current.frontend_kind,
                current.frontend_map,
            ):
                frontend = current.frontend
            else:
                try:
                    if os.path.lexists(os.path.expanduser(fmap)):  # (not a built-in name)
                        check_regular_file(os.path.expanduser(fmap))  # a FIFO would block
                    # (the map is loaded once per process and shared by cameras naming it)
                    frontend = self.frontend(
                        kind, os.path.expanduser(fmap), owner=owner, **(frontend_options or {})
                    )
                except Exception as e:
                    raise ValueError(
                        f"cannot load frontend_map {fmap!r} ({kind}): {type(e).__name__}: {e}"
                    ) from None
        return LoadedMaps(landmarks, frontend, kind, fmap)


#: the process-wide cache the node uses
SHARED_MAPS = MapCache()
