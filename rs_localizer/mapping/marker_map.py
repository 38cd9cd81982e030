"""Marker maps from a rolling-shutter video: :func:`map_markers`, the stages in order
(initialization, :mod:`~rs_localizer.mapping.marker_init`; coarse and final bundle adjustment
with outlier rejection, :mod:`~rs_localizer.mapping.marker_problem`; covariance,
:mod:`~rs_localizer.mapping.marker_covariance`; output frame,
:mod:`~rs_localizer.mapping.marker_frame`) and the result assembled."""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from ..camera import CameraModel
from .marker_frame import frame_and_covariance
from .marker_init import (
    MarkerInit,
    choose_gauge,
    initialize,
    ippe_candidates,
    read_detections,
    regauge,
    screen_videos,
)
from .marker_model import (
    FrameDetections,
    MappingOptions,
    MarkerMapResult,
    frame_velocities,
    marker_corners_local,
)
from .marker_problem import MarkerProblem

__all__ = ["concatenate_videos", "map_markers"]


def concatenate_videos(videos: Sequence[Sequence[FrameDetections]], gap: float = 10.0) -> list:
    """Several videos of one place as one sequence for :func:`map_markers`: each video's
    stamps shifted to start ``gap`` seconds after the previous one ends (no motion tie across
    the cut). Returns the frames, the videos' in order (videos without frames skipped): pass
    :func:`map_markers` the index of each frame's video as ``videos``."""
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
    video_names: Sequence[str] | None = None,
    up_in_camera: dict | None = None,
) -> MarkerMapResult:
    """Build a marker map from a video's detections with rolling-shutter bundle adjustment.

    Stages: (1) initialization in capture order from the frame that sees the most markers
    (:class:`~rs_localizer.mapping.marker_init.MarkerInit`): each frame's pose by OpenCV
    ``solvePnP`` (Levenberg-Marquardt from the previous frame's pose, so a frame seeing a single
    marker keeps the continuous one of the two planar solutions), a new marker by the better of
    its two ``SOLVEPNP_IPPE_SQUARE`` poses, refined over all its views so far from both tilts;
    every 25 frames and at the end a global-shutter adjustment of everything placed (SciPy
    ``least_squares``, soft L1); a marker seen in fewer than ``min_views`` frames is left out
    (``unmapped``); when some views of an id place it far from the others and agree among
    themselves, only one group is used; (2) a coarse adjustment with the rolling-shutter model
    and the starting frame's pose as the gauge (:func:`_coarse_adjustment`); (3) the
    rolling-shutter bundle adjustment of every frame's pose and velocities and every marker's
    6-DoF pose (:mod:`~rs_localizer.mapping.marker_model`: the estimator's model, paper eq. 4)
    with SciPy ``least_squares`` (sparse Jacobian, robust loss), optionally one line delay,
    consecutive frames tied by the motion model (on the camera centres: independent of the
    world frame), one marker held fixed (the gauge: the anchor, at its pose when given, else the
    most detected surveyed marker, else the most detected marker, in its own frame; one seen
    at two places is replaced by the most detected other), the output frame applied afterwards
    (the cost does not depend on the world frame: the map changes by a rigid motion only);
    detections whose RMS error exceeds ``reject_px`` are rejected (counted) and the map adjusted
    again without robust loss, to convergence (Levenberg-Marquardt with exact sparse solves,
    :meth:`~rs_localizer.mapping.marker_problem.MarkerProblem.polish`;
    :func:`_adjust_and_reject`); (4) the covariance ``(J^T J)^-1`` of the markers, the
    reprojection rows scaled by the estimated noise and weighted for the errors that repeat
    from one viewpoint (:func:`~rs_localizer.mapping.marker_covariance.covariance_in_gauge`);
    (5) the map moved to its output frame (one anchor at its pose, a best fit to surveyed
    markers, gravity-aligned) with every marker's covariance propagated through the frame's
    own uncertainty (:func:`~rs_localizer.mapping.marker_frame.frame_and_covariance`), and
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
        videos: (len(frames),) index of the video of each frame. A video of another place is
            refused before the map is built and the map built from the others
            (``MarkerMapResult.refused_videos``): one sharing no marker with the others, or
            whose markers in common lie elsewhere
            (:func:`~rs_localizer.mapping.marker_init.screen_videos`); one whose frames the
            joint initialization cannot place is an error.
        video_names: the videos' names in messages (default ``video 1``, ``video 2``...).
        up_in_camera: index into ``frames`` -> (3,) unit up direction in that frame's camera
            (optical frame): the accelerometer's mean specific force while still-ish, rotated
            by the camera-IMU mounting; the gravity-aligned frame's first source
            (``options.frame``, :func:`~rs_localizer.mapping.marker_frame.find_up`).
    Returns:
        :class:`MarkerMapResult` in the output frame (``options.anchor`` at
        ``options.anchor_pose``, ``options.anchors`` fitted, gravity-aligned with
        ``options.frame``, or the best-observed marker's own frame).
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
    obs_px, obs_n, stamps = read_detections(frames, camera)
    refused: dict = {}
    if videos is not None:
        if len(videos) != len(frames):
            raise ValueError(f"videos: {len(videos)} entries for {len(frames)} frames")
        refused = screen_videos(obs_px, obs_n, stamps, videos, options, camera, video_names)
        for k in [k for k in obs_px if videos[k] in refused]:
            del obs_px[k], obs_n[k], stamps[k]
        timings["video check"] = time.perf_counter() - t_start
    try:
        # the adjustment's cost does not depend on the world frame (the corner model in a
        # camera-centred world, the motion tie on the camera centres) and the last adjustment
        # is run to convergence, so the output frame changes the map only by a rigid motion
        # and neither the line delay nor the frames' velocities
        gauge, _ = choose_gauge(obs_px, options)
    except ValueError as e:
        if not refused:
            raise
        raise ValueError(f"{e}; {'; '.join(refused.values())}") from None
    if options.anchors:
        unknown = [m for m in options.anchors if np.asarray(options.anchors[m]).size != 12]
        if unknown:
            raise ValueError(f"surveyed anchors {unknown} need (4, 3) corners")
    bar = tqdm(total=5, desc="marker map", disable=not progress, leave=False)
    bar.set_postfix_str("initialization")
    init = initialize(obs_px, obs_n, stamps, options, gauge, camera, videos, video_names)
    if gauge in init.suspects:  # (an id seen at two places cannot hold the map still)
        count = {m: sum(m in d for d in obs_px.values()) for m in init.markers}
        pool = [m for m in init.markers if m not in init.suspects]
        if pool:  # (the coarse adjustment moves the map onto the new gauge)
            gauge = max(pool, key=lambda m: (count[m], -m))
    timings["initialization"] = time.perf_counter() - t_start
    bar.update(1)
    bar.set_postfix_str("coarse adjustment")
    t0 = time.perf_counter()
    _coarse_adjustment(init, obs_px, camera, options, gauge, _gauge_pose(options, gauge))
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
    framed = frame_and_covariance(
        prob, sol, poses, options, gauge, sides, inconsistent, up_in_camera
    )
    timings["covariance"] = time.perf_counter() - t0
    bar.update(1)
    bar.close()
    result = _assemble(
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
    result.refused_videos = refused
    if options.calibrate_readout:
        from ..calibration.readout import line_delay_verdict

        result.line_delay_std = framed["line_delay_std"]
        result.readout_verdict = line_delay_verdict(result.line_delay, result.line_delay_std)
    result.unmapped.update(_never_detected(obs_px, result.unmapped, refused))
    return result


def _never_detected(obs_px: dict, unmapped: dict, refused: dict) -> dict:
    """id -> why, for the ids between 0 and the largest detected id that no frame detected
    (tags in the room the video missed, named when there are at most 10 and at most half as
    many as the detected ids: a set of tags numbered from 0 with a few missing)."""
    ids = {m for d in obs_px.values() for m in d}
    if not ids:
        return {}
    gaps = [m for m in range(max(ids)) if m not in ids and m not in unmapped]
    if not gaps or len(gaps) > min(10, len(ids) // 2):
        return {}
    return {
        m: f"never detected (ids 0-{max(ids)} otherwise seen"
        + ("; in the videos kept" if refused else "")
        + "): if it is in the place, film it from closer"
        for m in gaps
    }


def _coarse_adjustment(init: MarkerInit, obs_px, camera, options, anchor, anchor_pose) -> None:
    """A coarse rolling-shutter adjustment (gauge: the starting frame, wide robust scale) that
    pulls the initialization together, then the whole moved rigidly onto ``anchor_pose`` (the
    adjustment's frame; the output frame is applied after the adjustment)."""
    fr_ids = sorted(init.frames)
    all_ids = sorted(init.markers)
    free = MarkerProblem(
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
    init.frames, init.markers, _ = regauge(
        {k: (Rf[i], Cf[i]) for i, k in enumerate(fr_ids)},
        {m: (Rm[i], pm[i]) for i, m in enumerate(all_ids)},
        anchor,
        anchor_pose,
    )


def _adjust_and_reject(init, obs_px, obs_n, camera, options, anchor, timings, bar) -> tuple:
    """Rolling-shutter bundle adjustment with the gauge marker fixed: robust loss, rejection of
    detections over ``reject_px``, plain least squares to convergence; views split by drift of the
    initialization (not a second copy of the id) are taken back and the map adjusted again.
    Returns ``(problem, solution, inconsistent ids, excluded detections)``."""
    fr_ids = sorted(init.frames)
    mk_ids = [m for m in sorted(init.markers) if m != anchor]
    exclude = set(init.excluded)
    x_start = None
    for rnd in range(2):
        prob = MarkerProblem(init, obs_px, camera, options, fr_ids, mk_ids, anchor, exclude=exclude)
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
        sol = prob.polish(sol.x, max_iter=options.final_max_iter)
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
                @ (np.mean([t for _, t in ippe_candidates(obj, obs_n[k][m])], 0) - Cf[fpos[k]])
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


def _marker_poses(prob: MarkerProblem, x: np.ndarray, gauge: int) -> dict:
    """id -> ``(R (3, 3), p (3,))`` of the gauge marker and every adjusted marker at ``x``."""
    _, _, _, _, Rm, pm, _ = prob.unpack(x)
    poses = {gauge: (prob.Ra, prob.pa)}
    poses.update({m: (Rm[i], pm[i]) for i, m in enumerate(prob.markers)})
    return poses


def _gauge_pose(options: MappingOptions, gauge: int) -> tuple[np.ndarray, np.ndarray]:
    """The gauge marker's pose in the adjustment's frame, ``(R (3, 3), p (3,))``: the anchor at
    its pose when it is the gauge and its pose is given (the solver then starts in the output
    frame), else the gauge marker's own frame."""
    if options.anchor is not None and options.anchor_pose is not None and gauge == options.anchor:
        Ra, pa = options.anchor_pose
        return np.asarray(Ra, float).reshape(3, 3), np.asarray(pa, float).reshape(3)
    return np.eye(3), np.zeros(3)


def _check_anchors_placed(
    gauge: int, inconsistent: dict, options: MappingOptions, init: MarkerInit
) -> None:
    """Raise ValueError when the gauge marker or a surveyed anchor has no single place."""
    if gauge in inconsistent:
        raise ValueError(
            f"anchor marker {gauge} cannot be placed: detected at places that disagree "
            f"({inconsistent[gauge][0].round(2)} and {inconsistent[gauge][1].round(2)})"
        )
    a = options.anchor
    if a is not None and (a in inconsistent or a not in init.markers):
        why = (
            f"detected at places that disagree ({inconsistent[a][0].round(2)} and "
            f"{inconsistent[a][1].round(2)})"
            if a in inconsistent
            else init.unmapped.get(a, "not placed")
        )
        raise ValueError(f"anchor marker {a} cannot be placed: {why}")
    bad = [m for m in (options.anchors or {}) if m in inconsistent or m not in init.markers]
    if bad:
        raise ValueError(f"surveyed anchor(s) {bad} cannot be placed (seen too little, or twice)")


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
    # camera's own velocities (frame_velocities: pose.model_twist with W, T per second; C the
    # world -> camera translation of the adjustment's frame: the camera's velocities in its
    # own frame do not depend on the world frame)
    omega, v = frame_velocities(W, T)
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
        angular_velocity=omega,
        linear_velocity=v,
        line_delay=float(ld),
        rmse_px=float(np.sqrt(np.mean(e**2))) if e.size else float("nan"),
        num_rejected=num_rejected,
        num_frames_skipped=n_frames - len(prob.frames),
        unmapped=init.unmapped,
        inconsistent={m: [Ro @ q + to for q in qs] for m, qs in inconsistent.items()},
        timings=timings,
        global_shutter=options.global_shutter,
        corner_offset_px=prob.corner_offset(sol.x),
        corner_offset_std_px=prob.corner_offset_std(sol.x),
        frame=framed["frame"],
        coverage=_coverage(prob, Rf, Cf, framed["gauge_poses"], mstd, sides, options.coverage_std),
        marker_shape_std=framed["shape_std"],
    )


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
