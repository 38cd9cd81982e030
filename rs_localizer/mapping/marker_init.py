"""Marker maps, stage (1): the detections read, the gauge marker chosen, and the incremental
initialization in capture order (frame poses by PnP, marker poses by the better of their two
planar IPPE solutions, refined from both tilts), moved onto the anchor; a video the map cannot
place is refused (model: :mod:`rs_localizer.mapping.marker_model`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import cv2
import numpy as np

from ..camera import CameraModel
from ..geometry import rotvec_to_matrix, skew
from .marker_model import FrameDetections, MappingOptions, fit_rigid, marker_corners_local
from .marker_problem import MarkerProblem


def ippe_candidates(obj: np.ndarray, x: np.ndarray) -> list:
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


def robust_gauss_newton(
    fun: Callable[..., tuple],
    x0: np.ndarray,
    f_scale: float,
    tol: float = 1e-8,
    max_iter: int = 100,
) -> tuple[np.ndarray, float]:
    """Minimize ``f_scale^2 * sum(sqrt(1 + (r / f_scale)^2) - 1)`` (SciPy's ``soft_l1`` loss
    and cost) over a small dense problem: Levenberg-Marquardt (damping ``lambda * max(diag H)``,
    updated as Nielsen's) on the normal equations of the robust loss (gradient weighted by the
    loss' first derivative, curvature by SciPy's scaling of a robust loss). ``fun(x,
    with_jac)`` returns the residuals (M,) and their Jacobian (M, N) (None without
    ``with_jac``). Stops when a step lowers the cost by at most ``tol`` of it or moves ``x`` by
    at most ``tol * (tol + |x|)`` (SciPy's ``ftol`` and ``xtol``), or when no step lowers it.
    Returns ``(x (N,), cost)``."""

    def cost_of(r):
        return float(f_scale**2 * np.sum(np.sqrt(1.0 + (r / f_scale) ** 2) - 1.0))

    x = np.asarray(x0, dtype=float)
    r, J = fun(x)
    cost = cost_of(r)
    lam, nu = 1e-3, 2.0
    for _ in range(max_iter):
        # soft_l1: first derivative (1 + z)^-0.5, SciPy's curvature scale (1 + z)^-1.5
        s1 = 1.0 / np.sqrt(1.0 + (r / f_scale) ** 2)
        H = J.T @ ((s1**3)[:, None] * J)
        g = J.T @ (s1 * r)
        damp = max(float(np.max(np.diag(H))), 1e-12) * np.eye(len(x))
        done = True
        for _ in range(20):
            try:
                step = -np.linalg.solve(H + lam * damp, g)
            except np.linalg.LinAlgError:
                lam, nu = lam * nu, 2 * nu
                continue
            r_new, _ = fun(x + step, False)
            c_new = cost_of(r_new)
            if c_new < cost:
                small = cost - c_new <= tol * cost or np.linalg.norm(step) <= tol * (
                    tol + np.linalg.norm(x)
                )
                gain = (cost - c_new) / max(-(g @ step + 0.5 * step @ H @ step), 1e-300)
                lam *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
                x, r, cost = x + step, r_new, c_new
                done = small
                break
            lam, nu = lam * nu, 2 * nu
        if done:
            break
        r, J = fun(x)
    return x, cost


def _rotation_and_left_jacobian(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``expm([q]x)`` (3, 3) and its left Jacobian (3, 3) at one rotation vector ``q``
    (3,) (rad) (:func:`~rs_localizer.geometry.rotvec_to_matrix`,
    :func:`~rs_localizer.mapping.marker_problem.left_jacobian`; one vector, no broadcasting)."""
    t2 = float(q @ q)
    K = np.array([[0.0, -q[2], q[1]], [q[2], 0.0, -q[0]], [-q[1], q[0], 0.0]])
    K2 = K @ K
    if t2 < 1e-12:
        a, b, c = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0
    else:
        t = np.sqrt(t2)
        st, ct = np.sin(t), np.cos(t)
        a, b, c = st / t, (1.0 - ct) / t2, (t - st) / (t2 * t)
    eye = np.eye(3)
    return eye + a * K + b * K2, eye + b * K + c * K2


def _projection_jacobian(p: np.ndarray, f: float) -> np.ndarray:
    """(..., 2, 3) derivative of ``f * p_xy / max(p_z, 1e-6)`` with respect to the camera
    point ``p`` (..., 3) (m; zero along z where the depth is clamped)."""
    z = p[..., 2]
    zc = np.maximum(z, 1e-6)
    J = np.zeros(p.shape[:-1] + (2, 3))
    J[..., 0, 0] = J[..., 1, 1] = f / zc
    live = z > 1e-6
    J[..., 0, 2] = np.where(live, -f * p[..., 0] / zc**2, 0.0)
    J[..., 1, 2] = np.where(live, -f * p[..., 1] / zc**2, 0.0)
    return J


def mirrored_tilt(R: np.ndarray, views: np.ndarray) -> np.ndarray | None:
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


class MarkerInit:
    """Incremental initialization in video order: frame poses (world -> camera), marker poses.

    The world is first the camera frame of the frame that sees the most markers (the seed).
    Frames are visited in capture order away from the seed; each gets its pose from the mapped
    markers it sees (OpenCV ``solvePnP``, Levenberg-Marquardt from the previous frame's pose, so
    a frame seeing a single marker keeps the continuous one of its two planar solutions); a
    marker first seen gets the better of its two IPPE poses in that view, and every marker is
    refined over all its views so far (:func:`robust_gauss_newton`) from its current tilt and from
    that tilt mirrored, the better fit kept: a single view fixes a small marker's centre well
    but its tilt poorly, and may pick the wrong one of the two. The whole is moved onto the
    anchor afterwards (:func:`regauge`).
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
            rvec=cv2.Rodrigues(np.asarray(R0, dtype=float))[0],
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
            for Rmc, tmc in ippe_candidates(
                marker_corners_local(self.opts.side(m)), self.obs[k][m]
            ):
                R = Rmc @ Rm.T
                out.append((R, tmc - R @ pm))
        return out

    def pose_frame(self, k: int, guess: tuple | None, cut: bool = False) -> bool:
        """Pose of frame ``k`` from the placed markers it sees, started from ``guess``.

        With several markers, the pose from all of them and from each alone compete (each
        alone only when some marker disagrees with the pose from all of them): the one
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
        ``subsets`` (default: all known markers, then each alone unless every marker agrees
        with the pose from all of them), or None."""
        every = subsets is None
        if every:
            subsets = [known] + ([[m] for m in known] if len(known) > 1 else [])
        best = None
        # (every known marker's reprojection RMS at once, as _rms)
        X = np.concatenate([self.world_corners(m) for m in known])
        x = np.concatenate([self.obs[k][m] for m in known])
        for sub, start in zip(subsets, starts, strict=False):
            pose = self._pnp(k, sub, start)
            if pose is None:
                continue
            R, C = pose
            rms = np.sqrt(np.mean(_gs_errors_px(R, C, X, x, self.f).reshape(-1, 4) ** 2, axis=1))
            agree = [m for m, r in zip(known, rms, strict=True) if r <= self.gate_px]
            away = np.linalg.norm(cv2.Rodrigues(R @ guess[0].T)[0]) + np.linalg.norm(
                R.T @ C - guess[0].T @ guess[1]
            )
            score = (len(agree), -away)
            if best is None or score > best[0]:
                best = (score, pose, agree)
            if every and len(agree) == len(known):  # (all agree: no marker alone does better)
                break
        return best

    def new_marker(self, k: int, mid: int) -> None:
        obj = marker_corners_local(self.opts.side(mid))
        R, C = self.frames[k]
        best = None
        for Rmc, tmc in ippe_candidates(obj, self.obs[k][mid]):
            Rm, pm = R.T @ Rmc, R.T @ (tmc - C)
            e = np.mean(_gs_errors_px(R, C, obj @ Rm.T + pm, self.obs[k][mid], self.f))
            if best is None or e < best[0]:
                best = (e, Rm, pm)
        self.markers[mid] = (best[1], best[2])

    def refine_marker(self, mid: int, frames: list) -> None:
        """Marker pose over its views ``frames`` (global-shutter reprojection, soft L1),
        started from its current pose and from its tilt mirrored through its mean viewing
        direction (the other planar solution, :func:`mirrored_tilt`); the better fit is kept.
        A small marker's first view fits both tilts about equally, so the one picked there
        may be the wrong one: its later views, from other directions, tell them apart."""
        obj = marker_corners_local(self.opts.side(mid))
        R0, p0 = self.markers[mid]
        Rs = np.array([self.frames[k][0] for k in frames])
        Cs = np.array([self.frames[k][1] for k in frames])
        xs = np.array([self.obs[k][mid] for k in frames])

        def fun(q, with_jac=True):
            E, Jl = _rotation_and_left_jacobian(q[:3])
            Y = obj @ (E @ R0).T
            p = np.einsum("kij,nj->kni", Rs, Y + q[3:]) + Cs[:, None, :]
            z = np.maximum(p[..., 2:3], 1e-6)
            r = ((p[..., :2] / z - xs) * self.f).ravel()
            if not with_jac:
                return r, None
            # (analytic: d expm([q]x) v / dq = -[expm([q]x) v]x J_l(q))
            dX = np.concatenate(
                [-skew(Y) @ Jl, np.broadcast_to(np.eye(3), (len(Y), 3, 3))],
                axis=2,
            )  # (n, 3, 6)
            J = _projection_jacobian(p, self.f) @ np.einsum("kij,njc->knic", Rs, dX)
            return r, J.reshape(-1, 6)

        starts = [np.zeros(3)]
        centres = -np.einsum("kji,kj->ki", Rs, Cs)  # (the cameras' centres in the world)
        delta = mirrored_tilt(R0, centres - p0)
        if delta is not None:
            starts.append(delta)
        best = None
        for r0 in starts:
            x, cost = robust_gauss_newton(fun, np.r_[r0, p0], f_scale=5.0)
            if best is None or cost < best[1]:
                best = (x, cost)
        self.markers[mid] = (rotvec_to_matrix(best[0][:3]) @ R0, best[0][3:])

    def adjust(self) -> None:
        """Global-shutter bundle adjustment of everything placed so far (gauge: the seed
        frame), a robust loss wide enough for the rolling-shutter shear."""
        frames = sorted(self.frames)
        markers = sorted(self.markers)
        opts = replace(self.opts, global_shutter=True, calibrate_readout=False, corner_offset=False)
        prob = MarkerProblem(
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
            ts = [t for _, t in ippe_candidates(obj, self.obs[k][mid])]
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


def regauge(frames: dict, markers: dict, anchor: int, anchor_pose: tuple) -> tuple:
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


def read_detections(frames: Sequence[FrameDetections], camera: CameraModel) -> tuple:
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


def choose_gauge(obs_px: dict, options: MappingOptions) -> tuple[int, list]:
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


def initialize(
    obs_px: dict,
    obs_n: dict,
    stamps: dict,
    options: MappingOptions,
    gauge: int,
    camera: CameraModel,
    videos: Sequence[int] | None,
    names: Sequence[str] | None = None,
) -> MarkerInit:
    """Stage (1) of :func:`~rs_localizer.mapping.marker_map.map_markers`: the initialization in
    capture order (:class:`MarkerInit`), with at least two frames placed and every video placed
    (:func:`_check_videos`).

    Raises:
        ValueError: as :meth:`MarkerInit.run`, fewer than 2 frames with a pose, or a video of
            another place.
    """
    init = MarkerInit(obs_n, stamps, options, gauge, camera, obs_px)
    try:
        init.run()
    except ValueError:
        if videos is not None:  # (a video of another place: say so)
            _check_videos(videos, init, obs_px, names)
        raise
    if len(init.frames) < 2:
        raise ValueError(f"anchor marker {gauge}: fewer than 2 frames with a pose")
    if videos is not None:
        _check_videos(videos, init, obs_px, names)
    return init


def _check_videos(
    videos: Sequence[int], init: MarkerInit, obs_px: dict, names: Sequence[str] | None
) -> None:
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
            f"{video_name(v, names)}: the map places {len(posed)} of its {len(ks)} frames with "
            f"markers (markers in common with the other videos: {common or 'none'}; reprojection "
            f"RMS {rms}): another place, or markers moved between the videos"
        )


def video_name(v: int, names: Sequence[str] | None) -> str:
    """The name of video ``v`` (0-based) in messages: ``names[v]``, else ``video {v + 1}``."""
    return str(names[v]) if names is not None and v < len(names) else f"video {v + 1}"


def screen_videos(
    obs_px: dict,
    obs_n: dict,
    stamps: dict,
    videos: Sequence[int],
    options: MappingOptions,
    camera: CameraModel,
    names: Sequence[str] | None = None,
) -> dict:
    """The videos of another place, found before the joint initialization: video index ->
    why it is refused (naming it, ``names`` or ``video N``).

    Each video is initialized alone (:class:`MarkerInit`, its most detected marker first):
    its markers' layout up to a rigid motion. Starting from the reference video (the one
    that detects ``options.anchor``, else the first surveyed anchor, else the one with the
    most frames with detections), a video whose layout shares at least two markers with the
    layout accepted so far is fitted onto it (corners, rigid best fit,
    :func:`_consensus_fit`: the best rigid fit of the markers in common that agree): it is
    refused when fewer than half of them (or fewer than two) lie within ``max(0.25 m, the
    side of its largest marker in common)`` RMS (another place with the same ids, or most
    markers moved), else its markers join the layout. A few markers off (placed poorly by
    one video's initialization, or one moved) do not refuse a video: the joint
    initialization's check of one id at two places deals with them. A video that
    shares no marker id with the accepted ones is refused too. A video sharing one marker, or
    whose own initialization fails, is left to the joint initialization.

    ``obs_px``, ``obs_n``, ``stamps``: :func:`read_detections`; ``videos``: the video index
    of every input frame. With fewer than two videos nothing is refused.
    """
    by_video: dict = {}
    for k in obs_px:
        by_video.setdefault(int(videos[k]), []).append(k)
    if len(by_video) < 2:
        return {}
    ids = {v: {m for k in ks for m in obs_px[k]} for v, ks in by_video.items()}
    wanted = (
        options.anchor if options.anchor is not None else next(iter(options.anchors or {}), None)
    )
    holders = [v for v in by_video if wanted is not None and int(wanted) in ids[v]]
    ref = holders[0] if holders else max(by_video, key=lambda v: (len(by_video[v]), -v))
    layouts = {
        v: _video_layout(by_video[v], obs_px, obs_n, stamps, options, camera) for v in by_video
    }
    placed = dict(layouts[ref] or {})
    known = set(ids[ref])
    pending = sorted(v for v in by_video if v != ref)
    refused: dict = {}
    changed = True
    while pending and changed:
        changed = False
        for v in list(pending):
            lay = layouts[v] or {}
            common = sorted(set(lay) & set(placed))
            if len(common) < 2:
                continue
            bound = max(0.25, max(options.side(m) for m in common))
            R, t, per_marker, agree = _consensus_fit(
                [lay[m] for m in common], [placed[m] for m in common], bound
            )
            pending.remove(v)
            changed = True
            if agree.sum() < max(2, 0.5 * len(common)):
                rms = float(np.sqrt(np.mean(per_marker**2)))
                apart = ", ".join(
                    f"{m}: {e:.2f} m" for m, e in zip(common, per_marker, strict=True)
                )
                refused[v] = (
                    f"{video_name(v, names)}: refused, another place or markers moved between "
                    f"the videos: its markers in common with the map {common} lie {rms:.2f} m "
                    f"RMS from the map's after the best rigid fit of those that agree; "
                    f"{int(agree.sum())} of {len(common)} within {bound:.2f} m, fewer than half "
                    f"(per marker {apart})"
                )
                continue
            for m, c in lay.items():
                placed.setdefault(m, c @ R.T + t)
            known |= ids[v]
    for v in pending:
        if not ids[v] & (known | {m for u in pending if u != v for m in ids[u]}):
            refused[v] = (
                f"{video_name(v, names)}: refused, no marker in common with the other videos "
                f"(its markers {sorted(ids[v])}): another place"
            )
    return refused


def _consensus_fit(src: list, dst: list, bound: float) -> tuple:
    """The rigid motion that best moves the markers' corners ``src`` onto ``dst`` (lists of
    (4, 3), m, the same markers) when some of them are off (a marker the initialization
    placed poorly, or moved): each marker's own corners propose a motion, the one that most
    markers agree with (RMS corner residual within ``bound`` m) is kept and refitted on those
    markers until they no longer change. Returns ``(R, t, per-marker RMS residual (M,),
    agreeing (M,) bool)``."""
    S, D = np.concatenate(src), np.concatenate(dst)
    n = len(src)

    def residuals(R, t):
        e = np.linalg.norm(S @ R.T + t - D, axis=1).reshape(n, 4)
        return np.sqrt(np.mean(e**2, axis=1))

    best = None
    for i in range(n):
        R, t = fit_rigid(src[i], dst[i])
        agree = residuals(R, t) <= bound
        if best is None or agree.sum() > best.sum():
            best = agree
    R, t = fit_rigid(S, D)
    agree = best if best.sum() >= 2 else np.ones(n, bool)
    for _ in range(10):
        keep = np.repeat(agree, 4)
        R, t = fit_rigid(S[keep], D[keep])
        e = residuals(R, t)
        new = e <= bound
        if new.sum() < 2 or (new == agree).all():
            break
        agree = new
    return R, t, e, e <= bound


def _video_layout(
    ks: list, obs_px: dict, obs_n: dict, stamps: dict, options: MappingOptions, camera: CameraModel
) -> dict | None:
    """id -> (4, 3) corners (m) of the markers one video places alone (its own frame: the
    initialization's, :class:`MarkerInit`, from its most detected marker), or None when its
    initialization fails."""
    count: dict = {}
    for k in ks:
        for m in obs_px[k]:
            count[m] = count.get(m, 0) + 1
    anchor = max(count, key=lambda m: (count[m], -m))
    sub = {k: obs_n[k] for k in ks}
    init = MarkerInit(
        sub, {k: stamps[k] for k in ks}, options, anchor, camera, {k: obs_px[k] for k in ks}
    )
    try:
        init.run()
    except ValueError:
        return None
    return {m: init.world_corners(m) for m in init.markers}
