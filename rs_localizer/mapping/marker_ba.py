"""Marker maps from a rolling-shutter video: incremental initialization and bundle adjustment.

Input: per frame the detected corners of square fiducial markers (ArUco/AprilTag order TL, TR,
BR, BL, measured pixels) and the frame's capture time. Output: each marker's 6-DoF pose and
world corners, with a gauge-fixed covariance, and each frame's pose and twist.

Model. Every corner observation is explained by the estimator's model (paper eq. 4 with the exact
rotation, docs/architecture.md "Conventions"; :mod:`rs_localizer.estimation.refine`)::

    x_i ~ pi( expm(tau_i [w]x) R X_i + C + tau_i t ),   tau_i = r_i - r0 (measured line)

with ``x_i`` the undistorted normalized corner and ``X_i`` a marker corner. Here the velocities
are per second: ``w = s * w_s``, ``t = s * t_s`` with ``s = line_delay * focal``
(:attr:`CameraModel.seconds_per_unit_r`), so that one global line delay can be calibrated and
consecutive frames can be tied by the same velocities. A marker is a square of known side:
its corners are ``R_m c_k + p_m`` with ``c_k`` the corners of OpenCV's ``SOLVEPNP_IPPE_SQUARE``
(``(-h, h, 0), (h, h, 0), (h, -h, 0), (-h, -h, 0)``, ``h`` half the side; z out of the face).
The world frame is the anchor marker's frame (or ``anchor_pose``): the anchor is not adjusted.

The solver is SciPy's ``least_squares`` (trust-region reflective with a sparse Jacobian from
``jac_sparsity``; a robust loss, then outlier rejection and a final plain least-squares pass).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix, diags, lil_matrix
from scipy.sparse.linalg import splu

from ..camera import CameraModel
from ..geometry import matrix_to_rotvec, rotvec_to_matrix, skew

__all__ = [
    "FrameDetections",
    "MappingOptions",
    "MarkerMapResult",
    "OutputFrame",
    "concatenate_videos",
    "corner_jacobian",
    "map_markers",
    "marker_corners_local",
    "shape_covariance",
]


def marker_corners_local(side: float) -> np.ndarray:
    """(4, 3) corners of a square marker of side ``side`` (m) in its own frame, in ArUco order
    TL, TR, BR, BL: ``(-h, h, 0), (h, h, 0), (h, -h, 0), (-h, -h, 0)``, ``h = side / 2``, z out
    of the face (the object points of OpenCV's ``SOLVEPNP_IPPE_SQUARE``).

    Raises:
        ValueError: for a side that is not finite and positive.
    """
    if not np.isfinite(side) or side <= 0:
        raise ValueError(f"marker side must be finite and > 0, got {side}")
    h = 0.5 * float(side)
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass(frozen=True)
class FrameDetections:
    """One frame's marker detections.

    Attributes:
        stamp: capture time of the frame's reference line (s).
        corners: marker id -> (4, 2) measured (distorted) pixel corners in ArUco order.
    """

    stamp: float
    corners: dict = field(default_factory=dict)


@dataclass(frozen=True)
class MappingOptions:
    """Options of :func:`map_markers`.

    Attributes:
        marker_size: default side length of the markers' black square (m).
        marker_sizes: marker id -> side (m) for markers of another size.
        anchor: id of the marker that fixes the world frame; ``None`` (and no ``anchors``):
            the most detected marker (the best-observed one, whose pose the video fixes best).
        anchor_pose: ``(R, p)``: the anchor's rotation (3, 3, marker -> world) and centre (3,)
            (m) in the world; ``None``: the anchor's own frame is the world.
        anchors: id -> (4, 3) surveyed world corners (m) of several markers: the world frame
            is the rigid best fit of their mapped corners to these (a frame several markers
            fix); excludes ``anchor``.
        max_anchor_residual: RMS corner residual (m) of the surveyed anchors after the fit
            that is always accepted; above it and above 3 times the position std the map
            states for them, the anchors disagree with the video (an error).
        shared_errors: weight the detections in the covariance for the detector's errors that
            repeat when a marker is seen again from the same viewpoint
            (:func:`_shared_error_weights`); False: every detection independent.
        planar_ambiguity: widen each marker's rotation covariance along its mirrored tilt
            where the cost says the mirror fits (:func:`_mirror_covariance`).
        view_cluster_rad: viewing directions within this angle (rad; and distances within
            30 %) count as one viewpoint for ``shared_errors``.
        coverage_std: markers whose stated position std (largest axis, m) exceeds this are
            named in ``MarkerMapResult.coverage`` with what would help.
        max_frame_rotation_deg, max_frame_position_mm: bounds on the output frame's own
            uncertainty above which the map tools warn.
        global_shutter: adjust with the global-shutter model (velocities fixed at 0, no motion
            tie): for global-shutter cameras and for comparison.
        calibrate_readout: estimate one line delay for the whole video (needs the motion tie).
        corner_offset: estimate one corner offset (pixels) for the whole video: the detected
            corners lie this far inside the marker's projected square, along its diagonals.
            OpenCV's subpixel refinement of the outer corner of a blurred black square is
            biased inwards (about 0.2 px on rendered images); left in, it makes every marker
            look smaller, so further away, by a fixed fraction.
        corner_offset_sigma_px: standard deviation (pixels) of a zero-mean prior on the
            corner offset: where the video's views fix it poorly (markers seen from a narrow
            range of distances) it stays near zero instead of wandering.
        motion_sigma_rot, motion_sigma_pos: standard deviations (rad, m) of the motion-model tie
            between consecutive frames (the change of pose between their reference lines
            against the mean of their velocities times the time between them); ``None``
            (either): no tie.
        motion_sigma_angular_accel: standard deviation of the camera's angular acceleration
            (rad/s^2) between tied frames: their angular velocities differ by about this times
            the time between them (hand-held: ~10 rad/s^2).
        max_frame_gap: consecutive frames further apart than this multiple of the median frame
            interval are not tied (a gap in the video).
        loss, f_scale_px: robust loss of ``least_squares`` and its scale (pixels).
        reject_px: a detection whose four corners' RMS reprojection error exceeds this (pixels)
            after the robust adjustment is rejected (counted) and the map adjusted again.
        min_views: a marker seen in fewer frames with a pose is left out of the map (reported
            in ``MarkerMapResult.unmapped``): its planar two-fold ambiguity and its depth are
            not fixed by one view.
        max_nfev: function-evaluation budget of each ``least_squares`` call.
    """

    marker_size: float
    marker_sizes: dict = field(default_factory=dict)
    anchor: int | None = None
    anchor_pose: tuple | None = None
    anchors: dict | None = None
    max_anchor_residual: float = 0.05
    shared_errors: bool = True
    planar_ambiguity: bool = True
    view_cluster_rad: float = 0.35
    coverage_std: float = 0.01
    max_frame_rotation_deg: float = 0.5
    max_frame_position_mm: float = 20.0
    global_shutter: bool = False
    calibrate_readout: bool = False
    corner_offset: bool = True
    corner_offset_sigma_px: float = 0.2
    motion_sigma_rot: float | None = 2e-3
    motion_sigma_pos: float | None = 5e-3
    motion_sigma_angular_accel: float = 10.0
    max_frame_gap: float = 1.5
    loss: str = "huber"
    f_scale_px: float = 1.0
    reject_px: float = 3.0
    min_views: int = 2
    max_nfev: int = 60

    def side(self, marker_id: int) -> float:
        """Side length (m) of marker ``marker_id``."""
        return float(self.marker_sizes.get(int(marker_id), self.marker_size))


@dataclass
class MarkerMapResult:
    """Result of :func:`map_markers`. World frame: the output frame (see ``MappingOptions``
    and ``frame``).

    Attributes:
        anchor: the anchor's id (the first of the markers that fix the frame).
        corners: id -> (4, 3) world corners (m), ArUco order.
        marker_poses: id -> ``(R, p)``: (3, 3) marker -> world rotation, (3,) centre (m).
        marker_covariance: id -> (6, 6) covariance of (rotation [rad, world axes, left
            perturbation], centre [m]) in the output frame, the frame's own uncertainty
            included; zeros for a single anchor (exact in its own frame).
        marker_std: id -> (6,) square roots of that diagonal.
        observations: id -> number of detections used in the adjustment.
        frame_ids: (K,) indices into the input frames of the frames with a pose.
        orientation, position: (K, 3, 3) camera -> world, (K, 3) camera centre (m), at each
            frame's reference line.
        angular_velocity, linear_velocity: (K, 3) the camera's own velocities in its optical
            frame (rad/s, m/s); zeros with ``global_shutter``.
        line_delay: seconds between lines (calibrated or the camera's).
        rmse_px: RMS reprojection error of the detections kept (pixels).
        num_rejected: detections rejected as outliers.
        num_frames_skipped: frames without detections or without a pose.
        unmapped: id -> why the marker is not in the map.
        inconsistent: id -> two (3,) world positions (m): one id detected at two places
            (left out of the map, never averaged).
        timings: stage -> seconds.
        global_shutter: the global-shutter model was used.
        corner_offset_px: the detector's corner offset found (pixels, inwards along the
            diagonals; ``MappingOptions.corner_offset``), 0 when not estimated.
        frame: :class:`OutputFrame`: how the output frame is fixed, and how well.
        coverage: id -> why the marker's stated std exceeds ``MappingOptions.coverage_std``
            and what would help.
        marker_shape_std: id -> (4,) each corner's shape-only std (m, rms per axis): its
            uncertainty relative to the other markers' corners, the frame's and the map's
            rigid motion as a whole left out (:func:`shape_covariance`). A camera localized
            against the map sees these, not ``marker_std``: the latter also holds where the
            whole map sits in the output frame, which is common to all markers.
    """

    anchor: int
    corners: dict
    marker_poses: dict
    marker_covariance: dict
    marker_std: dict
    observations: dict
    frame_ids: np.ndarray
    orientation: np.ndarray
    position: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    line_delay: float
    rmse_px: float
    num_rejected: int
    num_frames_skipped: int
    unmapped: dict
    inconsistent: dict
    timings: dict
    global_shutter: bool
    corner_offset_px: float = 0.0
    frame: OutputFrame | None = None
    coverage: dict = field(default_factory=dict)
    marker_shape_std: dict = field(default_factory=dict)


# ------------------------------------------------------------------------- initialization


def _ippe_candidates(obj: np.ndarray, x: np.ndarray) -> list:
    """Both IPPE solutions (marker -> camera ``(R, t)``) of a square from normalized corners.

    OpenCV's square solver (``SOLVEPNP_IPPE_SQUARE``) is tried first; where it returns
    non-finite poses (OpenCV 4.6 does on some exact, noise-free corners) the general planar one
    (``SOLVEPNP_IPPE``, the same two solutions of a plane) replaces it."""
    finite = []
    for flags in (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_IPPE):
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            obj, x.reshape(-1, 1, 2), np.eye(3), None, flags=flags
        )
        poses = [
            (rotvec_to_matrix(np.ravel(r)), np.ravel(t)) for r, t in zip(rvecs, tvecs, strict=True)
        ][:n]
        finite = [(R, t) for R, t in poses if np.isfinite(R).all() and np.isfinite(t).all()]
        if finite and len(finite) == len(poses):
            break
    return finite


def _gs_errors_px(R: np.ndarray, C: np.ndarray, X: np.ndarray, x: np.ndarray, f: float):
    """(N,) global-shutter reprojection errors (pixels) of world points X under world->camera."""
    p = X @ R.T + C
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.linalg.norm(p[:, :2] / p[:, 2:3] - x, axis=1) * f
    return np.where(p[:, 2] > 1e-6, e, np.inf)


class _Init:
    """Incremental initialization in video order: frame poses (world -> camera), marker poses.

    The world is first the camera frame of the frame that sees the most markers (the seed).
    Frames are visited in capture order away from the seed; each gets its pose from the mapped
    markers it sees (OpenCV ``solvePnP``, Levenberg-Marquardt from the previous frame's pose, so
    a frame seeing a single marker keeps the continuous one of its two planar solutions); a
    marker first seen gets the better of its two IPPE poses in that view, and every marker is
    refined over all its views so far (SciPy ``least_squares``) from its current tilt and from
    that tilt mirrored, the better fit kept: a single view fixes a small marker's centre well
    but its tilt poorly, and may pick the wrong one of the two. The whole is moved onto the
    anchor afterwards (:func:`_regauge`).
    """

    def __init__(
        self,
        obs: dict,
        stamps: dict,
        opts: MappingOptions,
        anchor: int,
        camera: CameraModel,
        obs_px: dict,
        window: int = 25,
    ) -> None:
        self.obs = obs  # frame -> {id: (4, 2) normalized corners}
        self.obs_px = obs_px
        self.camera = camera
        self.window = window
        focal = camera.mean_focal
        self.stamps = stamps
        self.opts = opts
        self.f = focal
        self.anchor = anchor
        self.frames: dict = {}  # frame -> (R, C) world -> camera
        self.markers: dict = {}  # id -> (R marker -> world, p)
        self.unmapped: dict = {}
        self.seed = None
        self.excluded: set = set()  # (frame, id) detections that disagree with their frame
        self.suspects: dict = {}  # id -> [frames of one place, of another]
        self.gate_px = 25.0

    def world_corners(self, mid: int) -> np.ndarray:
        R, p = self.markers[mid]
        return marker_corners_local(self.opts.side(mid)) @ R.T + p

    def _pnp(self, k: int, markers: list, guess: tuple) -> tuple | None:
        X = np.concatenate([self.world_corners(m) for m in markers])
        x = np.concatenate([self.obs[k][m] for m in markers]).reshape(-1, 1, 2)
        R0, C0 = guess
        ok, rv, tv = cv2.solvePnP(
            X,
            x,
            np.eye(3),
            None,
            rvec=matrix_to_rotvec(R0).reshape(3, 1).copy(),
            tvec=np.asarray(C0, dtype=float).reshape(3, 1).copy(),
            useExtrinsicGuess=True,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        return (rotvec_to_matrix(np.ravel(rv)), np.ravel(tv)) if ok else None

    def _rms(self, k: int, m: int, R: np.ndarray, C: np.ndarray) -> float:
        e = _gs_errors_px(R, C, self.world_corners(m), self.obs[k][m], self.f)
        return float(np.sqrt(np.mean(e**2)))

    def _ippe_guesses(self, k: int, known: list) -> list:
        """Camera poses (world -> camera) of frame ``k`` from each known marker's two planar
        solutions: starting points that need no previous frame (after a cut)."""
        out = []
        for m in known:
            Rm, pm = self.markers[m]
            for Rmc, tmc in _ippe_candidates(
                marker_corners_local(self.opts.side(m)), self.obs[k][m]
            ):
                R = Rmc @ Rm.T
                out.append((R, tmc - R @ pm))
        return out

    def pose_frame(self, k: int, guess: tuple | None, cut: bool = False) -> bool:
        """Pose of frame ``k`` from the placed markers it sees, started from ``guess``.

        With several markers, the pose from all of them and from each alone compete: the one
        that most markers agree with wins (ties: the one nearest the guess, the video being
        continuous); markers that disagree with it (a misdetection, or one id at another place)
        are left out of this frame's initialization. After a cut (``cut``: a gap in the
        stamps, another video), or when no start from the guess fits, each known marker's two
        planar solutions are tried as starts too."""
        known = [m for m in self.obs[k] if m in self.markers and (k, m) not in self.excluded]
        if not known:
            return False
        best = self._best_pose(k, known, guess, [guess] * (1 + (len(known) > 1) * len(known)))
        if cut or best is None or not best[2]:
            starts = self._ippe_guesses(k, known)
            alt = self._best_pose(k, known, guess, starts, subsets=[known] * len(starts))
            if alt is not None and (best is None or alt[0] > best[0]):
                best = alt
        if best is None or not best[2]:
            return False
        _, pose, agree = best
        self.excluded.update((k, m) for m in known if m not in agree)
        pose = self._pnp(k, agree, pose) or pose
        self.frames[k] = pose
        return True

    def _best_pose(
        self,
        k: int,
        known: list,
        guess: tuple | None,
        starts: list,
        subsets: list | None = None,
    ) -> tuple | None:
        """The best ``(score, pose, agreeing markers)`` over PnP from ``starts`` on
        ``subsets`` (default: all known markers, then each alone), or None."""
        if subsets is None:
            subsets = [known] + ([[m] for m in known] if len(known) > 1 else [])
        best = None
        for sub, start in zip(subsets, starts, strict=False):
            pose = self._pnp(k, sub, start)
            if pose is None:
                continue
            R, C = pose
            agree = [m for m in known if self._rms(k, m, R, C) <= self.gate_px]
            away = np.linalg.norm(matrix_to_rotvec(R @ guess[0].T)) + np.linalg.norm(
                R.T @ C - guess[0].T @ guess[1]
            )
            score = (len(agree), -away)
            if best is None or score > best[0]:
                best = (score, pose, agree)
        return best

    def new_marker(self, k: int, mid: int) -> None:
        obj = marker_corners_local(self.opts.side(mid))
        R, C = self.frames[k]
        best = None
        for Rmc, tmc in _ippe_candidates(obj, self.obs[k][mid]):
            Rm, pm = R.T @ Rmc, R.T @ (tmc - C)
            e = np.mean(_gs_errors_px(R, C, obj @ Rm.T + pm, self.obs[k][mid], self.f))
            if best is None or e < best[0]:
                best = (e, Rm, pm)
        self.markers[mid] = (best[1], best[2])

    def refine_marker(self, mid: int, frames: list) -> None:
        """Marker pose over its views ``frames`` (global-shutter reprojection, soft L1),
        started from its current pose and from its tilt mirrored through its mean viewing
        direction (the other planar solution, :func:`_mirrored_tilt`); the better fit is kept.
        A small marker's first view fits both tilts about equally, so the one picked there
        may be the wrong one: its later views, from other directions, tell them apart."""
        obj = marker_corners_local(self.opts.side(mid))
        R0, p0 = self.markers[mid]
        Rs = np.array([self.frames[k][0] for k in frames])
        Cs = np.array([self.frames[k][1] for k in frames])
        xs = np.array([self.obs[k][mid] for k in frames])

        def res(q):
            X = obj @ (rotvec_to_matrix(q[:3]) @ R0).T + q[3:]
            p = np.einsum("kij,nj->kni", Rs, X) + Cs[:, None, :]
            z = np.maximum(p[..., 2:3], 1e-6)
            return ((p[..., :2] / z - xs) * self.f).ravel()

        starts = [np.zeros(3)]
        centres = -np.einsum("kji,kj->ki", Rs, Cs)  # (the cameras' centres in the world)
        delta = _mirrored_tilt(R0, centres - p0)
        if delta is not None:
            starts.append(delta)
        best = None
        for r0 in starts:
            sol = least_squares(res, np.r_[r0, p0], loss="soft_l1", f_scale=5.0)
            if best is None or sol.cost < best.cost:
                best = sol
        self.markers[mid] = (rotvec_to_matrix(best.x[:3]) @ R0, best.x[3:])

    def adjust(self) -> None:
        """Global-shutter bundle adjustment of everything placed so far (gauge: the seed
        frame), a robust loss wide enough for the rolling-shutter shear."""
        frames = sorted(self.frames)
        markers = sorted(self.markers)
        opts = replace(self.opts, global_shutter=True, calibrate_readout=False, corner_offset=False)
        prob = _Problem(
            self,
            self.obs_px,
            self.camera,
            opts,
            frames,
            markers,
            None,
            frames.index(self.seed),
            self.excluded,
        )
        # (a loose tolerance and a small budget: this only keeps the initialization from
        # drifting)
        sol = prob.solve(
            prob.x0(self, self.camera.line_delay),
            loss="soft_l1",
            f_scale=5.0,
            tol=1e-4,
            max_nfev=30,
        )
        Rf, Cf, _, _, Rm, pm, _ = prob.unpack(sol.x)
        self.frames = {k: (Rf[i], Cf[i]) for i, k in enumerate(frames)}
        self.markers = {m: (Rm[i], pm[i]) for i, m in enumerate(markers)}

    def views(self, mid: int) -> list:
        return [k for k in self.frames if mid in self.obs[k] and (k, mid) not in self.excluded]

    def check_marker(self, mid: int) -> None:
        """Final decision on a marker: one place (else inconsistent), enough views."""
        # one id at two places: views whose own single-view position lies far from the map's
        # and agree among themselves
        every = [k for k in self.frames if mid in self.obs[k]]
        obj = marker_corners_local(self.opts.side(mid))
        own = {}
        for k in every:
            R, C = self.frames[k]
            ts = [t for _, t in _ippe_candidates(obj, self.obs[k][mid])]
            own[k] = R.T @ (np.mean(ts, axis=0) - C)
        pm = self.markers[mid][1]
        far = [
            k
            for k in every
            if np.linalg.norm(own[k] - pm)
            > max(
                0.5,
                3 * self.opts.side(mid),
                0.25 * np.linalg.norm(own[k] + self.frames[k][0].T @ self.frames[k][1]),
            )
        ]
        if len(far) >= self.opts.min_views:
            other = np.median([own[k] for k in far], axis=0)
            if all(np.linalg.norm(own[k] - other) < np.linalg.norm(other - pm) / 3 for k in far):
                # two places, or drift of the initialization: decided after the adjustment
                # (map_markers); meanwhile the marker stays at one place, the other's views out
                near = [k for k in every if k not in far]
                if len(near) < self.opts.min_views:
                    near, far = far, near
                    self.markers[mid] = (self.markers[mid][0], other)
                self.suspects[mid] = [near, far]
                self.excluded.update((k, mid) for k in far)
        frames = self.views(mid)
        if len(frames) < self.opts.min_views:
            self.unmapped[mid] = (
                f"seen in {len(frames)} frame(s) with a pose; at least {self.opts.min_views} "
                "needed to fix its pose"
            )
            del self.markers[mid]
            return
        self.refine_marker(mid, frames)

    def run(self) -> None:
        """Place the frames and markers; raises ValueError when the anchor cannot be placed."""
        keys = sorted(self.obs, key=lambda k: self.stamps[k])
        s = max(
            range(len(keys)),
            key=lambda i: (len(self.obs[keys[i]]), self.anchor in self.obs[keys[i]]),
        )
        self.seed = keys[s]
        self.frames[self.seed] = (np.eye(3), np.zeros(3))
        for m in self.obs[self.seed]:
            self.new_marker(self.seed, m)
        added = 0
        dts = np.diff([self.stamps[k] for k in keys])
        gap = self.opts.max_frame_gap * float(np.median(dts)) if len(dts) else 0.0
        for direction in (keys[s + 1 :], keys[:s][::-1]):
            prev = self.seed
            for k in direction:
                cut = abs(self.stamps[k] - self.stamps[prev]) > max(gap, 0.5)
                if not self.pose_frame(k, self.frames[prev], cut=cut):
                    continue
                prev = k
                added += 1
                if added % self.window == 0:
                    self.adjust()
                for m in self.obs[k]:
                    if (k, m) in self.excluded:
                        continue
                    if m not in self.markers:
                        self.new_marker(k, m)
                    else:
                        self.refine_marker(m, self.views(m)[-12:])
                self.pose_frame(k, self.frames[k])
        self.adjust()
        for mid in sorted(self.markers):
            self.check_marker(mid)
        # frames again with the refined markers
        for k in list(self.frames):
            if not self.pose_frame(k, self.frames[k]):
                del self.frames[k]
        if self.anchor not in self.markers:
            why = self.unmapped.get(self.anchor, "detected at places that disagree")
            raise ValueError(f"anchor marker {self.anchor} cannot be placed: {why}")


def _mirrored_tilt(R: np.ndarray, views: np.ndarray) -> np.ndarray | None:
    """Rotation vector (world axes, left perturbation) that mirrors the tilt of a marker
    (rotation ``R``, marker -> world) through its mean viewing direction: the other of the two
    poses of a square that fit a view from about that direction (IPPE's two solutions).
    ``views``: (K, 3) vectors from the marker's centre to the cameras (world). None when the
    marker is seen head-on (the two coincide)."""
    v = views @ R  # (in the marker's frame)
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    u = v.mean(axis=0)
    u /= max(np.linalg.norm(u), 1e-12)
    n_alt = 2 * u[2] * u - np.array([0.0, 0.0, 1.0])
    axis = np.cross([0.0, 0.0, 1.0], n_alt)
    ang = float(np.arctan2(np.linalg.norm(axis), n_alt[2]))
    if ang < 1e-6:
        return None
    return R @ (axis / np.linalg.norm(axis) * ang)


def _regauge(frames: dict, markers: dict, anchor: int, anchor_pose: tuple):
    """Move frames (world -> camera) and markers (marker -> world) rigidly so that the anchor
    sits at ``anchor_pose``; the reprojections do not change."""
    Ra, pa = markers[anchor]
    Rt, pt = anchor_pose
    Rg = Rt @ Ra.T
    pg = pt - Rg @ pa
    markers = {m: (Rg @ R, Rg @ p + pg) for m, (R, p) in markers.items()}
    markers[anchor] = (Rt, pt)
    frames = {k: (R @ Rg.T, C - R @ Rg.T @ pg) for k, (R, C) in frames.items()}
    return frames, markers, (Rg, pg)


# ------------------------------------------------------------------------- bundle adjustment


class _Problem:
    """Parameter layout, residuals and Jacobian sparsity of the bundle adjustment."""

    def __init__(
        self,
        init: _Init,
        obs_px: dict,
        camera: CameraModel,
        opts: MappingOptions,
        frames: list,
        markers: list,
        anchor: int,
        fix_frame: int | None = None,
        exclude: Iterable = (),
    ) -> None:
        self.camera = camera
        self.opts = opts
        self.frames = frames  # frame indices, parameter order
        self.markers = markers  # adjusted marker ids (anchor excluded)
        self.anchor = anchor
        self.vel = not opts.global_shutter
        self.fpar = 12 if self.vel else 6
        self.nf = len(frames)
        self.nm = len(markers)
        self.moff = self.nf * self.fpar
        self.ld_col = self.moff + 6 * self.nm if opts.calibrate_readout else None
        self.n = self.moff + 6 * self.nm + (1 if opts.calibrate_readout else 0)
        self.co_col = self.n if opts.corner_offset else None
        self.n += 1 if opts.corner_offset else 0
        # pixel noise of the detections (the reprojection rows are in pixels, unweighted): the
        # corner offset's prior row is scaled by it so that it weighs as its sigma says
        self.noise_px = 1.0
        self.R0f = np.array([init.frames[k][0] for k in frames])
        self.C0f = np.array([init.frames[k][1] for k in frames])
        self.R0m = np.array([init.markers[m][0] for m in markers])
        self.p0m = np.array([init.markers[m][1] for m in markers])
        self.fix = fix_frame
        if anchor is None:
            self.Ra, self.pa = np.eye(3), np.zeros(3)
        else:
            self.Ra, self.pa = init.markers[anchor]
        self.local = {m: marker_corners_local(opts.side(m)) for m in {*markers, anchor} - {None}}
        fidx = {k: i for i, k in enumerate(frames)}
        midx = {m: i for i, m in enumerate(markers)}
        # one row block per detection (4 corners)
        self.det = []  # (frame index, marker id)
        fi, mi, loc, xs, taus = [], [], [], [], []
        for k in frames:
            for m, uv in obs_px[k].items():
                if (m != anchor and m not in midx) or (k, m) in exclude:
                    continue
                x, r, _ = camera.normalize(uv)
                self.det.append((k, m))
                fi.append(np.full(4, fidx[k]))
                mi.append(np.full(4, midx.get(m, -1)))
                loc.append(self.local[m])
                xs.append(x)
                taus.append(r - camera.r0)
        self.fi = np.concatenate(fi)
        self.mi = np.concatenate(mi)
        self.loc = np.concatenate(loc)
        self.x = np.concatenate(xs)
        self.tau = np.concatenate(taus)
        self.keep = np.ones(len(self.det), dtype=bool)
        self.fxy = np.array([camera.K[0, 0], camera.K[1, 1]])
        # motion tie between consecutive frames
        self.ties = []
        if self.vel and opts.motion_sigma_rot is not None and opts.motion_sigma_pos is not None:
            st = np.array([init.stamps[k] for k in frames])
            dts = np.diff(st)
            if len(dts):
                med = np.median(dts)
                self.ties = [
                    (i, i + 1, dts[i])
                    for i in range(len(dts))
                    if 0 < dts[i] <= opts.max_frame_gap * med
                ]
        if opts.calibrate_readout and not self.ties:
            raise ValueError(
                "calibrating the line delay needs consecutive frames tied by the motion model "
                "(a video with stamps, the rolling-shutter model and motion_sigma_* set)"
            )

    def x0(self, init: _Init, line_delay: float) -> np.ndarray:
        x = np.zeros(self.n)
        F = x[: self.moff].reshape(self.nf, self.fpar)
        F[:, 3:6] = self.C0f
        if self.vel:
            st = np.array([init.stamps[k] for k in self.frames])
            for i in range(self.nf):
                a, b = max(i - 1, 0), min(i + 1, self.nf - 1)
                dt = st[b] - st[a]
                if b == a or dt <= 0 or dt > 3 * self.opts.max_frame_gap * np.median(np.diff(st)):
                    continue
                F[i, 6:9] = matrix_to_rotvec(self.R0f[b] @ self.R0f[a].T) / dt
                F[i, 9:12] = (self.C0f[b] - self.C0f[a]) / dt
        x[self.moff : self.moff + 6 * self.nm].reshape(self.nm, 6)[:, 3:6] = self.p0m
        if self.ld_col is not None:
            x[self.ld_col] = line_delay * 1e6
        return x

    def unpack(self, x: np.ndarray) -> tuple:
        F = x[: self.moff].reshape(self.nf, self.fpar)
        Rf = rotvec_to_matrix(F[:, :3]) @ self.R0f
        Cf = F[:, 3:6]
        W = F[:, 6:9] if self.vel else np.zeros((self.nf, 3))
        T = F[:, 9:12] if self.vel else np.zeros((self.nf, 3))
        M = x[self.moff : self.moff + 6 * self.nm].reshape(self.nm, 6)
        Rm = rotvec_to_matrix(M[:, :3]) @ self.R0m
        pm = M[:, 3:6]
        ld = x[self.ld_col] * 1e-6 if self.ld_col is not None else self.camera.line_delay
        return Rf, Cf, W, T, Rm, pm, ld

    def corner_offset(self, x: np.ndarray) -> float:
        """The detector's corner offset (pixels, inwards) in ``x``; 0 when not estimated."""
        return float(x[self.co_col]) if self.co_col is not None else 0.0

    def corner_residuals(self, x: np.ndarray) -> np.ndarray:
        """(N, 2) reprojection residuals (pixels) of all corners."""
        Rf, Cf, W, T, Rm, pm, ld = self.unpack(x)
        Rm_all = np.concatenate([Rm, self.Ra[None]])
        pm_all = np.concatenate([pm, self.pa[None]])
        X = np.einsum("nij,nj->ni", Rm_all[self.mi], self.loc) + pm_all[self.mi]
        ts = self.tau * (ld * self.camera.focal)
        A = rotvec_to_matrix(ts[:, None] * W[self.fi])
        p = np.einsum("nij,nj->ni", A @ Rf[self.fi], X) + Cf[self.fi] + ts[:, None] * T[self.fi]
        z = np.where(p[:, 2] > 1e-6, p[:, 2], 1e-6)
        u = p[:, :2] / z[:, None] * self.fxy
        e = u - self.x * self.fxy
        if self.co_col is not None:  # detections lie inside the square along its diagonals
            q = u.reshape(-1, 4, 2)  # (the four corners of each detection)
            d = (q - q.mean(axis=1, keepdims=True)).reshape(-1, 2)
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
            e = e - x[self.co_col] * d
        return e

    def residuals(self, x: np.ndarray) -> np.ndarray:
        e = self.corner_residuals(x).reshape(-1, 8)[self.keep].ravel()
        if self.fix is not None:  # gauge on a frame: its pose held (stiff prior)
            F = x[: self.moff].reshape(self.nf, self.fpar)
            e = np.concatenate(
                [e, 1e3 * F[self.fix, :3], 1e3 * (F[self.fix, 3:6] - self.C0f[self.fix])]
            )
        if self.co_col is not None:  # the corner offset's prior: zero mean
            prior = x[self.co_col] / self.opts.corner_offset_sigma_px * self.noise_px
            e = np.concatenate([e, [prior]])
        if not self.ties:
            return e
        Rf, Cf, W, T, *_ = self.unpack(x)
        i = np.array([a for a, _, _ in self.ties])
        j = np.array([b for _, b, _ in self.ties])
        dt = np.array([d for _, _, d in self.ties])[:, None]
        er = matrix_to_rotvec(Rf[j] @ np.swapaxes(Rf[i], 1, 2)) - dt * 0.5 * (W[i] + W[j])
        ec = Cf[j] - Cf[i] - dt * 0.5 * (T[i] + T[j])
        o = self.opts
        # the angular velocity changes by about the angular acceleration times the time between
        # frames (without it the mean of two frames' velocities is tied, their difference free)
        ew = (W[j] - W[i]) / (o.motion_sigma_angular_accel * dt)
        return np.concatenate(
            [
                e,
                (er / o.motion_sigma_rot).ravel(),
                (ec / o.motion_sigma_pos).ravel(),
                ew.ravel(),
            ]
        )

    def solve(
        self,
        x0: np.ndarray,
        *,
        loss: str = "linear",
        f_scale: float = 1.0,
        tol: float = 1e-6,
        max_nfev: int | None = None,
    ) -> Any:
        """SciPy ``least_squares`` (trust region reflective with this problem's Jacobian
        sparsity, Jacobian-scaled variables) on :meth:`residuals` from ``x0``; ``loss``,
        ``f_scale``, ``tol`` (``ftol`` and ``xtol``) and ``max_nfev`` (default: the options')
        as SciPy's."""
        return least_squares(
            self.residuals,
            x0,
            jac_sparsity=self.sparsity(),
            loss=loss,
            f_scale=f_scale,
            x_scale="jac",
            max_nfev=self.opts.max_nfev if max_nfev is None else max_nfev,
            ftol=tol,
            xtol=tol,
            method="trf",
        )

    def sparsity(self) -> csr_matrix:
        nd = int(self.keep.sum())
        nfix = 6 if self.fix is not None else 0
        nco = 1 if self.co_col is not None else 0
        S = lil_matrix((8 * nd + nfix + nco + 9 * len(self.ties), self.n), dtype=np.int8)
        midx = {m: i for i, m in enumerate(self.markers)}
        fidx = {k: i for i, k in enumerate(self.frames)}
        row = 0
        for (k, m), kept in zip(self.det, self.keep, strict=True):
            if not kept:
                continue
            f0 = fidx[k] * self.fpar
            S[row : row + 8, f0 : f0 + self.fpar] = 1
            if m in midx:
                m0 = self.moff + 6 * midx[m]
                S[row : row + 8, m0 : m0 + 6] = 1
            if self.ld_col is not None:
                S[row : row + 8, self.ld_col] = 1
            if self.co_col is not None:
                S[row : row + 8, self.co_col] = 1
            row += 8
        if nfix:
            S[row : row + 6, self.fix * self.fpar : self.fix * self.fpar + 6] = 1
            row += 6
        if nco:
            S[row, self.co_col] = 1
            row += 1
        for _ in range(3):  # rotation, position and angular velocity rows of all ties
            for i, j, _ in self.ties:
                for a in (i, j):
                    S[row : row + 3, a * self.fpar : (a + 1) * self.fpar] = 1
                row += 3
        return S.tocsr()


def _marker_covariance(jac, n_rep: int, sigma: float, prob: _Problem) -> np.ndarray:
    """Covariance (6 M, 6 M) of the adjusted markers' parameters (rotation vector, centre; M =
    ``prob.nm``) at the solution: the markers' block of ``(J^T J)^-1`` with the first ``n_rep``
    rows of ``jac`` (those in pixels) scaled by ``1 / sigma``, the other parameters (frames,
    line delay) marginalized by the Schur complement with a sparse LU factorization of their
    block (SciPy ``splu``); where that block is singular, the dense pseudo-inverse of the
    whole ``J^T J``."""
    J = csr_matrix(jac)
    scale = np.ones(J.shape[0])
    scale[:n_rep] = 1.0 / max(sigma, 1e-12)
    J = diags(scale) @ J
    H = (J.T @ J).tocsc()
    m0, m1 = prob.moff, prob.moff + 6 * prob.nm
    other = np.r_[np.arange(m0), np.arange(m1, H.shape[0])]
    Hmm = H[m0:m1, m0:m1].toarray()
    Hoo = H[other][:, other].tocsc()
    Hom = H[other][:, m0:m1].toarray()
    try:
        with np.errstate(all="raise"):
            X = splu(Hoo).solve(Hom)
        if not np.isfinite(X).all():
            raise FloatingPointError
    except (RuntimeError, FloatingPointError):
        full = np.linalg.pinv(H.toarray(), rcond=1e-12, hermitian=True)
        return full[m0:m1, m0:m1]
    return np.linalg.pinv(Hmm - Hom.T @ X, rcond=1e-12, hermitian=True)


def _two_places(suspects: dict, Rf, Cf, fr_ids, obs_n, options) -> dict:
    """Ids whose two groups of views place them more than max(0.5 m, 3 sides) apart with the
    adjusted frames (world -> camera ``Rf``, ``Cf``): id -> [place, place], each the median of
    its views' single-view centres (IPPE)."""
    fpos = {k: i for i, k in enumerate(fr_ids)}
    out = {}
    for m, groups in suspects.items():
        obj = marker_corners_local(options.side(m))
        places = []
        for views in groups:
            cs = [
                Rf[fpos[k]].T
                @ (np.mean([t for _, t in _ippe_candidates(obj, obs_n[k][m])], 0) - Cf[fpos[k]])
                for k in views
                if k in fpos
            ]
            if cs:
                places.append(np.median(cs, axis=0))
        if len(places) == 2 and np.linalg.norm(places[0] - places[1]) > max(
            0.5, 3 * options.side(m)
        ):
            out[m] = places
    return out


def _read_detections(frames: Sequence[FrameDetections], camera: CameraModel) -> tuple:
    """``(obs_px, obs_n, stamps)``: per frame with detections, id -> (4, 2) pixel corners and
    undistorted normalized corners, and the stamps. Raises ValueError on corners that are not
    (4, 2) and finite, or no detections at all."""
    obs_px, obs_n, stamps = {}, {}, {}
    for k, fr in enumerate(frames):
        if not fr.corners:
            continue
        obs_px[k], obs_n[k] = {}, {}
        for mid, c in fr.corners.items():
            c = np.asarray(c, dtype=float)
            if c.shape != (4, 2) or not np.isfinite(c).all():
                raise ValueError(f"frame {k}: marker {mid} needs (4, 2) finite pixel corners")
            obs_px[k][int(mid)] = c
            obs_n[k][int(mid)] = camera.undistort(c)
        stamps[k] = float(fr.stamp)
    if not obs_px:
        raise ValueError(
            f"no marker detections in any of the {len(frames)} frames "
            "(wrong dictionary, or no markers in view)"
        )
    return obs_px, obs_n, stamps


def _choose_gauge(obs_px: dict, options: MappingOptions) -> tuple[int, list]:
    """The marker held fixed in the adjustment (the internal gauge) and the surveyed anchors.

    ``options.anchor`` given: that marker. ``options.anchors`` given: the most detected of
    them. Neither: the most detected marker (its pose is fixed by the most views). Raises
    ValueError naming an anchor that no frame detects."""
    ids = {m for d in obs_px.values() for m in d}
    count = {m: sum(m in d for d in obs_px.values()) for m in ids}
    wanted = [int(options.anchor)] if options.anchor is not None else []
    wanted += [int(m) for m in (options.anchors or {})]
    missing = [m for m in wanted if m not in ids]
    if missing:
        raise ValueError(
            f"anchor marker {', '.join(map(str, missing))} is not detected in any frame "
            f"(detected ids: {sorted(ids)})"
        )
    if options.anchor is not None:
        return int(options.anchor), wanted
    pool = wanted or sorted(ids)
    return max(pool, key=lambda m: (count[m], -m)), wanted


def _coarse_adjustment(init: _Init, obs_px, camera, options, anchor, anchor_pose) -> None:
    """A coarse rolling-shutter adjustment (gauge: the starting frame, wide robust scale) that
    pulls the initialization together, then the whole moved rigidly onto ``anchor_pose``."""
    fr_ids = sorted(init.frames)
    all_ids = sorted(init.markers)
    free = _Problem(
        init,
        obs_px,
        camera,
        options,
        fr_ids,
        all_ids,
        None,
        fix_frame=fr_ids.index(init.seed),
        exclude=init.excluded,
    )
    # (a loose tolerance: only to start the adjustments below close to the solution)
    sol = free.solve(free.x0(init, camera.line_delay), loss="soft_l1", f_scale=10.0, tol=1e-4)
    Rf, Cf, _, _, Rm, pm, _ = free.unpack(sol.x)
    init.frames, init.markers, _ = _regauge(
        {k: (Rf[i], Cf[i]) for i, k in enumerate(fr_ids)},
        {m: (Rm[i], pm[i]) for i, m in enumerate(all_ids)},
        anchor,
        anchor_pose,
    )


def _adjust_and_reject(init, obs_px, obs_n, camera, options, anchor, timings, bar) -> tuple:
    """Rolling-shutter bundle adjustment with the gauge marker fixed: robust loss, rejection of
    detections over ``reject_px``, plain least squares; views split by drift of the
    initialization (not a second copy of the id) are taken back and the map adjusted again.
    Returns ``(problem, solution, inconsistent ids, excluded detections)``."""
    fr_ids = sorted(init.frames)
    mk_ids = [m for m in sorted(init.markers) if m != anchor]
    exclude = set(init.excluded)
    x_start = None
    for rnd in range(2):
        prob = _Problem(init, obs_px, camera, options, fr_ids, mk_ids, anchor, exclude=exclude)
        t0 = time.perf_counter()
        sol = prob.solve(
            prob.x0(init, camera.line_delay) if x_start is None else x_start,
            loss=options.loss,
            f_scale=options.f_scale_px,
        )
        timings["robust adjustment"] = timings.get("robust adjustment", 0.0) + (
            time.perf_counter() - t0
        )
        e8 = prob.corner_residuals(sol.x).reshape(-1, 8)  # (one row per detection)
        prob.keep = np.sqrt(np.mean(e8**2, axis=1)) <= options.reject_px
        kept = e8[prob.keep]
        prob.noise_px = float(np.sqrt(np.mean(kept**2))) if kept.size else 1.0
        t0 = time.perf_counter()
        sol = prob.solve(sol.x)
        timings["final adjustment"] = timings.get("final adjustment", 0.0) + (
            time.perf_counter() - t0
        )
        bar.update(1)
        bar.set_postfix_str(
            f"round {rnd + 1}: cost {sol.cost:.4g}, rms {prob.noise_px:.2f} px, "
            f"{int((~prob.keep).sum())} detections rejected"
        )
        Rf, Cf, *_ = prob.unpack(sol.x)
        inconsistent = _two_places(init.suspects, Rf, Cf, fr_ids, obs_n, options)
        # views split by drift of the initialization, not by a second copy: adjust again
        # with them
        drift = {(k, m) for k, m in exclude if m in init.suspects and m not in inconsistent}
        if not drift or x_start is not None:
            break
        exclude -= drift
        x_start = sol.x
    return prob, sol, inconsistent, exclude


def _view_clusters(prob: _Problem, Rf, Cf, Rm_all: dict, angle: float) -> np.ndarray:
    """(D,) cluster label of every detection: detections of one marker whose viewing
    directions (marker -> camera, in the marker's frame) lie within ``angle`` rad of the
    cluster's first one and whose distances differ by less than 30 % share a label."""
    fidx = {k: i for i, k in enumerate(prob.frames)}
    labels = np.full(len(prob.det), -1)
    heads: dict = {}  # marker -> [(label, direction, distance)]
    nxt = 0
    cos_max = np.cos(angle)
    for d, (k, m) in enumerate(prob.det):
        i = fidx[k]
        R, p = Rm_all[m]
        v = R.T @ (-Rf[i].T @ Cf[i] - p)
        dist = float(np.linalg.norm(v))
        u = v / max(dist, 1e-9)
        for lab, u0, d0 in heads.setdefault(m, []):
            if u @ u0 > cos_max and abs(np.log(dist / d0)) < np.log(1.3):
                labels[d] = lab
                break
        else:
            heads[m].append((nxt, u, dist))
            labels[d] = nxt
            nxt += 1
    return labels


def _shared_error_weights(prob: _Problem, x, labels: np.ndarray) -> tuple[np.ndarray, float]:
    """Weights (D,) of the detections in the covariance, and the correlation found.

    A detector's error on a marker repeats when the marker is seen again from the same
    viewpoint (the same image of it: same blur, same pixels on its edges), so detections from
    one viewpoint do not add independent information. The correlation ``rho`` of the
    residuals of consecutive detections of one marker within a viewpoint cluster is
    estimated from the adjustment's own residuals (0 for independent noise); a cluster of
    ``n`` detections then carries the information of ``n / (1 + (n - 1) rho)`` independent
    ones (the design effect of equally correlated samples), and each of its detections is
    weighted by ``1 / (1 + (n - 1) rho)``."""
    e8 = prob.corner_residuals(x).reshape(-1, 8)
    keep = prob.keep
    last: dict = {}
    num = den = 0.0
    for d in range(len(prob.det)):
        if not keep[d]:
            continue
        lab = labels[d]
        if lab in last:
            a, b = e8[last[lab]], e8[d]
            num += float(a @ b)
            den += float(np.sqrt((a @ a) * (b @ b)))
        last[lab] = d
    rho = float(np.clip(num / den, 0.0, 1.0)) if den > 0 else 0.0
    n = np.bincount(labels[keep], minlength=labels.max() + 1)
    w = 1.0 / (1.0 + (n[labels] - 1) * rho)
    return w, rho


def _gauge_covariance(prob: _Problem, sol, weights: np.ndarray) -> tuple[np.ndarray, float]:
    """Joint covariance (6 M, 6 M) of the adjusted markers (gauge: the fixed marker) and the
    estimated pixel noise: reprojection rows weighted by ``weights`` (per detection) and
    scaled by the noise (:func:`_marker_covariance`)."""
    e = prob.corner_residuals(sol.x).reshape(-1, 8)[prob.keep]
    n_rep = e.size
    dof = max(n_rep - prob.n, 1)
    sigma = float(np.sqrt(np.sum(e**2) / dof))
    J = csr_matrix(sol.jac)
    scale = np.ones(J.shape[0])
    scale[:n_rep] = np.repeat(np.sqrt(weights[prob.keep]), 8)
    # (the corner offset's prior row follows the reprojections and is in pixels too)
    n_px = n_rep + (1 if prob.co_col is not None else 0)
    return _marker_covariance(diags(scale) @ J, n_px, sigma, prob), sigma


def _mirror_covariance(prob: _Problem, x, weights, sigma: float, poses: dict) -> dict:
    """id -> (6, 6) covariance to add to a marker's pose for the planar ambiguity of its tilt.

    A square seen from about one direction has two poses that fit it: the true one and its
    tilt mirrored through the viewing direction (the two solutions of IPPE). Far and small,
    both fit almost equally, and the linearized covariance at one of them, which can be sharp
    there, says nothing of the other. For each marker the tilt is mirrored through its mean
    viewing direction (rotation ``delta``, the frames and the centre held), and the rise of
    its weighted reprojection cost ``d = sum w e^2 / sigma^2`` gives the variance along
    ``delta`` that the cost's secant implies, ``|delta|^2 / d``; where that exceeds the
    linearized variance along ``delta``, the difference is added along it (rotation block)."""
    Rf, Cf, *_ = prob.unpack(x)
    fidx = {k: i for i, k in enumerate(prob.frames)}
    midx = {m: i for i, m in enumerate(prob.markers)}
    e8 = prob.corner_residuals(x).reshape(-1, 8)
    out = {}
    for m, (R, p) in poses.items():
        rows = [d for d, (k, mm) in enumerate(prob.det) if mm == m and prob.keep[d]]
        if not rows:
            continue
        views = np.array([-Rf[fidx[prob.det[d][0]]].T @ Cf[fidx[prob.det[d][0]]] - p for d in rows])
        delta = _mirrored_tilt(R, views)  # (world axes, left perturbation)
        if delta is None:
            continue
        ang = float(np.linalg.norm(delta))
        R_alt = rotvec_to_matrix(delta) @ R
        x_alt = np.array(x, dtype=float)
        Ra_save = prob.Ra
        if m in midx:
            M = x_alt[prob.moff : prob.moff + 6 * prob.nm].reshape(prob.nm, 6)
            M[midx[m], :3] = matrix_to_rotvec(R_alt @ prob.R0m[midx[m]].T)
        else:
            prob.Ra = R_alt
        try:
            e_alt = prob.corner_residuals(x_alt).reshape(-1, 8)
        finally:
            prob.Ra = Ra_save
        w = weights[rows]
        rise = float(np.sum(w * (np.sum(e_alt[rows] ** 2, 1) - np.sum(e8[rows] ** 2, 1))))
        rise = max(rise / sigma**2, 1.0)
        d = delta / ang
        var = ang**2 / rise
        out[m] = (d, var)
    return out


def _fit_rigid(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) minimizing ``|R src + t - dst|`` over (N, 3)
    points (Kabsch; SciPy ``Rotation.align_vectors`` on the centred points)."""
    from scipy.spatial.transform import Rotation

    cs, cd = src.mean(0), dst.mean(0)
    rot, _ = Rotation.align_vectors(dst - cd, src - cs)
    R = rot.as_matrix()
    return R, cd - R @ cs


def shape_covariance(points: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The shape-only part (3 N, 3 N) of the joint covariance ``cov`` (3 N, 3 N) of ``points``
    (N, 3): the covariance projected onto the complement of the rigid motions of all points
    together, ``P cov P^T`` with ``P = I - G G^+`` and ``G`` the (3 N, 6) stacked
    ``[I, -[x_i]x]`` (a small translation and rotation of the whole set). This is the
    minimum-trace (inner-constraint) gauge of bundle adjustment (Triggs, McLauchlan, Hartley,
    Fitzgibbon, "Bundle Adjustment: A Modern Synthesis", 2000, section 9): it does not depend
    on which gauge ``cov`` was computed in, and it is the covariance of the points after a
    best rigid fit of the whole set onto its mean (to first order). What it keeps is each
    point's error relative to the others, which is what a camera localized against the
    points sees; the uncertainty of where the whole set sits goes to the frame."""
    x = np.asarray(points, float)
    n = len(x)
    G = np.zeros((3 * n, 6))
    for i, c in enumerate(x - x.mean(0)):
        G[3 * i : 3 * i + 3, :3] = np.eye(3)
        G[3 * i : 3 * i + 3, 3:] = -skew(c)
    P = np.eye(3 * n) - G @ np.linalg.pinv(G)
    return P @ np.asarray(cov, float) @ P.T


def corner_jacobian(R_o: np.ndarray) -> np.ndarray:
    """(3, 6) derivative of a marker corner ``c = p + R o`` (m, map frame) with respect to its
    marker's pose perturbation (rotation vector applied on the left, rad; centre, m), the
    order of ``MarkerMapResult.marker_covariance``: ``[-[R o]x, I]``. ``R_o``: (3,) the
    corner's offset ``R o`` from the marker centre (m, map frame)."""
    return np.hstack([-skew(np.asarray(R_o, float)), np.eye(3)])


def _corner_shape_std(poses: dict, ids: list, cov: np.ndarray, sides: dict, keep) -> dict:
    """id -> (4,) shape-only std of each corner of the markers in ``keep`` (m, rms per axis:
    ``sqrt(trace / 3)``): the joint covariance of all their corners, ``J cov J^T`` with a
    corner ``c = p + R o`` moving by ``[-[R o]x, I]`` with its marker's pose perturbation
    (``ids``' order in ``cov``), projected by :func:`shape_covariance`."""
    ms = [m for m in ids if m in keep]
    ms = list(dict.fromkeys(ms))
    J = np.zeros((12 * len(ms), cov.shape[0]))
    pts = []
    for a, m in enumerate(ms):
        R, p = poses[m]
        j = 6 * ids.index(m)
        for k, o in enumerate(marker_corners_local(sides[m])):
            ro = R @ o
            r = 12 * a + 3 * k
            J[r : r + 3, j : j + 6] = corner_jacobian(ro)
            pts.append(p + ro)
    S = shape_covariance(np.array(pts), J @ cov @ J.T)
    d = np.clip(np.diag(S), 0.0, None).reshape(len(ms), 4, 3)
    return {m: np.sqrt(d[a].sum(1) / 3.0) for a, m in enumerate(ms)}


@dataclass
class OutputFrame:
    """How the map's output frame is fixed and how well.

    Attributes:
        kind: ``anchor`` (one marker at its pose), ``surveyed`` (best fit to surveyed
            markers) or ``best-observed`` (the most detected marker).
        anchors: the markers that fix it.
        rotation_std_deg, position_std_mm: the frame's own uncertainty against the map as a
            whole (the rigid best fit of all mapped markers' centres): standard deviation of
            its rotation (largest axis, deg) and of its origin (largest axis, mm).
        covariance: (6, 6) that uncertainty (rotation rad, position m; map axes).
        residual_mm: RMS corner residual of the surveyed markers after the fit (0 else).
        shared_error_correlation: correlation of the detections' errors from one viewpoint
            (:func:`_shared_error_weights`) used in the covariances.
    """

    kind: str
    anchors: list
    rotation_std_deg: float
    position_std_mm: float
    covariance: np.ndarray
    residual_mm: float = 0.0
    shared_error_correlation: float = 0.0


def _pose_vector_map(poses: dict, ids: list, x: np.ndarray) -> dict:
    """Marker poses with the perturbation ``x`` (6 per id: rotation vector, world axes left;
    centre) applied."""
    out = dict(poses)
    for i, m in enumerate(ids):
        R, p = poses[m]
        out[m] = (rotvec_to_matrix(x[6 * i : 6 * i + 3]) @ R, p + x[6 * i + 3 : 6 * i + 6])
    return out


def _output_transform(poses: dict, options: MappingOptions, gauge: int, sides: dict) -> tuple:
    """Rigid transform ``(R, t)`` from the adjustment's frame to the output frame, and the RMS
    corner residual (m) of the surveyed anchors (0 for one anchor)."""
    if options.anchors:
        ids = sorted(options.anchors)
        src = np.concatenate(
            [marker_corners_local(sides[m]) @ poses[m][0].T + poses[m][1] for m in ids]
        )
        dst = np.concatenate([np.asarray(options.anchors[m], float).reshape(4, 3) for m in ids])
        R, t = _fit_rigid(src, dst)
        res = np.linalg.norm(src @ R.T + t - dst, axis=1)
        return R, t, float(np.sqrt(np.mean(res**2)))
    anchor = gauge if options.anchor is None else int(options.anchor)
    Rt, pt = options.anchor_pose if options.anchor_pose is not None else (np.eye(3), np.zeros(3))
    Ra, pa = poses[anchor]
    R = np.asarray(Rt, float) @ Ra.T
    return R, np.asarray(pt, float) - R @ pa, 0.0


def _propagate(poses: dict, ids: list, cov: np.ndarray, options, gauge, sides) -> tuple:
    """Marker poses and covariances in the output frame, and the frame's covariance.

    The adjustment holds the gauge marker fixed; the output frame is a function of the
    estimated markers (an anchor's pose, or a best fit to surveyed markers), so its own
    uncertainty enters every marker's: with ``y(x)`` the markers' poses in the output frame
    as a function of all adjusted markers' poses ``x`` (6 per marker), the covariance is
    ``A cov A^T`` with ``A = dy/dx`` (central differences). The frame's own uncertainty is
    that of the output frame against the rigid best fit of all markers' centres (the map as a
    whole), by the same propagation."""
    cent_ids = sorted(poses)
    all_out = sorted(poses)
    h = 1e-6

    def outputs(x: np.ndarray) -> np.ndarray:
        P = _pose_vector_map(poses, ids, x)
        R, t, _ = _output_transform(P, options, gauge, sides)
        y = []
        for m in all_out:
            Rm, pm = P[m]
            y.append(matrix_to_rotvec(R @ Rm @ R0_out[m].T))
            y.append(R @ pm + t)
        # the output frame against the best fit of all centres
        C = np.array([P[m][1] for m in cent_ids])
        Rb, tb = _fit_rigid(C, np.array([poses[m][1] for m in cent_ids]))
        # frame -> adjustment frame is (R^T, -R^T t); map it by the best fit
        Rf = Rb @ R.T
        y.append(matrix_to_rotvec(Rf @ R0_frame.T))
        y.append(tb - Rb @ R.T @ t)
        return np.concatenate(y)

    R_, _, _ = _output_transform(poses, options, gauge, sides)
    R0_frame = R_.T
    R0_out = {m: R_ @ poses[m][0] for m in all_out}
    y0 = outputs(np.zeros(6 * len(ids)))
    A = np.empty((y0.size, 6 * len(ids)))
    for j in range(6 * len(ids)):
        dx = np.zeros(6 * len(ids))
        dx[j] = h
        A[:, j] = (outputs(dx) - outputs(-dx)) / (2 * h)
    S = A @ cov @ A.T
    out_cov = {m: S[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i, m in enumerate(all_out)}
    G = np.kron(np.eye(2), R_)  # (the frame's uncertainty on the output axes)
    frame_cov = G @ S[-6:, -6:] @ G.T
    return out_cov, frame_cov


def _best_observed(poses: dict, ids: list, cov: np.ndarray) -> int:
    """The marker whose pose the map fixes best: the smallest uncertainty of its pose
    against the map as a whole (the markers' poses moved by the rigid best fit of all centres
    onto the estimate, covariance by central differences as :func:`_propagate`), scored as
    the position variance the rotation's uncertainty causes at the map's median distance
    from it plus its own position variance (largest axes)."""
    all_ids = sorted(poses)
    cent = np.array([poses[m][1] for m in all_ids])
    R0 = {m: poses[m][0] for m in all_ids}

    def outputs(x: np.ndarray) -> np.ndarray:
        P = _pose_vector_map(poses, ids, x)
        C = np.array([P[m][1] for m in all_ids])
        Rb, tb = _fit_rigid(C, cent)
        y = []
        for m in all_ids:
            y.append(matrix_to_rotvec(Rb @ P[m][0] @ R0[m].T))
            y.append(Rb @ P[m][1] + tb)
        return np.concatenate(y)

    h = 1e-6
    n = 6 * len(ids)
    A = np.empty((6 * len(all_ids), n))
    for j in range(n):
        dx = np.zeros(n)
        dx[j] = h
        A[:, j] = (outputs(dx) - outputs(-dx)) / (2 * h)
    S = A @ cov @ A.T
    best, score = all_ids[0], np.inf
    for i, m in enumerate(all_ids):
        r = np.median(np.linalg.norm(cent - poses[m][1], axis=1))
        blk = S[6 * i : 6 * i + 6, 6 * i : 6 * i + 6]
        sc = np.linalg.eigvalsh(blk[:3, :3])[-1] * r**2 + np.linalg.eigvalsh(blk[3:, 3:])[-1]
        if sc < score:
            best, score = m, sc
    return best


def _coverage(prob, Rf, Cf, poses, std, sides, bound: float) -> dict:
    """id -> why a marker's stated position std (largest axis) exceeds ``bound`` (m): seen
    in few frames, only from far, only head-on, from one direction."""
    fidx = {k: i for i, k in enumerate(prob.frames)}
    views: dict = {}
    for (k, m), kept in zip(prob.det, prob.keep, strict=True):
        if kept and m in poses:
            i = fidx[k]
            R, p = poses[m]
            views.setdefault(m, []).append(R.T @ (-Rf[i].T @ Cf[i] - p))
    out = {}
    for m, s in std.items():
        worst = float(np.max(s[3:]))
        if worst <= bound or m not in views:
            continue
        v = np.array(views[m])
        dist = np.linalg.norm(v, axis=1)
        u = v / dist[:, None]
        tilt = np.degrees(np.arccos(np.clip(u[:, 2], -1, 1)))
        spread = np.degrees(np.arccos(np.clip(u @ u.mean(0) / np.linalg.norm(u.mean(0)), -1, 1)))
        why = []
        if len(v) < 10:
            why.append(f"seen in {len(v)} frames")
        if dist.min() > 12 * sides[m]:
            why.append(f"only from far (closest {dist.min():.1f} m, {sides[m] * 100:.0f} cm side)")
        if tilt.max() < 20:
            why.append(f"only head-on (within {tilt.max():.0f} deg of its face normal)")
        elif spread.max() < 10:
            why.append(f"from one direction only (within {spread.max():.0f} deg)")
        out[m] = (
            f"std {worst * 1000:.0f} mm: "
            + (", ".join(why) if why else "far from the markers that fix the frame")
            + "; views from closer and at an angle would fix it"
        )
    return out


def concatenate_videos(videos: Sequence[Sequence[FrameDetections]], gap: float = 10.0) -> list:
    """Several videos of one place as one sequence for :func:`map_markers`: each video's
    stamps shifted to start ``gap`` seconds after the previous one ends (no motion tie across
    the cut). Returns the frames; :func:`video_of_frames` gives which video each came from."""
    out, t_end = [], None
    for v in videos:
        v = list(v)
        if not v:
            continue
        shift = 0.0 if t_end is None else t_end + gap - v[0].stamp
        out.extend(FrameDetections(f.stamp + shift, f.corners) for f in v)
        t_end = out[-1].stamp
    return out


def map_markers(
    frames: Sequence[FrameDetections],
    camera: CameraModel,
    options: MappingOptions,
    progress: bool = False,
    videos: Sequence[int] | None = None,
) -> MarkerMapResult:
    """Build a marker map from a video's detections with rolling-shutter bundle adjustment.

    Stages: (1) initialization in capture order from the frame that sees the most markers
    (:class:`_Init`): each frame's pose by OpenCV ``solvePnP`` (Levenberg-Marquardt from the
    previous frame's pose, so a frame seeing a single marker keeps the continuous one of the
    two planar solutions), a new marker by the better of its two ``SOLVEPNP_IPPE_SQUARE``
    poses, refined over all its views so far from both tilts; every 25 frames and at the end a
    global-shutter adjustment of everything placed (SciPy ``least_squares``, soft L1); a marker
    seen in fewer than ``min_views`` frames is left out (``unmapped``); when some views of an
    id place it far from the others and agree among themselves, only one group is used; (2) a
    coarse adjustment with the rolling-shutter model and the starting frame's pose as the
    gauge (:func:`_coarse_adjustment`); (3) the rolling-shutter bundle adjustment of every frame's
    pose and velocities and every marker's 6-DoF pose (module docstring: the estimator's
    model, paper eq. 4) with SciPy ``least_squares`` (sparse Jacobian, robust loss),
    optionally one line delay, consecutive frames tied by the motion model, one marker held
    fixed (the gauge: the anchor, or the most detected marker); detections whose RMS error
    exceeds ``reject_px`` are rejected (counted) and the map adjusted again without robust
    loss (:func:`_adjust_and_reject`); (4) the covariance ``(J^T J)^-1`` of the markers, the
    reprojection rows scaled by the estimated noise and weighted for the errors that repeat
    from one viewpoint (:func:`_shared_error_weights`); (5) the map moved to its output
    frame (one anchor at its pose, or a best fit to surveyed markers) with every marker's
    covariance propagated through the frame's own uncertainty (:func:`_propagate`), and
    that uncertainty reported; (6) an id whose two groups of views still place it more than
    max(0.5 m, 3 sides) apart is left out of the map and reported with both places
    (``inconsistent``, never averaged).

    Args:
        frames: the video's detections in capture order (:class:`FrameDetections`; pixel
            corners (4, 2) per id, ArUco order); several videos: :func:`concatenate_videos`.
        camera: intrinsics, distortion and RS timing (``line_delay``: the value used, or the
            starting value with ``calibrate_readout``).
        options: :class:`MappingOptions`.
        progress: show the stages and adjustment rounds (tqdm, on stderr).
        videos: (len(frames),) index of the video of each frame: a video whose frames the
            map cannot place (no marker in common, or its markers disagree) is refused.
    Returns:
        :class:`MarkerMapResult` in the output frame (``options.anchor`` at
        ``options.anchor_pose``, ``options.anchors`` fitted, or the most detected marker).
    Raises:
        ValueError: no detections in any frame (wrong dictionary?), an anchor not detected in
            any frame, corners that are not (4, 2) and finite, an anchor that cannot be placed
            (seen in fewer than ``min_views`` frames with a pose, or at places that disagree),
            surveyed anchors that disagree with the video (RMS corner residual over
            ``max_anchor_residual``), a video of another place, or ``calibrate_readout``
            without a motion tie.
    """
    from tqdm import tqdm

    t_start = time.perf_counter()
    timings: dict = {}
    obs_px, obs_n, stamps = _read_detections(frames, camera)
    gauge, _ = _choose_gauge(obs_px, options)
    if options.anchors:
        unknown = [m for m in options.anchors if np.asarray(options.anchors[m]).size != 12]
        if unknown:
            raise ValueError(f"surveyed anchors {unknown} need (4, 3) corners")
    bar = tqdm(total=5, desc="marker map", disable=not progress, leave=False)
    bar.set_postfix_str("initialization")
    init = _initialize(obs_px, obs_n, stamps, options, gauge, camera, videos)
    timings["initialization"] = time.perf_counter() - t_start
    bar.update(1)
    bar.set_postfix_str("coarse adjustment")
    t0 = time.perf_counter()
    _coarse_adjustment(init, obs_px, camera, options, gauge, _gauge_pose(options))
    timings["coarse adjustment"] = time.perf_counter() - t0
    bar.update(1)
    prob, sol, inconsistent, exclude = _adjust_and_reject(
        init, obs_px, obs_n, camera, options, gauge, timings, bar
    )
    _check_anchors_placed(gauge, inconsistent, options, init)
    all_ids = sorted(init.markers)
    # rejected: by the adjustment, and detections of mapped markers that disagreed with their
    # frame during the initialization
    num_rejected = int((~prob.keep).sum()) + sum(
        m in all_ids and m not in inconsistent for _, m in exclude
    )
    poses = _marker_poses(prob, sol.x, gauge)
    sides = {m: options.side(m) for m in poses}

    bar.set_postfix_str("covariance")
    t0 = time.perf_counter()
    framed = _frame_and_covariance(prob, sol, poses, options, gauge, sides, inconsistent)
    timings["covariance"] = time.perf_counter() - t0
    bar.update(1)
    bar.close()
    return _assemble(
        prob,
        sol,
        init,
        framed,
        sides,
        options,
        inconsistent,
        num_rejected,
        len(frames),
        timings,
        t_start,
    )


def _initialize(
    obs_px: dict,
    obs_n: dict,
    stamps: dict,
    options: MappingOptions,
    gauge: int,
    camera: CameraModel,
    videos: Sequence[int] | None,
) -> _Init:
    """Stage (1) of :func:`map_markers`: the initialization in capture order (:class:`_Init`),
    with at least two frames placed and every video placed (:func:`_check_videos`).

    Raises:
        ValueError: as :meth:`_Init.run`, fewer than 2 frames with a pose, or a video of
            another place.
    """
    init = _Init(obs_n, stamps, options, gauge, camera, obs_px)
    try:
        init.run()
    except ValueError:
        if videos is not None:  # (a video of another place: say so)
            _check_videos(videos, init, obs_px)
        raise
    if len(init.frames) < 2:
        raise ValueError(f"anchor marker {gauge}: fewer than 2 frames with a pose")
    if videos is not None:
        _check_videos(videos, init, obs_px)
    return init


def _marker_poses(prob: _Problem, x: np.ndarray, gauge: int) -> dict:
    """id -> ``(R (3, 3), p (3,))`` of the gauge marker and every adjusted marker at ``x``."""
    _, _, _, _, Rm, pm, _ = prob.unpack(x)
    poses = {gauge: (prob.Ra, prob.pa)}
    poses.update({m: (Rm[i], pm[i]) for i, m in enumerate(prob.markers)})
    return poses


def _gauge_pose(options: MappingOptions) -> tuple[np.ndarray, np.ndarray]:
    """The adjustment's frame, ``(R (3, 3), p (3,))``: the anchor at its pose when one is given
    (the motion tie of the camera centres is not invariant to where the world's origin lies:
    the output frame's origin is the one the tie sees), else the gauge marker's own frame."""
    if options.anchor is not None and options.anchor_pose is not None:
        Ra, pa = options.anchor_pose
        return np.asarray(Ra, float).reshape(3, 3), np.asarray(pa, float).reshape(3)
    return np.eye(3), np.zeros(3)


def _check_anchors_placed(gauge: int, inconsistent: dict, options: MappingOptions, init: _Init):
    """Raise ValueError when the gauge marker or a surveyed anchor has no single place."""
    if gauge in inconsistent:
        raise ValueError(
            f"anchor marker {gauge} cannot be placed: detected at places that disagree "
            f"({inconsistent[gauge][0].round(2)} and {inconsistent[gauge][1].round(2)})"
        )
    bad = [m for m in (options.anchors or {}) if m in inconsistent or m not in init.markers]
    if bad:
        raise ValueError(f"surveyed anchor(s) {bad} cannot be placed (seen too little, or twice)")


def _frame_and_covariance(prob, sol, poses, options, gauge, sides, inconsistent) -> dict:
    """Stage (4)-(5) of :func:`map_markers`: the covariance of the markers in the gauge
    (viewpoint clusters, shared-error weights), the output frame (the best-observed marker
    chosen when no anchor is given; surveyed anchors checked against their residual) and the
    markers' poses and covariances in it. Returns a dict of ``poses`` / ``cov`` (id -> output
    pose, (6, 6)), ``frame`` (:class:`OutputFrame`) and ``transform`` ``(R, t)`` (adjustment
    frame -> output frame). Raises ValueError for surveyed anchors that disagree."""
    Rf, Cf, *_ = prob.unpack(sol.x)
    labels = _view_clusters(prob, Rf, Cf, poses, options.view_cluster_rad)
    weights, rho = (
        _shared_error_weights(prob, sol.x, labels)
        if options.shared_errors
        else (np.ones(len(prob.det)), 0.0)
    )
    cov_gauge, sigma = _gauge_covariance(prob, sol, weights)
    # the gauge marker joins as a variable of its own, uncorrelated with the others: its
    # only uncertainty in the gauge is the ambiguity of its tilt
    ids = [*prob.markers, gauge]
    n = 6 * len(prob.markers)
    cov = np.zeros((n + 6, n + 6))
    cov[:n, :n] = cov_gauge
    if options.planar_ambiguity:
        for m, (d, var) in _mirror_covariance(prob, sol.x, weights, sigma, poses).items():
            i = 6 * ids.index(m)
            lin = float(d @ cov[i : i + 3, i : i + 3] @ d)
            if var > lin:
                cov[i : i + 3, i : i + 3] += (var - lin) * np.outer(d, d)
    kind = "surveyed" if options.anchors else "anchor" if options.anchor is not None else None
    if kind is None:
        kind = "best-observed"
        options = replace(options, anchor=_best_observed(poses, ids, cov))
    out_cov, frame_cov = _propagate(poses, ids, cov, options, gauge, sides)
    Ro, to, residual = _output_transform(poses, options, gauge, sides)
    if options.anchors:
        # what the map states for the surveyed markers' positions (rms per axis)
        stated = float(
            np.sqrt(np.mean([np.trace(out_cov[m][3:, 3:]) / 3 for m in options.anchors]))
        )
        bound = max(options.max_anchor_residual, 3 * stated)
        if residual > bound:
            raise ValueError(
                f"the surveyed anchors {sorted(options.anchors)} disagree with the video: RMS "
                f"corner residual {residual * 1000:.0f} mm after the best fit, above "
                f"{bound * 1000:.0f} mm (3x the {stated * 1000:.0f} mm the map states for them, "
                f"at least {options.max_anchor_residual * 1000:.0f} mm): a wrong pose or id, a "
                "moved marker, or a wrong marker size"
            )
    out_poses, covs = {}, {}
    for m in poses:
        if m in inconsistent:
            continue
        R, p = poses[m]
        out_poses[m] = (Ro @ R, Ro @ p + to)
        c = 0.5 * (out_cov[m] + out_cov[m].T)
        if m == options.anchor and kind == "anchor":
            c = np.zeros((6, 6))  # (the anchor's pose in its own frame is exact)
        covs[m] = c
    frame_std = np.sqrt(np.clip(np.diag(frame_cov), 0.0, None))
    frame = OutputFrame(
        kind,
        sorted(options.anchors) if options.anchors else [int(options.anchor)],
        float(np.degrees(frame_std[:3].max())),
        float(1e3 * frame_std[3:].max()),
        frame_cov,
        1e3 * residual,
        rho,
    )
    shape_std = _corner_shape_std(poses, ids, cov, sides, out_poses)
    return dict(
        poses=out_poses,
        cov=covs,
        frame=frame,
        transform=(Ro, to),
        gauge_poses=poses,
        shape_std=shape_std,
    )


def _assemble(
    prob, sol, init, framed, sides, options, inconsistent, num_rejected, n_frames, timings, t0
) -> MarkerMapResult:
    """Stage (6) of :func:`map_markers`: the :class:`MarkerMapResult` in the output frame
    (markers, their covariance and std, frames' poses and velocities, counts, coverage)."""
    Rf, Cf, W, T, _, _, ld = prob.unpack(sol.x)
    Ro, to = framed["transform"]
    used: dict = {}
    for (_, m), kept in zip(prob.det, prob.keep, strict=True):
        used[m] = used.get(m, 0) + int(kept)
    poses, covs = framed["poses"], framed["cov"]
    corners = {m: marker_corners_local(sides[m]) @ R.T + p for m, (R, p) in poses.items()}
    mstd = {m: np.sqrt(np.clip(np.diag(c), 0.0, None)) for m, c in covs.items()}
    # the frames in the output frame: world -> camera (R, C) becomes (R Ro^T, C - R Ro^T to)
    Rf_out = Rf @ Ro.T
    Cf_out = Cf - np.einsum("nij,j->ni", Rf_out, to)
    # camera's own velocities (docs/architecture.md): omega = -w / s, v = (w x C - t) / s with
    # w = s W, t = s T (C the world -> camera translation of the adjustment's frame: the
    # camera's velocities in its own frame do not depend on the world frame)
    e = prob.corner_residuals(sol.x).reshape(-1, 8)[prob.keep]
    timings["total"] = time.perf_counter() - t0
    return MarkerMapResult(
        anchor=framed["frame"].anchors[0],
        corners=corners,
        marker_poses=poses,
        marker_covariance=covs,
        marker_std=mstd,
        observations={m: used.get(m, 0) for m in poses},
        frame_ids=np.array(list(prob.frames)),
        orientation=np.swapaxes(Rf_out, 1, 2),
        position=-np.einsum("nji,nj->ni", Rf_out, Cf_out),
        angular_velocity=-W,
        linear_velocity=np.cross(W, Cf) - T,
        line_delay=float(ld),
        rmse_px=float(np.sqrt(np.mean(e**2))) if e.size else float("nan"),
        num_rejected=num_rejected,
        num_frames_skipped=n_frames - len(prob.frames),
        unmapped=init.unmapped,
        inconsistent={m: [Ro @ q + to for q in qs] for m, qs in inconsistent.items()},
        timings=timings,
        global_shutter=options.global_shutter,
        corner_offset_px=prob.corner_offset(sol.x),
        frame=framed["frame"],
        coverage=_coverage(prob, Rf, Cf, framed["gauge_poses"], mstd, sides, options.coverage_std),
        marker_shape_std=framed["shape_std"],
    )


def _check_videos(videos: Sequence[int], init: _Init, obs_px: dict) -> None:
    """Refuse a video of which the map places fewer than half the frames with markers: its
    markers are not the others' (another place), or disagree with them (the reprojection
    RMS of its frames against the map's markers is named)."""
    for v in sorted(set(videos)):
        ks = [k for k in obs_px if videos[k] == v]
        posed = [k for k in ks if k in init.frames]
        if len(posed) >= 0.5 * len(ks):
            continue
        others = {m for k in obs_px if videos[k] != v for m in obs_px[k]}
        mine = {m for k in ks for m in obs_px[k]}
        common = sorted(mine & others)
        errs = []
        for k in posed:
            for m in obs_px[k]:
                if m in init.markers:
                    errs.append(init._rms(k, m, *init.frames[k]))
        rms = f"{np.sqrt(np.mean(np.square(errs))):.1f} px" if errs else "no frame placed"
        raise ValueError(
            f"video {v + 1}: the map places {len(posed)} of its {len(ks)} frames with markers "
            f"(markers in common with the other videos: {common or 'none'}; reprojection "
            f"RMS {rms}): another place, or markers moved between the videos"
        )
