"""What a front end makes of an image: :class:`Correspondences` (2D-3D rows), the
:class:`Frontend` protocol every front end (markers, boards, a feature map) follows, and
:class:`VideoFrontend`, everything a camera's video
(:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`) calls on its front end.

The 2D points are pixels of the distorted image (the estimator undistorts them with the camera
model), the 3D points are in the world/map frame (m).
"""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = [
    "Correspondences",
    "Frontend",
    "FrontendHooks",
    "TrackingFrontend",
    "VideoFrontend",
    "video_frontend",
]


@dataclass(frozen=True, eq=False)
class Correspondences:
    """2D-3D correspondences of one frame.

    Attributes:
        pixels: (N, 2) px, distorted image points.
        points: (N, 3) m, world points.
        ids: (N,) int64 landmark / corner ids, or None.
        scores: (N,) match quality (higher is better, e.g. ``1 - ratio`` of a feature match),
            or None; used by PROSAC-style sampling.

    It unpacks, and indexes, as ``pixels, points, ids`` (``uv, xyz, ids =
    frontend.process(image)``); ``len`` is the number of rows. ``uv`` and ``xyz`` name
    ``pixels`` and ``points`` as the fields of a ``correspondences`` PointCloud2 do
    (:func:`rs_localizer.ros.pointcloud.read_correspondences` returns this type).
    """

    pixels: np.ndarray
    points: np.ndarray
    ids: np.ndarray | None = None
    scores: np.ndarray | None = None

    @classmethod
    def empty(cls) -> Correspondences:
        """No correspondences (with empty ids)."""
        return cls(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64))

    @classmethod
    def of(cls, result: Any) -> Correspondences:
        """``result`` itself, or the :class:`Correspondences` of a ``(pixels, points, ids)``
        tuple (a front end written before this type: no scores)."""
        if isinstance(result, Correspondences):
            return result
        pixels, points, ids = result
        return cls(pixels, points, ids)

    @property
    def uv(self) -> np.ndarray:
        """``pixels`` (N, 2) px, by the name of the cloud fields ``u, v``."""
        return self.pixels

    @property
    def xyz(self) -> np.ndarray:
        """``points`` (N, 3) m, by the name of the cloud fields ``x, y, z``."""
        return self.points

    def __len__(self) -> int:
        return len(self.pixels)

    def __iter__(self) -> Iterator[Any]:
        return iter((self.pixels, self.points, self.ids))

    def __getitem__(self, i: int) -> Any:
        """``pixels``, ``points``, ``ids`` by position (as the former 3-tuple)."""
        return (self.pixels, self.points, self.ids)[i]

    def valid_scores(self) -> np.ndarray | None:
        """``scores`` when there is one per row, else None."""
        s = self.scores
        return s if s is not None and len(s) == len(self.pixels) else None


@runtime_checkable
class Frontend(Protocol):
    """A front end: an image in, 2D-3D correspondences out.

    ``process(image, camera, encoding)``: ``image`` (H, W) or (H, W, 3) uint8 in ``encoding``
    (``bgr8``, ``rgb8``, ``mono8``), ``camera`` the frame's
    :class:`~rs_localizer.camera.CameraModel` (or None); returns :class:`Correspondences`.

    A front end that tracks from frame to frame is a :class:`TrackingFrontend`; what a video
    calls is :class:`VideoFrontend` (:func:`video_frontend` makes one of any front end).
    """

    def process(self, image: np.ndarray, camera: Any = None, encoding: str = "bgr8") -> Any:
        """The frame's :class:`Correspondences`."""
        ...


@runtime_checkable
class TrackingFrontend(Frontend, Protocol):
    """A :class:`Frontend` that follows points from frame to frame and wants to know how each
    frame was solved.

    ``observe(stamp_ns, pixels, estimate)``: called by the node after each image frame it
    estimated, with the frame's header stamp (ns), ``pixels`` (M, 2) the rows the estimator
    was given (the front end's rows without non-finite ones, capped to ``max_points``) and
    ``estimate`` (an ``RSPoseEstimate``: ``estimate.inliers`` (M,) is the inlier mask over
    ``pixels``; ``estimate.success`` false on a failed frame) or None when the estimator raised.
    """

    def observe(self, stamp_ns: int, pixels: np.ndarray, estimate: Any) -> None:
        """Take note of how the previous frame was solved."""
        ...


