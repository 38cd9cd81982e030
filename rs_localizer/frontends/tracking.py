"""Feature front end for video: track the last frame's inliers, match near predictions, detect
rarely.

Per frame, :class:`TrackingFeatureFrontend` gives the estimator correspondences of three kinds:

- **tracked**: the previous frame's inliers (pixel, map row) followed into this frame with
  pyramidal Lucas-Kanade optical flow (``cv2.calcOpticalFlowPyrLK``), kept only when tracking
  back lands within ``fb_max_px`` of the start (forward-backward check); they keep their map
  rows, so no descriptor is computed or matched. Each track flows from its *anchor*, the
  frame its pixel was detected in (a global or refresh detection), not from the previous
  frame: frame-to-frame flow adds a little error on every frame, and a track followed for
  a second drifts away from its map point. A track whose anchor is older than
  ``max_anchor_age`` frames (the view has changed too much for the old patch), or of an
  anchor beyond the ``max_anchors`` newest, is anchored again at its tracked pixel;
- **guided**: map points predicted in view and not tracked, matched to the keypoints of a
  *refresh* detection near their predicted pixel (within ``search_radius_px``; the
  nearest 8 keypoints of each window from one ``scipy.spatial.cKDTree`` query; descriptor
  distance and ratio tests). The
  prediction is a rolling-shutter projection (:meth:`rs_localizer.camera.CameraModel.project_rs`:
  each point at its own capture line) of the solved pose and twist of the frame the detection
  ran on. The refresh detection and this matching run in a background thread (in OpenCV,
  SciPy and NumPy calls, which release the GIL) on one frame, every
  ``refresh_frames`` frames or when fewer than ``min_tracked_inliers`` tracks survive; its
  matches are then tracked (LK, from their predicted pixels) from that frame into the
  current one and join the tracks: a refresh never holds up a frame;
- **global**: full detection and matching against the whole map
  (:class:`~rs_localizer.frontends.features.FeatureFrontend`, FLANN for SIFT maps), run
  synchronously only when there is nothing to track: the first frame, after a frame that was
  not solved, after a time reset (no ``prediction``: a stamp going back, or a gap longer than
  the video's :attr:`~rs_localizer.tracking.sequence.SequenceSettings.max_gap`), or when
  fewer than ``min_points`` tracks remain, or fewer than ``collapse_ratio`` times
  the median inlier count of the video's last solved frames (the tracks collapsed: an image
  that jumped, a stale prediction; a pose from their few survivors would be an accidental
  fit, so the frame is matched whole as a relocalization is).

The motion model is not the front end's: each frame's ``prediction`` (the frame's predicted
model ``(R, C, w, t)``, :meth:`~rs_localizer.tracking.sequence.SequenceLocalizer.predict`: the
video tracker's, the one the estimator starts from) places the tracks' optical flow and the
refresh's matches; the front end keeps no pose.

The estimator stays the judge: every pose comes from a full rolling-shutter estimate over these
correspondences; :meth:`TrackingFeatureFrontend.observe` gives the front end how the frame
was solved (:class:`~rs_localizer.correspondences.FrameFeedback`), and only its inliers are
tracked further (tracked outliers are dropped). Without
``observe`` (a caller that does not report estimates), or without a ``prediction``, every
frame is a global one (:class:`~rs_localizer.tracking.tracker.CarriedPrediction` predicts for
a caller driving the front end by hand).
``observe(stamp_ns, points2d, feedback)`` is the ``TrackingFrontend`` protocol the node calls.

This is the standard design of video trackers (PTAM, ORB-SLAM's localization mode, VINS's
feature tracker) with a rolling-shutter motion model for the guided search.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..camera import CameraModel
from ..correspondences import Correspondences, FrameFeedback, accepts_pixels_keyword
from ..maps.features import FeatureMap
from ..pose import RSModel
from .features import FeatureFrontend, make_detector
from .image import to_gray

__all__ = ["FRAME_KINDS", "FrameReport", "TrackingFeatureFrontend"]

#: kinds of frame: ``global`` (full detection + global matching), ``tracked`` (tracks and
#: guided matches only)
FRAME_KINDS = ("global", "tracked")


@dataclass
class FrameReport:
    """What the front end did on its last frame: ``kind`` (:data:`FRAME_KINDS`), the number
    of ``tracked``, ``guided`` and ``global`` correspondences, ``reason`` a global frame ran
    (``start``, ``lost``, ``time_reset``, ``few_tracks``, ``tracking_off``), and stage times
    (s): ``tracking`` (optical flow), ``guided`` (joining a refresh's matches), ``detection``
    (+ global matching; on global frames only). ``refresh_started``: a background refresh
    began on this frame; ``refresh_waited``: this frame waited for a refresh (see
    ``refresh_wait_frames``)."""

    kind: str = "global"
    tracked: int = 0
    guided: int = 0
    global_: int = 0
    reason: str = ""
    times: dict = field(default_factory=dict)
    refresh_started: bool = False
    refresh_waited: bool = False


@dataclass
class _Refresh:
    """A background detection on one frame and what is needed to use its result."""

    index: int
    gray: np.ndarray
    pose: tuple  # (R, C, w, t) of that frame's estimate (world -> camera, per unit r)
    camera: CameraModel
    result: Any = None  # (uv (G, 2) float32, rows (G,)): the guided matches in that frame
    done: threading.Event = field(default_factory=threading.Event)


class TrackingFeatureFrontend(FeatureFrontend):
    """Feature front end for a video (see the module doc): a
    :class:`~rs_localizer.frontends.features.FeatureFrontend` (its global matching) whose
    ``process`` tracks, plus :meth:`observe`. After ``process``, ``last_kinds`` (N,) says
    what each correspondence is (0 tracked, 1 guided, 2 global) and ``last_ages`` (N,) how
    many frames ago its pixel was detected.

    Args:
        feature_map: the map (or a path to its ``.npz``).
        matcher: global matching: ``flann`` (default for SIFT maps; refused for ORB maps) or
            ``bf``. flann_checks, ratio, n_features: as ``FeatureFrontend``.
        tracking: False: every frame global (the per-frame front end, with its matcher).
        refresh_frames: start a background refresh detection every this many frames (0: only
            when tracks run low).
        search_radius_px: guided matching window around each predicted pixel (px).
        min_tracked_inliers: fewer tracked inliers than this start a refresh.
        min_points: fewer correspondences than this after tracking: a global frame.
        collapse_ratio: fewer correspondences after tracking than this times the median
            inlier count of the last ``recent_frames`` solved frames (at least 3 of them): a
            global frame (reason ``few_tracks``); 0: never.
        max_tracks: at most this many tracks followed per frame (the best spread kept).
        lk_window, lk_levels: LK window (px) and pyramid levels. fb_max_px: forward-backward
            error bound (px).
        max_anchor_age: a track is followed from the frame it was detected in for at most
            this many frames, then anchored again at its tracked pixel.
        max_anchors: at most this many anchor frames tracked from (one optical-flow call
            each); the tracks of older ones are anchored again in the current frame.
        refresh_wait_frames: a refresh still running this many frames after it started,
            while fewer than ``min_tracked_inliers`` tracks remain, is waited for (a CPU too
            busy to detect within a few frame periods: the frame waits rather than the tracks
            thin out and drift). Default ``max(2 * refresh_frames, 10)``.

    Raises:
        ValueError: an unknown ``matcher``, ``flann`` with an ORB map, an empty map,
            descriptors of another type or width than the map's detector gives (uint8 x 32
            for ORB, float32 x 128 for SIFT), or a parameter out of range.
    """

    name = "features"

    def __init__(
        self,
        feature_map: FeatureMap | str | Path,
        matcher: str | None = None,
        flann_checks: int = 32,
        ratio: float = 0.8,
        n_features: int = 2000,
        tracking: bool = True,
        refresh_frames: int = 10,
        search_radius_px: float = 8.0,
        min_tracked_inliers: int = 150,
        min_points: int = 15,
        max_tracks: int = 1000,
        lk_window: int = 11,
        lk_levels: int = 2,
        fb_max_px: float = 1.0,
        refresh_wait_frames: int | None = None,
        max_anchor_age: int = 30,
        max_anchors: int = 4,
        collapse_ratio: float = 0.25,
        recent_frames: int = 10,
    ):
        if not isinstance(feature_map, FeatureMap):
            feature_map = FeatureMap.load(feature_map)
        if len(feature_map) == 0:
            raise ValueError("the feature map is empty")
        want = (np.uint8, 32) if feature_map.kind.lower() == "orb" else (np.float32, 128)
        des = np.asarray(feature_map.descriptors)
        if des.ndim != 2 or des.shape[1] != want[1] or not np.can_cast(des.dtype, want[0]):
            raise ValueError(
                f"the feature map's descriptors are {des.dtype} with shape {des.shape}; a "
                f"{feature_map.kind} map needs {np.dtype(want[0])} rows of {want[1]} values"
            )
        if matcher is None:
            matcher = "bf" if feature_map.kind.lower() == "orb" else "flann"
        if search_radius_px <= 0 or fb_max_px <= 0 or lk_window < 3 or min_points < 4:
            raise ValueError(
                "search_radius_px and fb_max_px must be > 0, lk_window >= 3, min_points >= 4"
            )
        if max_anchor_age < 1 or max_anchors < 1:
            raise ValueError("max_anchor_age and max_anchors must be >= 1")
        super().__init__(
            feature_map,
            ratio=ratio,
            n_features=n_features,
            matcher=matcher,
            flann_checks=flann_checks,
        )
        self.tracking = bool(tracking)
        self.refresh_frames = int(refresh_frames)
        self.refresh_wait_frames = (
            max(2 * self.refresh_frames, 10)
            if refresh_wait_frames is None
            else int(refresh_wait_frames)
        )
        self.search_radius_px = float(search_radius_px)
        self.min_tracked_inliers = int(min_tracked_inliers)
        self.min_points = int(min_points)
        self.max_tracks = int(max_tracks)
        self.lk = dict(
            winSize=(int(lk_window), int(lk_window)),
            maxLevel=int(lk_levels),
            criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03),
        )
        self.fb_max_px = float(fb_max_px)
        self.max_anchor_age = int(max_anchor_age)
        self.max_anchors = int(max_anchors)
        self.collapse_ratio = float(collapse_ratio)
        self._recent = deque(maxlen=max(int(recent_frames), 1))  # inliers of solved frames
        self._n_features = int(n_features)
        self._norm = cv2.NORM_HAMMING if feature_map.kind.lower() == "orb" else cv2.NORM_L2
        self.report = FrameReport()
        self.counts = {k: 0 for k in FRAME_KINDS}
        self._totals = {"tracked": 0, "guided": 0, "global": 0}
        self._times = {k: deque(maxlen=1000) for k in FRAME_KINDS}
        self.relocalizations = 0
        self.reset()

    @classmethod
    def from_file(cls, path: str | Path, **kw: Any) -> TrackingFeatureFrontend:
        return cls(FeatureMap.load(path), **kw)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the tracks, the motion and any refresh in flight (next frame: global)."""
        self._gray = None  # previous frame
        self._uv = np.zeros((0, 2), np.float32)  # tracks in the previous frame
        self._rows = np.zeros(0, np.int64)  # their map rows
        self._age = np.zeros(0, np.int64)  # frames since each track's pixel was detected
        self._anc = np.zeros(0, np.int64)  # each track's anchor: the frame index it is tracked from
        self._anc_uv = np.zeros((0, 2), np.float32)  # its pixel in that frame
        self._anchors: dict[int, np.ndarray] = {}  # anchor frame index -> gray image
        self._frame_camera = None  # the camera of the last processed frame
        self._index = -1
        self._solved_index = -2
        self._since_refresh = 0
        self._pending: _Refresh | None = None
        self._out_rows = np.zeros(0, np.int64)
        self._out_uv = np.zeros((0, 2))
        self._out_age = np.zeros(0, np.int64)
        self._out_anc = np.zeros(0, np.int64)
        self._out_anc_uv = np.zeros((0, 2), np.float32)
        self.last_kinds = np.zeros(0, np.int8)
        self.last_ages = np.zeros(0, np.int64)
        self._lost = True
        self._recent.clear()

    # ------------------------------------------------------------------ per frame
    def process(
        self,
        image: np.ndarray,
        camera: CameraModel | None = None,
        encoding: str = "rgb8",
        prediction: RSModel | None = None,
    ) -> Correspondences:
        """Correspondences of one frame (:class:`~rs_localizer.correspondences.Correspondences`:
        points2d (N, 2) distorted px, points (N, 3) world m, landmark ids (N,), scores (N,));
        ``report`` says how they were found. ``prediction``: the frame's predicted
        :class:`~rs_localizer.pose.RSModel` (module docstring), where the tracks and the
        refresh's matches are looked for; None: nothing predicts the frame (the first one,
        a time reset or a gap: a global frame)."""
        t_start = time.perf_counter()
        gray = to_gray(image, encoding)
        rep = FrameReport(times={})
        reason = None
        if not self.tracking:
            reason = "tracking_off"
        elif self._gray is None:
            reason = "start"
        elif self._lost:
            reason = "lost"
        elif prediction is None:
            reason = "time_reset"
        elif self._gray.shape != gray.shape:
            reason = "start"
        if reason is not None and reason not in ("tracking_off",):
            self._drop_tracks(keep_refresh=False)
        self._index += 1
        uv = np.zeros((0, 2), np.float32)
        rows = np.zeros(0, np.int64)
        kinds = np.zeros(0, np.int8)  # 0 tracked, 1 guided, 2 global
        ages = np.zeros(0, np.int64)
        anc, anc_uv = np.zeros(0, np.int64), np.zeros((0, 2), np.float32)
        if reason is None:
            t0 = time.perf_counter()
            guess = self._predict(self._rows, prediction, camera)
            uv, rows, idx = self._track_anchored(gray, guess)
            ages = self._age[idx] + 1
            anc, anc_uv = self._anc[idx], self._anc_uv[idx]
            kinds = np.zeros(len(uv), np.int8)
            rep.times["tracking"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            job = self._pending
            if (
                job is not None
                and self._index - job.index > self.refresh_wait_frames
                and len(uv) < self.min_tracked_inliers
            ):  # (a CPU too busy to finish the refresh in time: wait rather than drift)
                job.done.wait()
                rep.refresh_waited = True
            g_uv, g_rows, g_anc_uv, job = self._join_refresh(gray, prediction, camera)
            rep.times["guided"] = time.perf_counter() - t0
            if len(g_uv):  # (a guided match replaces the track of its landmark: re-anchored)
                lm = self.map.landmark_ids
                keep = ~np.isin(lm[rows], lm[g_rows])
                uv, rows, kinds, ages = uv[keep], rows[keep], kinds[keep], ages[keep]
                anc, anc_uv = anc[keep], anc_uv[keep]
                uv = np.concatenate([uv, g_uv])
                rows = np.concatenate([rows, g_rows])
                kinds = np.concatenate([kinds, np.ones(len(g_uv), np.int8)])
                ages = np.concatenate([ages, np.full(len(g_uv), self._index - job.index)])
                anc = np.concatenate([anc, np.full(len(g_uv), job.index, np.int64)])
                anc_uv = np.concatenate([anc_uv, g_anc_uv])
                self._anchors[job.index] = job.gray
            anc, anc_uv = self._reanchor(anc, anc_uv, uv, gray)
            recent = self._recent
            collapsed = len(recent) >= 3 and len(uv) < self.collapse_ratio * np.median(recent)
            if len(uv) < self.min_points or collapsed:
                reason = "few_tracks"
                self._drop_tracks(keep_refresh=False)
        if reason is not None:
            t0 = time.perf_counter()
            g_uv, _, ids = FeatureFrontend.process(self, gray, camera, encoding="mono8")
            rep.times["detection"] = time.perf_counter() - t0
            rep.kind, rep.reason, rep.global_ = "global", reason, len(g_uv)
            if reason in ("lost", "time_reset", "few_tracks"):
                self.relocalizations += 1
            rows = self._rows_of(ids)
            uv = np.asarray(g_uv, np.float32).reshape(-1, 2)
            kinds = np.full(len(uv), 2, np.int8)
            ages = np.zeros(len(uv), np.int64)
            anc, anc_uv = np.full(len(uv), self._index, np.int64), uv
            self._anchors = {self._index: gray}
            self._since_refresh = 0
        else:
            rep.kind = "tracked"
            rep.tracked = int(np.count_nonzero(kinds == 0))
            rep.guided = int(np.count_nonzero(kinds == 1))
            self.last_scores = np.where(kinds == 0, 0.5, 0.4).astype(float)
            self._since_refresh += 1
        self.counts[rep.kind] += 1
        self._totals["tracked"] += rep.tracked
        self._totals["guided"] += rep.guided
        self._totals["global"] += rep.global_
        self._times[rep.kind].append(time.perf_counter() - t_start)
        self._gray = gray
        self._frame_camera = camera
        self._out_rows, self._out_uv, self._out_age = rows, np.asarray(uv, float), ages
        self._out_anc, self._out_anc_uv = anc, np.asarray(anc_uv, np.float32).reshape(-1, 2)
        self.last_kinds, self.last_ages = kinds, ages
        self._lost = True  # until observe() says the frame was solved
        self.report = rep
        return Correspondences(
            np.asarray(uv, float).reshape(-1, 2),
            self.map.points[rows].reshape(-1, 3),
            self.map.landmark_ids[rows],
            np.asarray(self.last_scores, float),
        )

    @accepts_pixels_keyword
    def observe(
        self, stamp_ns: int | None, points2d: np.ndarray | None, feedback: FrameFeedback | None
    ) -> None:
        """The estimator's verdict on the last frame: its inliers are tracked into the next
        frame, the rest dropped; a failed frame (or None) makes the next frame global.

        Args:
            stamp_ns: the frame's stamp (ns; not used).
            points2d: (M, 2) px, the rows the estimator was given, when the caller removed or
                reordered rows of the front end's output (matched back by pixel); None: the
                output as returned.
            feedback: :class:`~rs_localizer.correspondences.FrameFeedback` of those rows
                (``success``, ``inliers`` (M,), the camera's ``model``), or None.
        """
        camera = self._frame_camera
        if feedback is None or not feedback.success:
            self._drop_tracks(keep_refresh=False)
            self._lost = True
            return
        inl = np.asarray(feedback.inliers, bool)
        uv = self._out_uv
        if points2d is not None and (len(points2d) != len(uv) or not np.array_equal(points2d, uv)):
            pos = {(float(a), float(b)): k for k, (a, b) in enumerate(uv)}
            idx = np.array([pos.get((float(a), float(b)), -1) for a, b in points2d], np.int64)
            keep = idx[(idx >= 0) & inl[: len(idx)]]
        elif len(inl) == len(uv):
            keep = np.flatnonzero(inl)
        else:
            keep = np.zeros(0, np.int64)
        self._uv = np.asarray(uv[keep], np.float32).reshape(-1, 2)
        self._recent.append(len(keep))
        self._rows = self._out_rows[keep]
        self._age = self._out_age[keep]
        self._anc, self._anc_uv = self._out_anc[keep], self._out_anc_uv[keep]
        used = set(np.unique(self._anc).tolist())
        self._anchors = {k: g for k, g in self._anchors.items() if k in used}
        rows = self._rows
        self._lost = False
        self._solved_index = self._index
        if not self.tracking or camera is None:
            return
        low = len(rows) < self.min_tracked_inliers
        due = self.refresh_frames > 0 and self._since_refresh >= self.refresh_frames
        if (low or due) and self._pending is None:
            pose = tuple(np.asarray(a, float) for a in feedback.model)
            self._start_refresh(camera, pose)

    def wait_refresh(self, timeout: float | None = None) -> bool:
        """Block until the background refresh in flight (if any) has detected (offline runs
        that want the same result on every run). Returns False on timeout."""
        job = self._pending
        return True if job is None else job.done.wait(timeout)

    def summary(self) -> dict:
        """Counters since start: frames per kind (``frontend_frames_<kind>``),
        ``frontend_relocalizations`` (global frames after tracking was lost or reset), mean
        correspondences per kind (tracked and guided over tracked frames, global over global
        frames) and median front-end time per frame kind (ms; ``nan`` before one)."""
        out = {f"frontend_frames_{k}": n for k, n in self.counts.items()}
        out["frontend_relocalizations"] = self.relocalizations
        n_tr, n_gl = max(self.counts["tracked"], 1), max(self.counts["global"], 1)
        out["frontend_correspondences_tracked_mean"] = f"{self._totals['tracked'] / n_tr:.1f}"
        out["frontend_correspondences_guided_mean"] = f"{self._totals['guided'] / n_tr:.1f}"
        out["frontend_correspondences_global_mean"] = f"{self._totals['global'] / n_gl:.1f}"
        for k in ("tracked", "global"):
            t = self._times[k]
            out[f"frontend_ms_median_{k}"] = f"{np.median(t) * 1e3:.3f}" if t else "nan"
        return out

    # ------------------------------------------------------------------ internals
    def _rows_of(self, ids: np.ndarray) -> np.ndarray:
        """Map rows of landmark ids (the first row of each id)."""
        if not hasattr(self, "_id_order"):
            lm = self.map.landmark_ids
            self._id_order = np.argsort(lm, kind="stable")
            self._id_sorted = lm[self._id_order]
        j = np.searchsorted(self._id_sorted, np.asarray(ids, np.int64))
        return self._id_order[np.clip(j, 0, len(self._id_order) - 1)]

    def _drop_tracks(self, keep_refresh: bool) -> None:
        self._uv = np.zeros((0, 2), np.float32)
        self._rows = np.zeros(0, np.int64)
        self._age = np.zeros(0, np.int64)
        self._anc = np.zeros(0, np.int64)
        self._anc_uv = np.zeros((0, 2), np.float32)
        self._anchors = {}
        if not keep_refresh:
            self._pending = None

    def _predict(
        self, rows: np.ndarray, prediction: RSModel | None, cam: CameraModel | None
    ) -> np.ndarray | None:
        """(K, 2) px: where the map points ``rows`` land in this frame under its
        ``prediction`` (the model ``(R, C, w, t)``; each point at its own capture line,
        :meth:`CameraModel.project_rs` of the frame's camera ``cam``); None without a
        prediction or a rolling-shutter timing."""
        if prediction is None or cam is None:
            return None
        if cam.seconds_per_unit_r <= 0 or len(rows) == 0:
            return None
        R, C, w, t = prediction
        uv = cam.project_rs(self.map.points[rows], R, C, w, t, iterations=4)
        return uv if np.isfinite(uv).all() else None

    def _cap(self, uv: np.ndarray, n: int, age: np.ndarray | None = None) -> np.ndarray:
        """Indices of at most ``n`` of the points ``uv`` (K, 2) spread over the image: an
        8 x 6 grid, the cells filled in turn (inside a cell the youngest ``age`` (K,) first,
        then a reproducible random order)."""
        if len(uv) <= n:
            return np.arange(len(uv))
        h, w = self._gray.shape[:2]
        cell = np.clip((uv[:, 0] * (8 / w)).astype(int), 0, 7) + 8 * np.clip(
            (uv[:, 1] * (6 / h)).astype(int), 0, 5
        )
        jitter = np.random.default_rng(len(uv)).random(len(uv))
        age = np.zeros(len(uv)) if age is None else age
        order = np.lexsort((jitter, age, cell))
        c = cell[order]
        start = np.r_[0, np.flatnonzero(c[1:] != c[:-1]) + 1]
        rank = np.arange(len(c)) - np.repeat(start, np.diff(np.r_[start, len(c)]))
        return np.sort(order[np.lexsort((jitter[order], rank))[:n]])

    def _track(
        self,
        prev: np.ndarray,
        cur: np.ndarray,
        uv: np.ndarray,
        rows: np.ndarray,
        cap: bool = True,
        guess: np.ndarray | None = None,
    ):
        """LK tracks ``uv`` (K, 2) of image ``prev`` into image ``cur`` with the
        forward-backward check (at most ``max_tracks`` of them with ``cap``, spread by
        :meth:`_cap`), starting from ``guess`` (K, 2) px (the motion model's prediction) when
        given; the backward pass starts from ``uv``. Returns the surviving ``(uv (K', 2)
        float32, rows (K',), idx (K',))``, ``idx`` their indices in ``uv``."""
        idx = np.arange(len(uv))
        if len(uv) == 0:
            return uv, rows, idx
        if cap and len(uv) > self.max_tracks:
            idx = self._cap(uv, self.max_tracks)
            uv, rows = uv[idx], rows[idx]
            guess = None if guess is None else guess[idx]
        p0 = np.ascontiguousarray(uv, np.float32).reshape(-1, 1, 2)
        if guess is not None:
            p1 = np.ascontiguousarray(guess, np.float32).reshape(-1, 1, 2)
            p1, st, _ = cv2.calcOpticalFlowPyrLK(
                prev, cur, p0, p1, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self.lk
            )
        else:
            p1, st, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, None, **self.lk)
        if p1 is None:
            return uv[:0], rows[:0], idx[:0]
        p0b, st_b, _ = cv2.calcOpticalFlowPyrLK(
            cur, prev, p1, p0.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self.lk
        )
        fb = np.linalg.norm((p0b - p0).reshape(-1, 2), axis=1)
        p1 = p1.reshape(-1, 2)
        h, w = cur.shape[:2]
        ok = (
            (st.ravel() == 1)
            & (st_b.ravel() == 1)
            & (fb < self.fb_max_px)
            & (p1[:, 0] >= 0)
            & (p1[:, 1] >= 0)
            & (p1[:, 0] <= w - 1)
            & (p1[:, 1] <= h - 1)
        )
        return p1[ok], rows[ok], idx[ok]

    def _track_anchored(self, cur: np.ndarray, guess: np.ndarray | None):
        """The tracks (at most ``max_tracks``, spread by :meth:`_cap`) followed into image
        ``cur`` from their anchors: each from the frame it was detected (or re-anchored) in,
        at its pixel there, by LK from ``guess`` (K, 2) (the motion model's prediction; the
        previous frame's pixels without one), with the forward-backward check against the
        anchor pixel. Tracking from the anchor rather than from frame to frame keeps the
        optical flow's errors from adding up over the frames.

        Returns ``(uv (K', 2) float32, rows (K',), idx (K',))``, ``idx`` the tracks' indices."""
        n = len(self._uv)
        idx = np.arange(n)
        if n > self.max_tracks:
            # (the youngest anchors first: optical flow over fewer frames is more precise)
            idx = self._cap(self._uv, self.max_tracks, age=self._index - self._anc)
        start = self._uv if guess is None else guess
        out_uv, out_idx = [], []
        anc = self._anc[idx]
        for a in np.unique(anc):
            sel = idx[anc == a]
            img = self._anchors.get(int(a))
            if img is None:
                continue
            uv, _, k = self._track(
                img, cur, self._anc_uv[sel], self._rows[sel], cap=False, guess=start[sel]
            )
            out_uv.append(uv)
            out_idx.append(sel[k])
        if not out_idx:
            return np.zeros((0, 2), np.float32), self._rows[:0], idx[:0]
        uv, idx = np.concatenate(out_uv), np.concatenate(out_idx)
        return uv, self._rows[idx], idx

    def _reanchor(self, anc: np.ndarray, anc_uv: np.ndarray, uv: np.ndarray, gray: np.ndarray):
        """Tracks whose anchor is more than ``max_anchor_age`` frames old, or of the oldest
        anchors beyond ``max_anchors``, are anchored again in this frame at their tracked
        pixels ``uv`` (the view has changed too much for the old patch, or too many images
        would be tracked from). Returns the new ``(anc, anc_uv)``."""
        if len(anc) == 0:
            return anc, anc_uv
        old = self._index - anc > self.max_anchor_age
        live = np.unique(anc[~old])
        if len(live) > self.max_anchors:  # (keep max_anchors - 1, plus this frame)
            old |= (anc < live[-(self.max_anchors - 1)]) if self.max_anchors > 1 else True
        if not old.any():
            return anc, anc_uv
        anc, anc_uv = anc.copy(), np.array(anc_uv, np.float32).reshape(-1, 2)
        anc[old] = self._index
        anc_uv[old] = uv[old]
        self._anchors[self._index] = gray
        return anc, anc_uv

    def _start_refresh(self, camera: CameraModel, pose: tuple) -> None:
        """Detect on the last frame in a background thread (OpenCV releases the GIL);
        ``pose``: that frame's solved model ``(R, C, w, t)``, for its guided matching."""
        job = _Refresh(self._index, self._gray, pose, camera)
        self._pending = job
        self.report.refresh_started = True
        # (a detector per job: a dropped job's thread may still be running)
        det = make_detector(self.map.kind, self._n_features)

        def run():
            try:
                kps, des = det.detectAndCompute(job.gray, None)
                if des is not None and len(kps):
                    uv, rows = self._guided(job, cv2.KeyPoint_convert(kps).astype(float), des)
                    if len(rows):
                        job.result = (uv.astype(np.float32), rows)
            except cv2.error:
                job.result = None
            job.done.set()

        # (not a daemon: a detection still running at exit is finished, not killed in OpenCV)
        threading.Thread(target=run, name="tracking-refresh").start()
        self._since_refresh = 0

    def _join_refresh(
        self, gray: np.ndarray, prediction: RSModel | None, camera: CameraModel | None
    ):
        """A finished refresh (detection and guided matching in its frame, done in the
        background): its matches followed by LK into this frame ``gray``, from their pixels
        under the frame's ``prediction``.

        Returns ``(uv (G, 2) float32, rows (G,), uv_k (G, 2), job)``: ``uv_k`` their
        detected pixels in the refresh frame, ``job`` the refresh (its ``index``, ``gray``)."""
        job = self._pending
        empty = np.zeros((0, 2), np.float32), np.zeros(0, np.int64), np.zeros((0, 2)), job
        if job is None or not job.done.is_set():
            return empty
        self._pending = None
        if job.result is None or self._index - job.index > 90:  # (3 s at 30 Hz: too old)
            return empty
        uv_k, rows = job.result
        guess = self._predict(rows, prediction, camera)  # (the refresh frame: a few back)
        uv, rows, idx = self._track(job.gray, gray, uv_k, rows, cap=False, guess=guess)
        return uv, rows, uv_k[idx], job

    def _local_rows(self, pose: tuple, camera: CameraModel) -> np.ndarray:
        """Map rows in front of the camera and inside the image (global-shutter projection
        of the pose, 10 % margin)."""
        R, C = pose[0], pose[1]
        Xc = self.map.points @ R.T + C
        z = Xc[:, 2]
        ok = z > 0.05
        x = np.where(ok, Xc[:, 0] / np.where(ok, z, 1), 1e9)
        y = np.where(ok, Xc[:, 1] / np.where(ok, z, 1), 1e9)
        K = camera.K
        u, v = K[0, 0] * x + K[0, 2], K[1, 1] * y + K[1, 2]
        mw, mh = 0.1 * camera.width, 0.1 * camera.height
        ok &= (u > -mw) & (u < camera.width + mw) & (v > -mh) & (v < camera.height + mh)
        return np.flatnonzero(ok)

    def _guided(self, job: _Refresh, kp_uv: np.ndarray, des: np.ndarray):
        """Match the refresh frame's keypoints ``kp_uv`` (K, 2), ``des`` (K, D) to the map
        points predicted in view by that frame's RS pose and twist, within
        ``search_radius_px`` (distance and ratio tests, one keypoint per landmark)."""
        from scipy.spatial import cKDTree

        empty = np.zeros((0, 2)), np.zeros(0, np.int64)
        rows = self._local_rows(job.pose, job.camera)
        if len(rows) == 0:
            return empty
        R, C, w, t = job.pose
        pred = job.camera.project_rs(self.map.points[rows], R, C, w, t, iterations=5)
        ok = np.isfinite(pred).all(axis=1)
        ok &= (pred[:, 0] >= 0) & (pred[:, 1] >= 0)
        ok &= (pred[:, 0] <= job.camera.width - 1) & (pred[:, 1] <= job.camera.height - 1)
        rows, pred = rows[ok], pred[ok]
        if len(rows) == 0:
            return empty
        # (the keypoints in each window: the 8 nearest within the radius, in one call)
        kn = min(8, len(kp_uv))
        _, near = cKDTree(kp_uv).query(pred, k=kn, distance_upper_bound=self.search_radius_px)
        near = np.asarray(near).reshape(len(pred), kn)
        pr, col = np.nonzero(near < len(kp_uv))
        kq = near[pr, col].astype(np.int64)
        if len(pr) == 0:
            return empty
        md = self.map.descriptors[rows[pr]]
        if self._norm == cv2.NORM_HAMMING:
            bits = np.unpackbits(np.bitwise_xor(md, des[kq]), axis=1)
            dist = bits.sum(axis=1).astype(float)
        else:
            diff = np.asarray(md, np.float32) - np.asarray(des[kq], np.float32)
            dist = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        # per map point: best and second-best keypoint in its window
        order = np.lexsort((dist, pr))
        pr, kq, dist = pr[order], kq[order], dist[order]
        first = np.r_[True, pr[1:] != pr[:-1]]
        best = np.flatnonzero(first)
        nxt = best + 1
        has2 = (nxt < len(pr)) & (nxt < len(pr)) & np.r_[pr[1:] == pr[:-1], False][best]
        second = np.full(len(best), np.inf)
        second[has2] = dist[nxt[has2]]
        # an absolute bound too: the map's matches are rarely farther (SIFT L2 of unit*512)
        max_dist = 64.0 if self._norm == cv2.NORM_HAMMING else 300.0
        good = (dist[best] < self.ratio * second) & (dist[best] < max_dist)
        p, k, d = pr[best][good], kq[best][good], dist[best][good]
        # one map point per keypoint: the closest descriptor wins
        o = np.lexsort((d, k))
        p, k = p[o], k[o]
        uniq = np.r_[True, k[1:] != k[:-1]]
        p, k = p[uniq], k[uniq]
        return kp_uv[k], rows[p]
