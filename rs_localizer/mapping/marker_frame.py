"""Marker maps, stage (5): the output frame (one anchor at its pose, a best fit to surveyed
markers, the best-observed marker, or a gravity-aligned frame: z up from the accelerometer, the
walls or a floor marker, REP 105), the markers' poses and covariances moved into it with the
frame's own uncertainty propagated, and that uncertainty."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..geometry import matrix_to_rotvec, moved
from .marker_covariance import corner_shape_std, covariance_in_gauge
from .marker_model import MappingOptions, OutputFrame, fit_rigid, marker_corners_local
from .marker_problem import MarkerProblem


def _pose_vector_map(poses: dict, ids: list, x: np.ndarray) -> dict:
    """Marker poses with the perturbation ``x`` (6 per id: rotation vector, world axes left;
    centre) applied (:func:`~rs_localizer.geometry.moved`)."""
    R, p = moved(*(np.array([poses[m][i] for m in ids]) for i in (0, 1)), x.reshape(-1, 6))
    return {**poses, **dict(zip(ids, zip(R, p, strict=True), strict=True))}


#: a marker whose normal lies within this angle of horizontal hangs on a wall (rad); within
#: this angle of vertical it lies on the floor or the ceiling
WALL_TOLERANCE = np.radians(5.0)
#: two walls are not parallel when their normals differ by more than this (rad)
MIN_WALL_ANGLE = np.radians(30.0)
#: a marker is taken for a floor marker when its normal lies within this angle of the
#: cameras' mean image-up direction (rad; the camera held about upright)
FLOOR_TOLERANCE = np.radians(20.0)
#: an up proposal agrees with the cameras when the median angle between it and the cameras'
#: image-up directions (optical -y) over the video's frames is below this (rad)
UPRIGHT_ANGLE = np.radians(40.0)
#: another up proposal (more than ``DISTINCT_UP`` away, with at least ``RIVAL_SHARE`` as many
#: markers of its own as the winner: markers both fit count for neither) makes up ambiguous
#: unless its median angle to the cameras' image-up is larger by ``UPRIGHT_MARGIN`` (rad)
UPRIGHT_MARGIN = np.radians(25.0)
DISTINCT_UP = np.radians(20.0)
RIVAL_SHARE = 0.75


@dataclass(frozen=True)
class UpDirection:
    """Where the gravity-aligned frame's up comes from.

    Attributes:
        source: ``imu`` (the accelerometer's mean specific force, per frame in the camera
            frame, rotated by each frame's pose), ``walls`` (the direction most orthogonal to
            the normals of markers on vertical walls and most parallel to those of markers on
            the floor or the ceiling, checked against the cameras' image-up) or ``floor``
            (the mean normal of markers lying on the floor).
        up: (3,) unit up in the adjustment's frame at the solution.
        markers: the markers that fix it (walls, floor), empty for ``imu``.
        note: what was used, for the user (e.g. ``18 markers on 4 walls``).
        level: for ``walls``, the markers on the floor or the ceiling that also fix it.
    """

    source: str
    up: np.ndarray
    markers: tuple = ()
    note: str = ""
    level: tuple = ()

    def at(self, poses: dict) -> np.ndarray:
        """Up (3,) with the markers at ``poses`` (id -> ``(R, p)``; the same markers, sign
        kept): the smallest-eigenvalue direction of the walls' normals' scatter less the
        floor and ceiling markers' (:func:`_refine_up`), the mean of the floor markers'
        normals, or the fixed accelerometer's up."""
        if self.source == "imu":
            return self.up
        n = np.array([poses[m][0][:, 2] for m in self.markers])
        if self.source == "walls":
            level = np.array([poses[m][0][:, 2] for m in self.level]).reshape(-1, 3)
            u = _refine_up(n, level)
        else:
            u = n.mean(0)
        u = u / np.linalg.norm(u)
        return u if u @ self.up >= 0 else -u


def _refine_up(walls: np.ndarray, level: np.ndarray) -> np.ndarray:
    """The unit direction most orthogonal to the wall markers' normals ``walls`` (N, 3) and
    most parallel to the floor and ceiling markers' ``level`` (L, 3): the smallest
    eigenvector of ``sum n n^T`` (walls) ``- sum n n^T`` (level), which minimizes the summed
    squared sines of their tilts (least squares, sign arbitrary)."""
    M = walls.T @ walls - level.T @ level
    return np.linalg.eigh(M)[1][:, 0]


def _upright_angle(u: np.ndarray, image_ups: np.ndarray) -> float:
    """Median angle (rad) between the axis ``u`` (3,) (either sign) and the cameras'
    image-up directions ``image_ups`` (K, 3): small for up when the camera is held about
    upright, about 90 deg for a horizontal axis."""
    return float(np.median(np.arccos(np.clip(np.abs(image_ups @ u), 0.0, 1.0))))


def _fixes_up(walls: np.ndarray, level: np.ndarray) -> bool:
    """Whether these wall and level normals fix up: two walls that are not parallel (the
    normals spread along two horizontal axes), or a wall and a floor or ceiling marker."""
    if len(walls) + len(level) < 3 or len(walls) == 0:
        return False
    if len(level):
        return True
    w = np.linalg.eigvalsh(walls.T @ walls)
    return bool(w[1] >= 0.5 * np.sin(MIN_WALL_ANGLE) ** 2 * len(walls) / 2)


def _support(n: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Markers on walls (normal within ``WALL_TOLERANCE`` of horizontal) and on the floor or
    the ceiling (within it of vertical) for up ``u``: two (N,) masks."""
    c = np.abs(n @ u)
    return c < np.sin(WALL_TOLERANCE), c > np.cos(WALL_TOLERANCE)


def _wall_up(poses: dict, image_ups: np.ndarray) -> tuple[UpDirection | None, str]:
    """Up from the markers on vertical walls, the floor and the ceiling.

    A room's markers fit more than one up: in a box room any of its three axes leaves the
    other walls vertical and the remaining two level. The proposals are every marker's normal
    (up if it lies on the floor) and the cross product of every pair of normals at least
    ``MIN_WALL_ANGLE`` apart (up if both hang on walls); each proposal's markers are those
    within ``WALL_TOLERANCE`` of a wall or of the floor or ceiling (tilted markers do not
    agree). What tells the room's axes apart is how the camera was held: a proposal is kept
    only when the cameras' image-up directions (optical -y, ``image_ups`` (K, 3)) lie within
    ``UPRIGHT_ANGLE`` of it (median over frames). The kept proposal with the most markers
    wins, refined by :func:`_refine_up`; when another proposal more than ``DISTINCT_UP`` away
    with at least ``RIVAL_SHARE`` as many markers of its own (markers both fit count for
    neither) is within ``UPRIGHT_MARGIN`` of it as seen from the
    cameras, up is ambiguous and None is returned with the reason.

    Returns ``(up or None, why none)``."""
    ids = sorted(poses)
    if len(ids) < 3:
        return None, "no two non-parallel walls of markers"
    n = np.array([poses[m][0][:, 2] for m in ids])
    props = [n]
    for i in range(len(ids) - 1):
        c = np.cross(n[i], n[i + 1 :])
        norm = np.linalg.norm(c, axis=1)
        keep = norm > np.sin(MIN_WALL_ANGLE)
        props.append(c[keep] / norm[keep, None])
    props = np.concatenate(props)
    cands = []  # (markers, -upright angle, up, wall mask, level mask)
    for u in props:
        walls, level = _support(n, u)
        if not _fixes_up(n[walls], n[level]):
            continue
        for _ in range(3):  # refined on its own markers
            u = _refine_up(n[walls], n[level])
            walls, level = _support(n, u)
            if not _fixes_up(n[walls], n[level]):
                break
        else:
            a = _upright_angle(u, image_ups)
            cands.append((int(walls.sum() + level.sum()), a, u, walls, level))
    if not cands:
        return None, "no two non-parallel walls of markers"
    upright = [c for c in cands if c[1] < UPRIGHT_ANGLE]
    if not upright:
        best = max(cands, key=lambda c: c[0])
        return None, (
            f"up unknown: the walls' up ({best[0]} markers) lies "
            f"{np.degrees(best[1]):.0f} deg from the cameras' image-up (median), no proposal "
            f"within {np.degrees(UPRIGHT_ANGLE):.0f} deg: was the camera held upright?"
        )
    best = max(upright, key=lambda c: (c[0], -c[1]))
    count, angle, u, walls, level = best
    mine = walls | level
    for c in cands:
        apart = np.arccos(min(1.0, abs(float(c[2] @ u))))
        theirs = c[3] | c[4]
        # (markers both proposals fit, e.g. walls parallel to the axis between them, count
        # for neither)
        own, rival = int((mine & ~theirs).sum()), int((theirs & ~mine).sum())
        if (
            apart > DISTINCT_UP
            and c[0] >= 3
            and rival >= RIVAL_SHARE * own
            and c[1] < angle + UPRIGHT_MARGIN
        ):
            return None, (
                f"up ambiguous: {count} markers fit one up and {c[0]} another "
                f"{np.degrees(apart):.0f} deg from it ({own} and {rival} of them not both), "
                "and the cameras' image-up does not tell them apart "
                f"({np.degrees(angle):.0f} and {np.degrees(c[1]):.0f} deg from it, median)"
            )
    image_up = image_ups.mean(0)
    u = u if u @ image_up >= 0 else -u
    nw = n[walls]
    n_walls = _count_walls(nw, u)
    markers = tuple(m for m, k in zip(ids, walls, strict=True) if k)
    lv = [(m, float(v @ u)) for m, v, k in zip(ids, n, level, strict=True) if k]
    floor = [m for m, c in lv if c > 0]
    ceiling = [m for m, c in lv if c < 0]
    note = (
        f"{len(markers)} markers on {n_walls} vertical walls (within "
        f"{np.degrees(WALL_TOLERANCE):.0f} deg of vertical)"
    )
    if floor:
        note += f", {len(floor)} on the floor"
    if ceiling:
        note += f", {len(ceiling)} on the ceiling"
    note += (
        f"; the cameras' image-up {np.degrees(angle):.0f} deg from it (median), "
        "checked against the room's other axes"
    )
    return UpDirection("walls", u, markers, note, tuple(m for m, _ in lv)), ""


def _count_walls(n: np.ndarray, u: np.ndarray) -> int:
    """Number of wall directions among horizontal normals ``n`` (N, 3) (groups 30 deg apart)."""
    x = np.cross(u, [1.0, 0, 0]) if abs(u[0]) < 0.9 else np.cross(u, [0, 1.0, 0])
    x /= np.linalg.norm(x)
    y = np.cross(u, x)
    a = np.sort(np.arctan2(n @ y, n @ x))
    gaps = np.diff(np.r_[a, a[0] + 2 * np.pi])
    return max(1, int(np.sum(gaps > MIN_WALL_ANGLE)))  # (one gap per wall on a full circle)


def _floor_up(poses: dict, image_up: np.ndarray, flagged: tuple) -> UpDirection | None:
    """Up from markers on the floor: the ones ``flagged`` (placed), else those whose normal
    lies within ``FLOOR_TOLERANCE`` of the cameras' mean image-up direction; the markers
    within ``WALL_TOLERANCE`` of their mean normal (so a tilted one does not pull it)."""
    ids = [m for m in flagged if m in poses]
    how = "given as floor markers"
    if not ids:
        ids = [m for m in sorted(poses) if poses[m][0][:, 2] @ image_up > np.cos(FLOOR_TOLERANCE)]
        how = "facing up (the cameras' mean image-up within 20 deg)"
    if not ids:
        return None
    n = np.array([poses[m][0][:, 2] for m in ids])
    u = np.median(n, axis=0)
    u /= np.linalg.norm(u)
    keep = n @ u > np.cos(WALL_TOLERANCE)
    if flagged and not keep.all():
        keep[:] = True  # (the user's floor markers are all used)
    markers = tuple(m for m, k in zip(ids, keep, strict=True) if k)
    u = n[keep].mean(0)
    u /= np.linalg.norm(u)
    return UpDirection("floor", u, markers, f"floor marker(s) {list(markers)}, {how}")


def find_up(
    poses: dict,
    cam_to_world: dict,
    options: MappingOptions,
    up_in_camera: dict | None = None,
) -> tuple[UpDirection | None, str]:
    """The up direction of the gravity-aligned frame, from what the video offers, in this
    order (``options.frame``: ``auto`` the first available, or one source by name): the
    accelerometer (``up_in_camera``: frame index -> (3,) unit up in the camera's optical
    frame, the mean specific force while still-ish rotated by the camera-IMU mounting; each
    rotated into the map by the frame's pose ``cam_to_world`` (frame index -> (3, 3)) and
    averaged), markers on vertical walls (:func:`_wall_up`), floor markers
    (:func:`_floor_up`, ``options.floor_markers`` or detected). ``poses``: id -> ``(R, p)``
    in the adjustment's frame. Returns ``(up or None, why none: the sources tried)``."""
    image_ups = -np.array([R[:, 1] for R in cam_to_world.values()]).reshape(-1, 3)
    image_up = image_ups.mean(axis=0)
    image_up /= max(np.linalg.norm(image_up), 1e-12)
    mode = options.frame
    tried = []
    if mode in ("auto", "imu"):
        used = [k for k in (up_in_camera or {}) if k in cam_to_world]
        if used:
            u = np.sum([cam_to_world[k] @ np.asarray(up_in_camera[k], float) for k in used], 0)
            u /= np.linalg.norm(u)
            return UpDirection("imu", u, (), f"the accelerometer at {len(used)} frames"), ""
        tried.append("no accelerometer")
    if mode in ("auto", "walls"):
        up, why = _wall_up(poses, image_ups)
        if up is not None:
            return up, ""
        tried.append(why)
        if why.startswith("up "):
            return None, ", ".join(tried)  # (not a floor marker's either: said plainly)
    if mode in ("auto", "floor"):
        up = _floor_up(poses, image_up, tuple(options.floor_markers))
        if up is not None:
            return up, ""
        tried.append("no floor marker")
    return None, ", ".join(tried)


def gravity_transform(poses: dict, anchor: int, up: UpDirection) -> tuple:
    """Rigid transform ``(R, t)`` adjustment frame -> the gravity-aligned frame: z up
    (``up.at(poses)``), origin at the ``anchor``'s centre, x the horizontal part of its face
    normal (out of its wall, into the room; for a marker lying flat, its own y axis, the
    top edge's direction), y = z x x (a robot standing at the anchor facing the room: x
    ahead, y left, z up)."""
    z = up.at(poses)
    Ra, pa = poses[anchor]
    for axis in (Ra[:, 2], Ra[:, 1]):
        h = axis - (axis @ z) * z
        if np.linalg.norm(h) > np.sin(np.radians(30.0)):
            break
    x = h / np.linalg.norm(h)
    y = np.cross(z, x)
    R = np.array([x, y, z])
    return R, -R @ pa


def _output_transform(
    poses: dict, options: MappingOptions, gauge: int, sides: dict, up: UpDirection | None = None
) -> tuple:
    """Rigid transform ``(R, t)`` from the adjustment's frame to the output frame, and the RMS
    corner residual (m) of the surveyed anchors (0 for one anchor). ``up``: the
    gravity-aligned frame's (:func:`gravity_transform` at the anchor)."""
    if up is not None:
        anchor = gauge if options.anchor is None else int(options.anchor)
        R, t = gravity_transform(poses, anchor, up)
        return R, t, 0.0
    if options.anchors:
        ids = sorted(options.anchors)
        src = np.concatenate(
            [marker_corners_local(sides[m]) @ poses[m][0].T + poses[m][1] for m in ids]
        )
        dst = np.concatenate([np.asarray(options.anchors[m], float).reshape(4, 3) for m in ids])
        R, t = fit_rigid(src, dst)
        res = np.linalg.norm(src @ R.T + t - dst, axis=1)
        return R, t, float(np.sqrt(np.mean(res**2)))
    anchor = gauge if options.anchor is None else int(options.anchor)
    Rt, pt = options.anchor_pose if options.anchor_pose is not None else (np.eye(3), np.zeros(3))
    Ra, pa = poses[anchor]
    R = np.asarray(Rt, float) @ Ra.T
    return R, np.asarray(pt, float) - R @ pa, 0.0


def _propagate(poses: dict, ids: list, cov: np.ndarray, options, gauge, sides, up=None) -> tuple:
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
        R, t, _ = _output_transform(P, options, gauge, sides, up)
        y = []
        for m in all_out:
            Rm, pm = P[m]
            y.append(matrix_to_rotvec(R @ Rm @ R0_out[m].T))
            y.append(R @ pm + t)
        # the output frame against the best fit of all centres
        C = np.array([P[m][1] for m in cent_ids])
        Rb, tb = fit_rigid(C, np.array([poses[m][1] for m in cent_ids]))
        # frame -> adjustment frame is (R^T, -R^T t); map it by the best fit
        Rf = Rb @ R.T
        y.append(matrix_to_rotvec(Rf @ R0_frame.T))
        y.append(tb - Rb @ R.T @ t)
        return np.concatenate(y)

    R_, _, _ = _output_transform(poses, options, gauge, sides, up)
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
        Rb, tb = fit_rigid(C, cent)
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


def frame_and_covariance(
    prob: MarkerProblem,
    sol: Any,
    poses: dict,
    options: MappingOptions,
    gauge: int,
    sides: dict,
    inconsistent: dict,
    up_in_camera: dict | None = None,
) -> dict:
    """Stages (4)-(5) of :func:`~rs_localizer.mapping.marker_map.map_markers`: the
    covariance of the markers in the gauge
    (:func:`~rs_localizer.mapping.marker_covariance.covariance_in_gauge`), the output frame
    (the best-observed marker chosen when no anchor is given; surveyed anchors checked
    against their residual) and the markers' poses and covariances in it. ``sol``: SciPy's
    ``least_squares`` result of ``prob``; ``poses``: id -> ``(R (3, 3), p (3,))`` of the
    markers in the adjustment's frame; ``sides``: id -> side (m); ``inconsistent``: ids left
    out of the map. Returns a dict of ``poses`` / ``cov`` (id -> output pose, (6, 6)),
    ``frame`` (:class:`OutputFrame`), ``transform`` ``(R, t)`` (adjustment frame -> output
    frame), ``gauge_poses`` (``poses``), ``shape_std`` (id -> (4,),
    :func:`~rs_localizer.mapping.marker_covariance.corner_shape_std`) and ``line_delay_std``
    (s, NaN when not calibrated). Raises ValueError for
    surveyed anchors that disagree."""
    ids, cov, rho, ld_std = covariance_in_gauge(prob, sol, poses, options, gauge)
    kind = "surveyed" if options.anchors else "anchor" if options.anchor is not None else None
    up, note = None, ""
    if options.frame != "anchor" and not options.anchors and options.anchor_pose is None:
        Rf, *_ = prob.unpack(sol.x)
        cam_to_world = {k: Rf[i].T for i, k in enumerate(prob.frames)}
        live = {m: v for m, v in poses.items() if m not in inconsistent}
        up, why = find_up(live, cam_to_world, options, up_in_camera)
        if up is not None:
            kind = "gravity"
        else:
            note = (
                f"not gravity-aligned ({why}): z out of the anchor's face; give the IMU, "
                "markers on two walls or a floor marker"
            )
    if kind is None or (kind == "gravity" and options.anchor is None):
        best = _best_observed(poses, ids, cov)
        kind = kind or "best-observed"
        options = replace(options, anchor=best)
    out_cov, frame_cov = _propagate(poses, ids, cov, options, gauge, sides, up)
    Ro, to, residual = _output_transform(poses, options, gauge, sides, up)
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
        up_source="" if up is None else up.source,
        up_markers=[] if up is None else [int(m) for m in up.markers],
        note=note if up is None else f"z up from {up.note}",
    )
    shape_std = corner_shape_std(poses, ids, cov, sides, out_poses)
    return dict(
        poses=out_poses,
        cov=covs,
        frame=frame,
        transform=(Ro, to),
        gauge_poses=poses,
        shape_std=shape_std,
        line_delay_std=ld_std,
    )