@runtime_checkable
class VideoFrontend(Protocol):
    """What :class:`~rs_localizer.tracking.sequence.SequenceLocalizer` calls on the front end
    of a camera's video, per image frame, in this order:

    1. ``process(image, camera, encoding, prediction)``: the frame's
       :class:`Correspondences` (``image`` (H, W) or (H, W, C) uint8 in ``encoding``;
       ``camera`` the frame's :class:`~rs_localizer.camera.CameraModel`). ``prediction``:
       where the video's tracker expects the camera, the frame's model
       (:class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)`` at its reference row,
       :meth:`~rs_localizer.tracking.sequence.SequenceLocalizer.predict`: the one the
       estimator starts from), for a front end that searches near the predicted pixels
       (``camera.project_rs(X, *prediction)``); None when nothing predicts the frame (the
       first frame, a time reset, a gap: search the image whole). A front end keeps no pose
       of its own. May raise: the frame is dropped (``frontend_error``), the video goes on.
    2. ``pop_warning()``: a warning the front end wants shown once (e.g. a feature map whose
       descriptors do not match the detector's), or None.
    3. ``observe(stamp_ns, pixels, estimate)``: how the frame was solved, after the
       estimator ran (not for a frame dropped before it): ``pixels`` (M, 2) the rows the
       estimator was given (non-finite rows dropped, capped to ``max_points``) and
       ``estimate`` (``estimate.inliers`` (M,) the inlier mask over ``pixels``; ``success``
       false on a failed frame) or None when the estimator raised.

    The package's front ends all follow it (:class:`FrontendHooks` gives the no-op hooks; a
    front end that searches every image whole may leave ``prediction`` out of ``process``:
    :func:`video_frontend` does not pass it then).
    """

    def process(
        self,
        image: np.ndarray,
        camera: Any = None,
        encoding: str = "bgr8",
        prediction: Any = None,
    ) -> Any:
        """The frame's :class:`Correspondences`."""
        ...

    def pop_warning(self) -> str | None:
        """A warning to show once, or None."""
        ...

    def observe(self, stamp_ns: int, pixels: np.ndarray, estimate: Any) -> None:
        """Take note of how the frame was solved."""
        ...


class FrontendHooks:
    """The :class:`VideoFrontend` hooks of a front end that neither predicts nor warns:
    ``observe`` does nothing, ``pop_warning`` returns None (a front end overrides either)."""

    def observe(self, stamp_ns: int | None, pixels: np.ndarray | None, estimate: Any) -> None:
        """Nothing to take note of."""

    def pop_warning(self) -> str | None:
        """No warning."""
        return None


class _PerImage(FrontendHooks):
    """A :class:`Frontend` (``process(image, camera, encoding)`` only) as a
    :class:`VideoFrontend`: the prediction is not passed on, no hooks."""

    def __init__(self, frontend: Frontend):
        self.frontend = frontend

    def process(
        self,
        image: np.ndarray,
        camera: Any = None,
        encoding: str = "bgr8",
        prediction: Any = None,
    ) -> Any:
        return self.frontend.process(image, camera, encoding=encoding)


class _Unpredicted:
    """A :class:`VideoFrontend` whose ``process`` takes no ``prediction`` (it searches every
    image whole): the prediction is not passed on, the hooks are its own."""

    def __init__(self, frontend: Any):
        self.frontend = frontend
        self.observe, self.pop_warning = frontend.observe, frontend.pop_warning

    def process(
        self,
        image: np.ndarray,
        camera: Any = None,
        encoding: str = "bgr8",
        prediction: Any = None,
    ) -> Any:
        return self.frontend.process(image, camera, encoding=encoding)


def _takes_prediction(process: Any) -> bool:
    """``process`` has a ``prediction`` parameter (or takes any keyword)."""
    try:
        params = inspect.signature(process).parameters.values()
    except (TypeError, ValueError):  # (no signature to read: assume the full protocol)
        return True
    return any(p.name == "prediction" or p.kind is p.VAR_KEYWORD for p in params)


def video_frontend(frontend: Any) -> VideoFrontend:
    """``frontend`` itself when it is a :class:`VideoFrontend` (wrapped so that ``process``
    is not given the ``prediction`` when it takes none), else a per-image :class:`Frontend`
    wrapped into one (no feedback). The signature
    is read once, here.

    Raises:
        TypeError: ``frontend`` has no ``process`` method.
    """
    if isinstance(frontend, VideoFrontend):
        return frontend if _takes_prediction(frontend.process) else _Unpredicted(frontend)
    if not isinstance(frontend, Frontend):
        raise TypeError(
            f"a front end needs process(image, camera, encoding), got {type(frontend).__name__}"
        )
    return _PerImage(frontend)
