"""What a front end makes of an image: :class:`Correspondences` (2D-3D rows), the
:class:`Frontend` protocol every front end (markers, boards, a feature map) follows,
:class:`VideoFrontend`, everything a camera's video
(:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`) calls on its front end, and
:class:`FrameFeedback`, what the video tells its front end after each frame.

The 2D points (``points2d``, as :func:`~rs_localizer.estimation.estimate.estimate_rs_pose`
names them) are pixels of the distorted image (the estimator undistorts them with the camera
model), the 3D points are in the world/map frame (m).

``pixels``, the former name of ``points2d`` (:attr:`Correspondences.pixels`, the
``Correspondences(pixels=...)`` keyword and ``observe(..., pixels=...)`` of the package's front
ends), still works for one more release and warns (``DeprecationWarning``).
"""

from __future__ import annotations

import functools
import inspect
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .pose import RSModel

__all__ = [
    "Correspondences",
    "FrameFeedback",
    "Frontend",
    "FrontendHooks",
    "TrackingFrontend",
    "VideoFrontend",
    "accepts_pixels_keyword",
    "checked_groups",
    "video_frontend",
]


_PIXELS_DEPRECATED = (
    "'pixels' is deprecated and will be removed in the next release: use 'points2d' "
    "(the same (N, 2) px array)"
)


def _warn_pixels(stacklevel: int = 3) -> None:
    warnings.warn(_PIXELS_DEPRECATED, DeprecationWarning, stacklevel=stacklevel)


