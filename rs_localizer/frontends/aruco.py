"""ArUco front end: marker corners -> 2D-3D correspondences.

The marker detector of the map's dictionary
(:func:`~rs_localizer.frontends.marker_detection.make_marker_detector`: the AprilTag 3 library
for AprilTag families, OpenCV's ArUco detector with subpixel corner refinement for ArUco
dictionaries) finds the markers, over the full frame or, with ``windowed``, in windows around
the predicted markers (the same detector and settings); each corner ``k`` (in the detector's
order: for ArUco dictionaries the printed top-left, top-right, bottom-right, bottom-left; for
AprilTag families ``docs/marker_maps.md``'s "Corner order") of marker ``id`` found in the
marker map becomes a correspondence with id ``4 * id + k``, group ``id`` (the marker's 4 corners
share a part of their image error: the detector fits the marker's edges together) and the
corner's 3D position.
Markers not in the map are ignored; an id found twice in one image is dropped from that image
(counted).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .. import cv_compat
from ..camera import CameraModel
from ..correspondences import (
    Correspondences,
    FrameFeedback,
    FrontendHooks,
    accepts_pixels_keyword,
)
from ..pose import RSModel
from .image import to_gray
from .marker_detection import DetectorOptions, make_marker_detector

__all__ = ["ArucoFrontend", "marker_scores", "merge_windows", "window_share"]

#: a marker whose stated position std is this (m) scores 0.5 (:func:`marker_scores`)
SCORE_STD_M = 0.005


def marker_scores(std: np.ndarray) -> np.ndarray:
    """Match scores (N,) in (0, 1] from the markers' stated position std (N,) m (largest axis
    in the map): ``1 / (1 + (std / SCORE_STD_M)^2)``, higher for better-fixed markers; the
    estimator draws its RANSAC samples from the best-scored correspondences first
    (PROSAC-style ordering), so a frame's hypotheses come from its best-mapped markers."""
    s = np.asarray(std, dtype=float) / SCORE_STD_M
    return 1.0 / (1.0 + s * s)