@dataclass(frozen=True, eq=False, init=False)
class Correspondences:
    """2D-3D correspondences of one frame.

    ``Correspondences(points2d, points, ids=None, scores=None, groups=None)``.

    Attributes:
        points2d: (N, 2) px, distorted image points.
        points: (N, 3) m, world points.
        ids: (N,) int64 landmark / corner ids, or None.
        scores: (N,) match quality (higher is better, e.g. ``1 - ratio`` of a feature match),
            or None; used by PROSAC-style sampling.
        groups: (N,) int64 each correspondence's group, or None (every correspondence's image
            error its own): correspondences of one group share a part of their image error,
            as one marker's 4 corners share a shift of the marker's image (the group is the
            marker's id). The estimator's covariance includes that shared error
            (:attr:`~rs_localizer.estimation.view.View.groups`); the estimate does not
            change with it.

    It unpacks, and indexes, as ``points2d, points, ids`` (``uv, xyz, ids =
    frontend.process(image)``); ``len`` is the number of rows. ``uv`` and ``xyz`` name
    ``points2d`` and ``points`` as the fields of a ``correspondences`` PointCloud2 do
    (:func:`rs_localizer.ros.pointcloud.read_correspondences` returns this type).

    Deprecated: ``pixels`` (the keyword and the attribute), the former name of ``points2d``,
    works for one more release and warns (``DeprecationWarning``).

    :meth:`take` keeps the rows given (every per-row field alike).

    Raises:
        TypeError: ``points2d`` or ``points`` missing, or both ``points2d`` and ``pixels``.
        ValueError: ``groups`` that are not one integer per row of ``points2d``.
    """

    points2d: np.ndarray
    points: np.ndarray
    ids: np.ndarray | None = None
    scores: np.ndarray | None = None
    groups: np.ndarray | None = None

    def __init__(
        self,
        points2d: np.ndarray | None = None,
        points: np.ndarray | None = None,
        ids: np.ndarray | None = None,
        scores: np.ndarray | None = None,
        groups: np.ndarray | None = None,
        *,
        pixels: np.ndarray | None = None,
    ):
        if pixels is not None:
            _warn_pixels()
            if points2d is not None:
                raise TypeError("Correspondences takes points2d or pixels, not both")
            points2d = pixels
        if points2d is None or points is None:
            raise TypeError("Correspondences needs points2d (N, 2) and points (N, 3)")
        set_ = object.__setattr__  # (frozen)
        set_(self, "points2d", points2d)
        set_(self, "points", points)
        set_(self, "ids", ids)
        set_(self, "scores", scores)
        set_(self, "groups", checked_groups(groups, np.size(points2d) // 2))

    @property
    def pixels(self) -> np.ndarray:
        """Deprecated name of ``points2d`` (warns; removed in the next release)."""
        _warn_pixels()
        return self.points2d

    @classmethod
    def empty(cls) -> Correspondences:
        """No correspondences (with empty ids)."""
        return cls(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64))

    @classmethod
    def of(cls, result: Any) -> Correspondences:
        """``result`` itself, or the :class:`Correspondences` of a ``(points2d, points, ids)``
        tuple (a front end written before this type: no scores)."""
        if isinstance(result, Correspondences):
            return result
        points2d, points, ids = result
        return cls(points2d, points, ids)

    @property
    def uv(self) -> np.ndarray:
        """``points2d`` (N, 2) px, by the name of the cloud fields ``u, v``."""
        return self.points2d

    @property
    def xyz(self) -> np.ndarray:
        """``points`` (N, 3) m, by the name of the cloud fields ``x, y, z``."""
        return self.points

    def __len__(self) -> int:
        return len(self.points2d)

    def __iter__(self) -> Iterator[Any]:
        return iter((self.points2d, self.points, self.ids))

    def __getitem__(self, i: int) -> Any:
        """``points2d``, ``points``, ``ids`` by position (as the former 3-tuple)."""
        return (self.points2d, self.points, self.ids)[i]

    def take(self, rows: np.ndarray) -> Correspondences:
        """The correspondences of ``rows`` ((M,) indices into the N rows, or an (N,) bool
        mask), in that order: ``points2d`` (M, 2), ``points`` (M, 3) and, each when it has one
        entry per row, ``ids``, ``scores`` and ``groups`` (M,) (one that has not: None).

        Raises:
            IndexError: an index out of range, a mask of another length.
        """
        n = len(self)

        def per_row(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None or len(a) != n else np.asarray(a)[rows]

        uv = np.asarray(self.points2d).reshape(-1, 2)[rows]
        xyz = np.asarray(self.points).reshape(-1, 3)[rows]
        return Correspondences(
            uv, xyz, per_row(self.ids), per_row(self.scores), per_row(self.groups)
        )

    def valid_scores(self) -> np.ndarray | None:
        """``scores`` when there is one per row, else None."""
        s = self.scores
        return s if s is not None and len(s) == len(self.points2d) else None


def checked_groups(groups: Any, n: int) -> np.ndarray | None:
    """``groups`` (each correspondence's group, :attr:`Correspondences.groups`; the
    estimator's :attr:`~rs_localizer.estimation.view.View.groups`) as an (n,) int64 array, or
    None for None.

    Raises:
        ValueError: not a 1-D array of ``n`` integers.
    """
    if groups is None:
        return None
    g = np.asarray(groups)
    if g.shape != (n,) or not (np.issubdtype(g.dtype, np.integer) or g.size == 0):
        raise ValueError(
            f"groups must be ({n},) integers, one per correspondence; got {g.dtype} {g.shape}"
        )
    return g.astype(np.int64, copy=False)


@runtime_checkable
class FrameFeedback(Protocol):
    """How a frame was solved: what a video gives its front end's ``observe`` after the
    estimator ran (:class:`VideoFrontend`): the frame's estimate itself
    (:class:`~rs_localizer.estimation.result.RSPoseEstimate`), from a camera's video
    (:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`), or from a rig's
    (:class:`~rs_localizer.tracking.video.Localizer`) each camera's part of the rig frame's
    estimate (:func:`~rs_localizer.estimation.result.camera_estimate`). A front end reads these
    attributes only.

    Attributes:
        success: the frame was posed (a rig's camera: the rig frame it is part of).
        inliers: (M,) bool, the inlier mask over the ``points2d`` given with it (the rows the
            estimator was given).
        model: the camera's :class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)`` at its
            reference row (``R`` (3, 3), ``C`` (3,) world -> camera; ``w``, ``t`` (3,) per unit
            RS coordinate): the estimate's, or for a rig's camera the rig's pose through the
            camera's mounting; the identity and zeros on failure.
    """

    success: bool
    inliers: np.ndarray
    model: RSModel


def accepts_pixels_keyword(observe: Callable) -> Callable:
    """Decorator of a front end's ``observe(self, stamp_ns, points2d, feedback)``: a call with
    the deprecated keyword ``pixels=`` (the former name of ``points2d``) still works for one
    more release and warns (``DeprecationWarning``). The package's front ends use it."""

    @functools.wraps(observe)
    def wrapper(self, *args, **kwargs):
        if "pixels" in kwargs:
            _warn_pixels()
            kwargs["points2d"] = kwargs.pop("pixels")
        return observe(self, *args, **kwargs)

    return wrapper


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

    ``observe(stamp_ns, points2d, feedback)``: called by the node after each image frame it
    estimated, with the frame's header stamp (ns), ``points2d`` (M, 2) px the rows the
    estimator was given (the front end's rows without non-finite ones, capped to
    ``max_points``) and ``feedback`` (a :class:`FrameFeedback`: ``feedback.inliers`` (M,) is
    the inlier mask over ``points2d``; ``feedback.success`` false on a failed frame) or None
    when the estimator raised. The arguments are passed by position.
    """

    def observe(self, stamp_ns: int, points2d: np.ndarray, feedback: FrameFeedback | None) -> None:
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
    3. ``observe(stamp_ns, points2d, feedback)`` (by position): how the frame was solved,
       after the estimator ran (not for a frame dropped before it): ``points2d`` (M, 2) px the
       rows the estimator was given (non-finite rows dropped, capped to ``max_points``) and
       ``feedback`` (a :class:`FrameFeedback`: ``feedback.inliers`` (M,) the inlier mask over
       ``points2d``; ``success`` false on a failed frame) or None when the estimator raised
       (or the image was not searched: the next one is searched whole).

    The package's front ends all follow it (:class:`FrontendHooks` gives the no-op hooks; a
    front end that searches every image whole may leave ``prediction`` out of ``process``:
    :func:`video_frontend` does not pass it then).
    """

    def process(
        self,
        image: np.ndarray,
        camera: Any = None,
        encoding: str = "bgr8",
        prediction: RSModel | None = None,
    ) -> Any:
        """The frame's :class:`Correspondences`."""
        ...

    def pop_warning(self) -> str | None:
        """A warning to show once, or None."""
        ...

    def observe(self, stamp_ns: int, points2d: np.ndarray, feedback: FrameFeedback | None) -> None:
        """Take note of how the frame was solved."""
        ...


class FrontendHooks:
    """The :class:`VideoFrontend` hooks of a front end that neither predicts nor warns:
    ``observe`` does nothing, ``pop_warning``, ``marker_detector_note`` and ``summary`` return
    None (a front end overrides any of them).

    Attributes:
        few_match_frames: images with keypoints of which too few matched the map (a feature
            front end counts them); None: not counted.
    """

    few_match_frames: int | None = None

    @accepts_pixels_keyword
    def observe(
        self, stamp_ns: int | None, points2d: np.ndarray | None, feedback: FrameFeedback | None
    ) -> None:
        """Nothing to take note of."""

    def pop_warning(self) -> str | None:
        """No warning."""
        return None

    def summary(self) -> dict[str, Any] | None:
        """The front end's own diagnostics values since start, or None: none (the node then
        reports ``frontend_frames_global``, the images it ran on)."""
        return None

    def marker_detector_note(self) -> tuple[str, bool] | None:
        """``(one line naming the marker detector that runs, whether it stands in for the one
        asked for)`` for the log, or None: no marker detector to name (a front end with one
        overrides it)."""
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
        prediction: RSModel | None = None,
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
        prediction: RSModel | None = None,
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