class ArucoFrontend(FrontendHooks):
    """Detect ArUco markers and emit correspondences to their mapped 3D corners.

    Args:
        marker_corners: {marker id: (4, 3) world corners in ArUco order}.
        dictionary: cv2.aruco predefined dictionary name (e.g. ``DICT_4X4_250``).
        subpix_window: largest half size (px) of the subpixel corner refinement window (ArUco
            dictionaries: :func:`~rs_localizer.frontends.marker_detection.refine_corners`,
            window 2 px, then up to 0.8 marker cell and this).
        min_marker_perimeter: smallest marker perimeter as a fraction of the image's larger
            side (OpenCV ``minMarkerPerimeterRate``; 0.07: 45 px at 640x480, a 4x4 marker of
            1.9 px per cell; the smallest OpenCV decodes on ``python -m
            benchmarks.bench_markers``' textured room are 52 px around; every smaller outline
            is a candidate that costs time on textured walls: 14 ms of CPU per 640x480 frame
            there with 0.07, 20-24 ms with 0.02, as many markers found).
        marker_std: {marker id: stated position std (m)} of the map: each correspondence
            gets the score of its marker (:func:`marker_scores`, in ``last_scores``); a marker
            without one scores 1. None: no scores.
        windowed: detect only in windows around the markers' predicted pixels (the
            ``prediction`` given to :meth:`process`, each corner at its own capture line)
            instead of over the full frame (:meth:`predict_windows`: every map marker
            predicted in view); the full frame is searched when there is no prediction (start,
            a time reset), after a failed frame, when a marker found in the last frame and
            predicted inside the image is not found while the markers found lie off their
            predicted corners (the prediction may be off), when the windows would cover more than
            ``window_max_share`` of the frame (then the next :data:`DENSE_SKIP` frames as
            well), and every ``full_frame_every`` frames.
        windowed_min_pixels: with ``windowed``, search in windows only on images of at least
            this many pixels (smaller ones in full; 0: every size). On ``apriltag_room`` the
            windows save half the detection at 1280x720 and find the same markers, but at
            640x480 they cover half the frame and cost more than it (module notes).
        window_margin_px: padding (px) of each predicted marker's bounding box; at least the
            adaptive-threshold half window plus the expected prediction error.
        window_max_share: windows covering more than this share of the frame make it a
            full-frame search (the detectors' cost grows with the pixels searched, plus some
            per window: on a room dense with markers the windows cost more than the frame).
        full_frame_every: a full-frame detection at least every this many frames (0: only on
            the fallbacks above).
        detector_options: the marker detector's
            :class:`~rs_localizer.frontends.marker_detection.DetectorOptions` (AprilTag families
            with the AprilTag library, ArUco dictionaries with OpenCV; default: its defaults).

    ``process(image, camera) -> (points_px (N, 2), points3d (N, 3), ids (N,) int64)``.
    """

    name = "aruco"

    def __init__(
        self,
        marker_corners: dict,
        dictionary: str = "DICT_4X4_250",
        subpix_window: int = 3,
        min_marker_perimeter: float = 0.07,
        marker_std: dict | None = None,
        windowed: bool = False,
        windowed_min_pixels: int = 0,
        window_margin_px: float = 16.0,
        window_max_share: float = 0.5,
        full_frame_every: int = 10,
        detector_options: DetectorOptions | None = None,
    ):
        self.dictionary = dictionary
        self.marker_corners = {
            int(k): np.asarray(v, dtype=float).reshape(4, 3) for k, v in marker_corners.items()
        }
        # the corners are refined in stages (marker_detection.refine_corners: OpenCV's one
        # window leaves some corners unrefined); relativeCornerRefinmentWinSize (sic, OpenCV
        # >= 4.9) serves OpenCV's own refinement (refine="opencv")
        params = cv_compat.detector_parameters(
            cornerRefinementMethod=cv2.aruco.CORNER_REFINE_SUBPIX,
            cornerRefinementWinSize=int(subpix_window),
            cornerRefinementMaxIterations=50,
            cornerRefinementMinAccuracy=0.01,
            relativeCornerRefinmentWinSize=1.0,
            minMarkerPerimeterRate=float(min_marker_perimeter),
        )
        self.params = params
        self.detector = make_marker_detector(dictionary, detector_options, params)
        self.last_rejected = 0
        self.marker_std = (
            None if marker_std is None else {int(k): float(v) for k, v in marker_std.items()}
        )
        self.last_scores = None  # per correspondence, from marker_std
        self.windowed = bool(windowed)
        self.windowed_min_pixels = int(windowed_min_pixels)
        self.window_margin_px = float(window_margin_px)
        self.window_max_share = float(window_max_share)
        self.full_frame_every = int(full_frame_every)
        self._solved = False  # the last frame was solved (observe)
        self._camera = None  # the camera of the last processed frame
        self._since_full = 0
        self._missed = False  # a predicted marker was not found in the last windowed frame
        self._dense = 0  # frames still searched whole after windows covered most of one
        self._predicted: dict = {}  # marker id -> predicted corners (4, 2) of the windows
        self._last_found: set = set()  # marker ids found in the last frame
        self.counts = {"windowed": 0, "full": 0, "weak": 0, "duplicate": 0}
        self.last_weak = 0  # detections refused as weak in the last frame (AprilTag)
        self.last_duplicates = 0  # ids dropped from the last frame for being found twice
        self._times: list = []  # detection seconds per frame
        self.last_windows: list = []  # (x0, y0, x1, y1) of the last windowed frame
        self.last_kind = "full"  # how the last frame was searched: full or windowed
        # every map marker's corners, for the windows (predict_windows)
        self._map_ids = np.array(sorted(self.marker_corners), np.int64)
        self._map_X = (
            np.concatenate([self.marker_corners[int(m)] for m in self._map_ids])
            if len(self._map_ids)
            else np.zeros((0, 3))
        )

    @classmethod
    def from_scene(cls, scene: Any, **kw: Any) -> ArucoFrontend:
        return cls(scene.marker_corners(), scene.dictionary, **kw)

    @classmethod
    def from_map(cls, dictionary: str, corners: dict, std: dict, **kw: Any) -> ArucoFrontend:
        """From a loaded marker map: its ``dictionary``, ``corners`` {id: (4, 3) m} and stated
        position ``std`` {id: m} (empty: none), which score each marker's corners
        (``marker_std``, unless given in ``kw``)."""
        kw.setdefault("marker_std", std or None)
        return cls(corners, dictionary, **kw)

    @classmethod
    def from_file(cls, path: str | Path, **kw: Any) -> ArucoFrontend:
        """From a marker map YAML (:func:`rs_localizer.maps.markers.load_marker_map`) or a scene
        YAML / built-in scene name; the map's stated std, when it has them, score the
        correspondences (``marker_std``): the front end of ``make_frontend("aruco", path)``."""
        from ..maps.markers import load_marker_map, load_marker_std

        dictionary, corners = load_marker_map(Path(str(path)))
        return cls.from_map(dictionary, corners, load_marker_std(path), **kw)

    def detect(self, image: np.ndarray, encoding: str = "rgb8") -> tuple[np.ndarray, np.ndarray]:
        """Raw detections over the full image: (corners (M, 4, 2) pixels, marker ids (M,)),
        all markers found (ids found twice dropped). Raises ValueError as :meth:`process`."""
        corners, ids, rej = self.detector.detect(to_gray(image, encoding))
        self.last_rejected = int(rej) if self.detector.backend == "opencv" else 0
        return corners, ids

    def predict_windows(
        self, shape: tuple, camera: CameraModel | None, prediction: RSModel | None
    ) -> tuple[list, set] | None:
        """Windows to search in a frame of ``shape`` (H, W) predicted at ``prediction`` (the
        frame's model ``(R, C, w, t)``, :class:`~rs_localizer.pose.RSModel`): every corner of
        every map marker projected at its own capture line (:meth:`CameraModel.project_rs`),
        each marker predicted fully inside the image and facing the camera getting its corner
        bounding box padded by ``window_margin_px`` and clipped to the image, overlapping
        boxes merged where that adds no pixel (:func:`merge_windows`). The markers coming
        into view are searched where the prediction puts them, as the ones already seen.
        Markers predicted outside the image by more than the margin, seen from behind or from
        their back, or smaller than :data:`WINDOW_MIN_SIDE_PX` (no detector decodes them) get
        no window.

        Returns:
            ``(windows, ids)``: windows ``[(x0, y0, x1, y1)]`` (px, end exclusive), and the
            ids of the markers found in the last frame that are predicted fully inside the
            image (the ones whose absence makes the next frame a full-frame search); None without a
            prediction, after a frame that was not solved, without a camera or RS timing, or
            when no marker was found in the last frame.
        """
        cam = camera if camera is not None else self._camera
        if prediction is None or not self._solved or cam is None:
            return None
        if cam.seconds_per_unit_r <= 0:
            return None
        R, C, w, t = prediction
        if not self._last_found & self.marker_corners.keys():
            return None
        mids, X = self._map_ids, self._map_X
        h, wd = int(shape[0]), int(shape[1])
        # (pinhole, no lens: far outside the view the distortion may fold points back in)
        Xc = X @ np.asarray(R, float).T + np.asarray(C, float).reshape(3)
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = Xc[:, :2] / z[:, None]
        lim = np.array([wd, h], float) / np.array([cam.K[0, 0], cam.K[1, 1]])
        near = (z > 0) & (np.abs(xy) <= 2.0 * lim).all(axis=1)
        near = near.reshape(-1, 4).all(axis=1)
        mids = mids[near]
        if len(mids) == 0:
            return None
        uv = cam.project_rs(X.reshape(-1, 4, 3)[near].reshape(-1, 3), R, C, w, t, iterations=4)
        uv = uv.reshape(-1, 4, 2)
        ok = np.isfinite(uv).all(axis=(1, 2))
        # (up to the margin outside: a marker at the border may be inside, the prediction off)
        m = self.window_margin_px
        ok &= (uv[..., 0] >= -m).all(1) & (uv[..., 0] <= wd - 1 + m).all(1)
        ok &= (uv[..., 1] >= -m).all(1) & (uv[..., 1] <= h - 1 + m).all(1)
        inside = (uv[..., 0] >= 0).all(1) & (uv[..., 0] <= wd - 1).all(1)
        inside &= (uv[..., 1] >= 0).all(1) & (uv[..., 1] <= h - 1).all(1)
        # front face towards the camera (ArUco corners run clockwise in the image)
        a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]
        cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (
            c[:, 0] - a[:, 0]
        )
        ok &= np.nan_to_num(cross) > 0
        side = np.linalg.norm(np.roll(uv, -1, axis=1) - uv, axis=2).min(axis=1)
        ok &= np.nan_to_num(side) >= WINDOW_MIN_SIDE_PX
        q = uv[ok]
        lo = np.maximum(np.floor(q.min(axis=1) - m), 0).astype(int)
        hi = np.minimum(np.ceil(q.max(axis=1) + m).astype(int) + 1, [wd, h])
        boxes = np.concatenate([lo, hi], axis=1).tolist()
        self._predicted = dict(zip(mids[ok].tolist(), q, strict=True))
        return merge_windows(boxes), {int(i) for i in mids[ok & inside]} & self._last_found

    def _detect_windows(self, gray: np.ndarray, windows: list) -> tuple[np.ndarray, np.ndarray]:
        """Detections in each window with the full-frame detector and its settings
        (``detect_window``: OpenCV keeps the full frame's smallest marker perimeter, the
        AprilTag library its decimation and grid), corners in full-frame pixels. A marker
        seen in two overlapping windows is kept from the one it sits deeper in; an id found at
        two places (corners more than ``DUPLICATE_PX`` apart) is dropped, counted in
        ``last_duplicates``."""
        best: dict = {}  # marker id -> (distance of its corners to the window border, corners)
        dup: set = set()
        self.last_rejected = self.last_weak = self.last_duplicates = 0
        for x0, y0, x1, y1 in windows:
            c, i, rej = self.detector.detect_window(gray, (x0, y0, x1, y1))
            self.last_rejected += int(rej) if self.detector.backend == "opencv" else 0
            self.last_weak += self.detector.last_weak
            dup.update(self.detector.last_duplicate_ids)
            for cc, ii in zip(c, i, strict=True):
                inside = min(
                    cc[:, 0].min() - x0,
                    cc[:, 1].min() - y0,
                    x1 - cc[:, 0].max(),
                    y1 - cc[:, 1].max(),
                )
                k = int(ii)
                if k in best and np.abs(best[k][1] - cc).max() > DUPLICATE_PX:
                    dup.add(k)  # the same id at another place of the image
                elif k not in best or inside > best[k][0]:
                    best[k] = (inside, cc)  # (in two overlapping windows: the deeper one)
        self.last_duplicates = len(dup)
        ids = sorted(k for k in best if k not in dup)
        if not ids:
            return np.zeros((0, 4, 2)), np.zeros(0, np.int64)
        return np.asarray([best[i][1] for i in ids]), np.asarray(ids, np.int64)

    def _detect_frame(
        self, gray: np.ndarray, camera: CameraModel | None, prediction: RSModel | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Windowed detection when it applies (see ``windowed``), else full frame."""
        import time

        t0 = time.perf_counter()
        pred = None
        due = self.full_frame_every > 0 and self._since_full + 1 >= self.full_frame_every
        small = gray.shape[0] * gray.shape[1] < self.windowed_min_pixels
        # (after windows over most of the frame, the next DENSE_SKIP frames are searched whole
        # without predicting: a dense view stays dense for a while, predicting costs ~1 ms)
        dense, self._dense = self._dense > 0, max(self._dense - 1, 0)
        if self.windowed and not small and not self._missed and not due and not dense:
            pred = self.predict_windows(gray.shape, camera, prediction)
            if pred is not None and window_share(pred[0], gray.shape) > self.window_max_share:
                pred = None  # (windows over most of the frame cost more than the frame)
                self._dense = DENSE_SKIP
        self._missed = False
        if pred is not None:
            windows, expect = pred
            corners, mids = self._detect_windows(gray, windows)
            self.last_windows = windows
            self.last_kind = "windowed"
            self._missed = self._prediction_missed(expect, corners, mids)
            self._since_full += 1
            self.counts["windowed"] += 1
        else:
            corners, mids, rej = self.detector.detect(gray)
            self.last_rejected = int(rej) if self.detector.backend == "opencv" else 0
            self.last_weak = self.detector.last_weak
            self.last_duplicates = self.detector.last_duplicates
            self.last_windows = []
            self.last_kind = "full"
            self._since_full = 0
            self.counts["full"] += 1
        self._times.append(time.perf_counter() - t0)
        self.counts["weak"] += self.last_weak
        self.counts["duplicate"] += self.last_duplicates
        self._last_found = {int(i) for i in mids}
        return corners, mids

    def _prediction_missed(self, expect: set, corners: np.ndarray, mids: np.ndarray) -> bool:
        """Whether a windowed frame calls for a full-frame search: a marker of ``expect`` (found
        in the last frame, predicted inside the image) is missing and the markers found lie
        further than half ``window_margin_px`` from their predicted corners (or none was
        found): the prediction may have put the windows off. With the found markers where
        predicted, a missing one was not detectable there (occluded, too oblique or blurred
        to decode), which a full-frame search would not change."""
        found = {int(i) for i in mids}
        if expect.issubset(found):
            return False
        pred = self._predicted
        err = [
            float(np.abs(c - pred[int(i)]).max())
            for c, i in zip(corners, mids, strict=True)
            if int(i) in pred
        ]
        return not err or max(err) > 0.5 * self.window_margin_px

    @accepts_pixels_keyword
    def observe(
        self, stamp_ns: int | None, points2d: np.ndarray | None, feedback: FrameFeedback | None
    ) -> None:
        """How the last processed frame was solved (the node calls this after each frame):
        after a solved one (``feedback.success``) the next frame's markers are searched around
        their predicted pixels; a failed one (or None) makes the next frame a full-frame
        search. ``stamp_ns`` and ``points2d`` are not used."""
        self._solved = feedback is not None and bool(feedback.success)

    def reset(self) -> None:
        """Forget the last frame: the next frame is searched in full."""
        self._solved = False
        self._missed = False
        self._dense = 0

    def marker_detector_note(self) -> tuple[str, bool]:
        """``(the marker detector's line for the log, whether it stands in for a missing
        AprilTag library)``."""
        return self.detector.describe(), bool(self.detector.fallback)

    def summary(self) -> dict:
        """Counters since start: frames searched whole (``frontend_frames_global``) and in
        windows (``aruco_frames_windowed``), the median detection time per frame (ms; ``nan``
        before one), detections refused as weak (``aruco_markers_weak``) and ids dropped for
        being found twice in one image (``aruco_markers_duplicate``); and the detector in use
        (``aruco_detector``: which, and why OpenCV stands in for a missing AprilTag library,
        with the install line) with its settings (``aruco_detector_settings``)."""
        t = self._times
        det = self.detector
        return {
            "frontend_frames_global": self.counts["full"],
            "aruco_frames_windowed": self.counts["windowed"],
            "aruco_detect_ms_median": f"{np.median(t) * 1e3:.3f}" if t else "nan",
            "aruco_markers_weak": self.counts["weak"],
            "aruco_markers_duplicate": self.counts["duplicate"],
            "aruco_detector": det.describe(),
            "aruco_detector_settings": det.settings(),
        }

    def process(
        self,
        image: np.ndarray,
        camera: CameraModel | None = None,
        encoding: str = "rgb8",
        prediction: RSModel | None = None,
    ) -> Correspondences:
        """Correspondences of one image: :class:`~rs_localizer.correspondences.Correspondences`
        (``points2d`` (N, 2), ``points`` (N, 3), ``ids`` (N,), ``scores`` (N,) from the map's
        stated std when it has them (``marker_std``), else None, ``groups`` (N,) each
        corner's marker id; unpacks as ``(points2d, points3d, ids)``) with
        ``ids = 4 * marker_id + corner``. Pixels stay
        distorted, as the estimator expects; ``camera`` (the frame's model) and
        ``prediction`` (the frame's predicted :class:`~rs_localizer.pose.RSModel`, from the
        video's tracker: :meth:`~rs_localizer.tracking.sequence.SequenceLocalizer.predict`)
        serve the windowed detection (``windowed``), which without them searches the full
        frame.

        Raises:
            ValueError: an image narrower or lower than the detector takes
                (:func:`~rs_localizer.frontends.marker_detection.min_image_side`: 16 px, more
                at a ``quad_decimate`` above 2), never given to the detector library.
        """
        if camera is not None:
            self._camera = camera
        corners, mids = self._detect_frame(to_gray(image, encoding), camera, prediction)
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
        groups = np.repeat(np.asarray(mids[keep], np.int64), 4)
        return Correspondences(uv, X, ids.astype(np.int64), self.last_scores, groups)


#: px: markers predicted with a side shorter than this get no window (the AprilTag library
#: finds no 36h11 tag under ~12 px at quad_decimate 1.5, OpenCV no marker under the front end's
#: smallest perimeter)
WINDOW_MIN_SIDE_PX = 6.0

#: frames searched whole, without predicting, after windows covering most of a frame
DENSE_SKIP = 5

#: px: the same id found in two windows with corners further apart than this is two markers
DUPLICATE_PX = 2.0


def window_share(windows: list, shape: tuple) -> float:
    """The share of a frame of ``shape`` (H, W) that ``windows`` ``[(x0, y0, x1, y1)]`` (end
    exclusive) cover together (overlaps counted once)."""
    h, w = int(shape[0]), int(shape[1])
    covered = np.zeros((h, w), bool)
    for x0, y0, x1, y1 in windows:
        covered[y0:y1, x0:x1] = True
    return float(np.count_nonzero(covered)) / (h * w)


def merge_windows(boxes: list) -> list:
    """Overlapping boxes ``[x0, y0, x1, y1]`` (end exclusive) joined into their bounding box
    where that box has no more pixels than the two together (no pixel searched that neither
    covers), repeated until no pair qualifies;
    returns a list of 4-tuples (windows may still overlap where joining would cost pixels)."""

    def area(b: list) -> int:
        return (b[2] - b[0]) * (b[3] - b[1])

    boxes = [list(b) for b in boxes]
    merged = True
    while merged:
        merged = False
        out: list = []
        for b in boxes:
            for o in out:
                if b[0] < o[2] and o[0] < b[2] and b[1] < o[3] and o[1] < b[3]:
                    u = [min(o[0], b[0]), min(o[1], b[1]), max(o[2], b[2]), max(o[3], b[3])]
                    ov = (min(o[2], b[2]) - max(o[0], b[0])) * (min(o[3], b[3]) - max(o[1], b[1]))
                    if area(u) <= area(o) + area(b) - ov:
                        o[:] = u
                        merged = True
                        break
            else:
                out.append(b)
        boxes = out
    return [tuple(b) for b in boxes]
