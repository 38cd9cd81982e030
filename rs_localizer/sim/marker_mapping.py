"""Marker maps of simulated rooms against their truth: the scenes (:func:`room_scene`, a
hand-held walk with an anchor sweep; :func:`drive_detections`, a robot's drive), the errors of
a built map (:func:`map_errors`, :func:`frame_errors` in the map's output frame,
:func:`truth_in_frame`), and localization against a map the way the node does
(:func:`localization_errors`). Used by the marker-mapping tests and
``python -m benchmarks.bench_mapping`` (docs/marker_maps.md)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..camera import CameraModel
from ..mapping import (
    FrameDetections,
    MappingOptions,
    MarkerMapResult,
    corner_jacobian,
)
from .marker_room import (
    AnchorSweep,
    MarkerRoom,
    RobotDrive,
    RoomWalk,
    make_marker_room,
    room_camera,
    simulate_detections,
)

__all__ = [
    "CHI2_3_3SIGMA",
    "ROBUST_ALIGN_SCALE",
    "corner_sigmas",
    "drive_detections",
    "frame_errors",
    "localization_errors",
    "map_errors",
    "map_through_file",
    "robust_rigid_fit",
    "room_scene",
    "same_video_but_readout",
    "truth_in_frame",
]


#: chi-square quantile of 3 degrees of freedom at the 3-sigma probability (0.9973)
CHI2_3_3SIGMA = 14.16


#: m: the scale of the robust shape alignment's Huber weights (:func:`robust_rigid_fit`):
#: corners off by more than this count by their distance, not its square, so the few worst
#: markers of a map do not turn the fit of the rest
ROBUST_ALIGN_SCALE = 0.01


def robust_rigid_fit(
    A: np.ndarray, B: np.ndarray, scale: float = ROBUST_ALIGN_SCALE, iterations: int = 100
) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion that best moves the points ``A`` onto ``B`` (both (N, 3), m) when a
    few of them are far off: iteratively reweighted least squares (SciPy
    ``Rotation.align_vectors`` with weights) of the Huber loss of each point's distance,
    ``scale`` its threshold, started from the least-squares fit. Returns ``(R, t)`` with
    ``B ~ A @ R.T + t``."""
    A, B = np.asarray(A, float), np.asarray(B, float)
    w = np.ones(len(A))
    R, t = np.eye(3), np.zeros(3)
    for _ in range(iterations):
        ca, cb = w @ A / w.sum(), w @ B / w.sum()
        rot, _ = Rotation.align_vectors(B - cb, A - ca, weights=w)
        R_new = rot.as_matrix()
        t_new = cb - R_new @ ca
        done = np.allclose(R_new, R, atol=1e-12) and np.allclose(t_new, t, atol=1e-12)
        R, t = R_new, t_new
        if done:
            break
        e = np.linalg.norm(A @ R.T + t - B, axis=1)
        w = np.minimum(1.0, scale / np.maximum(e, 1e-15))
    return R, t


def map_errors(result: MarkerMapResult, true_corners: dict, true_centres: dict) -> dict:
    """Errors of a built map against the truth.

    Args:
        result: the map. true_corners: id -> (4, 3) true corners (m), true_centres: id ->
            (3,) true centres, both in the map's output frame (:func:`truth_in_frame`).
    Returns:
        dict: ``median_mm``, ``max_mm`` (corner errors as built), ``aligned_median_mm``,
        ``aligned_max_mm`` (after the least-squares rotation and translation of all corners,
        SciPy ``Rotation.align_vectors``), ``robust_median_mm``, ``robust_max_mm`` (after the
        robust rigid fit of :func:`robust_rigid_fit`: the map's shape, which a few markers
        far off do not turn), ``honest`` (fraction of non-anchor markers whose centre
        error is within the reported 3-sigma), ``std_median_mm`` (median over the non-anchor
        markers of the reported centre standard deviation, sqrt of the covariance's trace:
        what the detections can fix).
    """
    ids = sorted(result.corners)
    A = np.concatenate([result.corners[m] for m in ids])
    B = np.concatenate([true_corners[m] for m in ids])
    e = np.linalg.norm(A - B, axis=1)
    ca, cb = A.mean(0), B.mean(0)
    rot, _ = Rotation.align_vectors(B - cb, A - ca)
    ea = np.linalg.norm((A - ca) @ rot.as_matrix().T + cb - B, axis=1)
    Rr, tr = robust_rigid_fit(A, B)
    er = np.linalg.norm(A @ Rr.T + tr - B, axis=1)
    inside, stds = [], []
    for m in ids:
        if m == result.anchor and not result.marker_covariance[m].any():
            continue
        d = result.marker_poses[m][1] - true_centres[m]
        S = result.marker_covariance[m][3:, 3:]
        stds.append(float(np.sqrt(max(np.trace(S), 0.0))))
        try:
            inside.append(float(d @ np.linalg.solve(S, d)) <= CHI2_3_3SIGMA)
        except np.linalg.LinAlgError:
            inside.append(False)
    return dict(
        median_mm=1e3 * float(np.median(e)),
        max_mm=1e3 * float(e.max()),
        aligned_median_mm=1e3 * float(np.median(ea)),
        aligned_max_mm=1e3 * float(ea.max()),
        robust_median_mm=1e3 * float(np.median(er)),
        robust_max_mm=1e3 * float(er.max()),
        honest=float(np.mean(inside)) if inside else float("nan"),
        std_median_mm=1e3 * float(np.median(stds)) if stds else float("nan"),
    )


def room_scene(
    num_frames: int,
    seed: int = 0,
    markers: int = 28,
    anchor_frames: int = 0,
    corner_bias_px: float = 0.0,
    view_error_px: float = 0.0,
    readout_free: bool = False,
) -> tuple:
    """The benchmark's scene: a 4.5 x 4 x 2.6 m room with ``markers`` markers of mixed sizes, the
    hand-held walk around its centre seen by a 640x480 camera with a 30 ms readout, and the
    corner detections of ``num_frames`` frames (0.4 px noise; ``seed``: layout and noise). With
    ``anchor_frames`` > 0 the video opens with that many frames of an
    :class:`~rs_localizer.sim.marker_room.AnchorSweep` 1 m in front of the anchor (marker 0),
    then a cut of 1 s, then the walk. ``corner_bias_px``: the detected corners lie that far
    inside their marker's square; ``view_error_px``: the detector's error that repeats from
    one viewpoint (:func:`simulate_detections`). ``readout_free``: the same video taken
    with a global shutter (same stamps, detections and noise; ``simulate_detections``: map
    it with the camera at zero line delay).

    Returns:
        ``(room, camera, walk, frames, truth, options)``: the
        :class:`~rs_localizer.sim.marker_room.MarkerRoom`, the camera model, the
        :class:`~rs_localizer.sim.marker_room.RoomWalk`, the :class:`FrameDetections` (sweep
        first), the frames' true poses and velocities (:func:`simulate_detections`, same order)
        and the :class:`MappingOptions` with the true sizes and marker 0 as the anchor at its
        true pose.
    """
    room = make_marker_room(markers, seed=seed, size=(4.5, 4.0, 2.6))
    camera = room_camera(readout_time=0.03)
    walk = RoomWalk(centre=(2.25, 2.0))
    dets, truth = simulate_detections(
        room,
        camera,
        walk,
        num_frames=num_frames,
        seed=seed,
        corner_bias_px=corner_bias_px,
        view_error_px=view_error_px,
        view_seed=seed,
        readout_free=readout_free,
    )
    if anchor_frames > 0:
        sweep = AnchorSweep(tuple(room.p[0]), tuple(room.R[0][:, 2]))
        d0, t0 = simulate_detections(
            room,
            camera,
            sweep,
            anchor_frames,
            seed=seed + 1000,
            corner_bias_px=corner_bias_px,
            view_error_px=view_error_px,
            view_seed=seed,
            readout_free=readout_free,
        )
        shift = anchor_frames / 30.0 + 1.0
        dets = [(s - shift, d) for s, d in d0] + dets
        truth = {k: np.concatenate([t0[k], truth[k]]) for k in truth}
    frames = [FrameDetections(s, d) for s, d in dets]
    options = MappingOptions(
        marker_size=0.16,
        marker_sizes={int(i): float(s) for i, s in zip(room.ids, room.sides, strict=True)},
        anchor=0,
        anchor_pose=(room.R[0], room.p[0]),
    )
    return room, camera, walk, frames, truth, options


def drive_detections(
    room: MarkerRoom,
    camera: CameraModel,
    num_frames: int = 300,
    seed: int = 7,
    corner_bias_px: float = 0.0,
    view_error_px: float = 0.0,
    view_seed: int = 0,
    readout_free: bool = False,
) -> tuple:
    """A second video in the benchmark's room: a robot driving one loop at 0.4 m height
    (:class:`~rs_localizer.sim.marker_room.RobotDrive`, 10 s) with the same camera, 0.4 px
    noise, ``corner_bias_px`` and ``view_error_px`` as :func:`room_scene` (``view_seed``: the
    room's; ``readout_free``: the same video with a global shutter). Returns
    ``(detections, truth)`` as :func:`simulate_detections`."""
    return simulate_detections(
        room,
        camera,
        RobotDrive(centre=(2.25, 2.0)),
        num_frames=num_frames,
        seed=seed,
        corner_bias_px=corner_bias_px,
        view_error_px=view_error_px,
        view_seed=view_seed,
        readout_free=readout_free,
    )


def truth_in_frame(result: MarkerMapResult, room: MarkerRoom, options: MappingOptions) -> tuple:
    """The true corners and centres in the map's output frame: the world itself when the
    frame is fixed by surveyed markers (their true corners) or an anchor at its true pose;
    else the anchor's own frame (the true poses moved so that the anchor sits at
    ``options.anchor_pose`` or the identity). Returns ``(corners {id: (4, 3)}, centres
    {id: (3,)})``."""
    corners = room.corners()
    centres = {int(i): room.p[i] for i in room.ids}
    if result.frame is not None and result.frame.kind == "surveyed":
        return corners, centres
    a = int(result.anchor)
    Rt, pt = (np.eye(3), np.zeros(3)) if options.anchor_pose is None else options.anchor_pose
    if result.frame is not None and result.frame.kind == "best-observed":
        Rt, pt = np.eye(3), np.zeros(3)
    R = np.asarray(Rt) @ room.R[a].T
    t = np.asarray(pt) - R @ room.p[a]
    return (
        {m: c @ R.T + t for m, c in corners.items()},
        {m: R @ c + t for m, c in centres.items()},
    )


def frame_errors(result: MarkerMapResult, true_centres: dict) -> dict:
    """The output frame's true error against its stated uncertainty: the rotation of the
    rigid best fit of the map's centres onto their truth (deg), its Mahalanobis distance under
    the stated frame rotation covariance (``result.frame.covariance[:3, :3]``) and whether it
    lies within 3 sigma (chi2_3 below 14.16). Returns ``rotation_deg``, ``stated_deg``
    (largest-axis std), ``covered``."""
    ids = sorted(result.marker_poses)
    A = np.array([result.marker_poses[m][1] for m in ids])
    B = np.array([true_centres[m] for m in ids])
    rot, _ = Rotation.align_vectors(B - B.mean(0), A - A.mean(0))
    v = rot.as_rotvec()
    S = result.frame.covariance[:3, :3]
    try:
        d2 = float(v @ np.linalg.solve(S, v))
    except np.linalg.LinAlgError:
        d2 = float("inf")
    return dict(
        rotation_deg=float(np.degrees(np.linalg.norm(v))),
        stated_deg=result.frame.rotation_std_deg,
        covered=d2 <= CHI2_3_3SIGMA,
    )


def localization_errors(
    detections: list,
    truth: dict,
    marker_corners: dict,
    camera: CameraModel,
    solver: str = "r6p_1lin",
    marker_std: dict | None = None,
    corner_sigma: dict | None = None,
    min_markers: int = 1,
) -> dict:
    """Localize every frame of a video against a marker map, one frame at a time, the way the
    ``aruco`` front end and the estimator do in the node (the detected corners of the mapped
    markers as correspondences, ``estimate_rs_pose`` with the node's default options).

    Args:
        detections: ``[(stamp, {id: (4, 2) pixels})]`` (:func:`simulate_detections`).
        truth: the frames' true ``orientation`` (K, 3, 3) camera -> world and ``position``
            (K, 3) m, world frame.
        marker_corners: the map, id -> (4, 3) world corners (m).
        camera: the camera model. solver: the estimator's solver.
        marker_std: id -> stated position std (m): the correspondences scored by it as the
            ArUco front end does (:func:`rs_localizer.frontends.aruco.marker_scores`).
        corner_sigma: id -> (4,) stated std of each corner (m, per axis;
            :func:`corner_sigmas`): the estimator's final fit weighs each corner by it
            (``estimate_rs_pose(..., point_sigma=)``).
        min_markers: only frames that see at least this many mapped markers (3: the frames
            the default solver's RANSAC takes; fewer coplanar markers are posed by IPPE from
            their corners alone).
    Returns:
        dict: ``frames`` (with at least ``min_markers`` mapped markers), ``solved``, ``failed`` (a
        :class:`collections.Counter` of failure reasons), ``rotation_deg`` and
        ``position_cm`` (medians over the solved frames, against the truth), ``per_frame``
        (frame index -> ``(rotation_deg, position_cm)`` of each solved frame: for
        ``benchmarks.bench_mapping.paired_ratios``).
    """
    from collections import Counter

    from ..estimation import estimate_rs_pose
    from ..frontends import marker_scores
    from ..geometry import rotation_angle_deg

    rot, pos, per_frame, failed, n = [], [], {}, Counter(), 0
    for k, (_, d) in enumerate(detections):
        ids = [m for m in sorted(d) if m in marker_corners]
        if not ids or len(ids) < min_markers:
            continue
        n += 1
        uv = np.concatenate([d[m] for m in ids])
        X = np.concatenate([np.asarray(marker_corners[m], float) for m in ids])
        scores = (
            None
            if marker_std is None
            else np.repeat(marker_scores(np.array([marker_std.get(m, 0.0) for m in ids])), 4)
        )
        sigma = (
            None
            if corner_sigma is None
            else np.concatenate([np.asarray(corner_sigma[m], float) for m in ids])
        )
        est = estimate_rs_pose(uv, X, camera, solver=solver, scores=scores, point_sigma=sigma)
        if not est.success:
            failed[est.failure] += 1
            continue
        rot.append(rotation_angle_deg(est.pose.orientation, truth["orientation"][k]))
        pos.append(100 * np.linalg.norm(est.pose.position - truth["position"][k]))
        per_frame[k] = (rot[-1], pos[-1])
    return dict(
        frames=n,
        solved=len(rot),
        failed=failed,
        rotation_deg=float(np.median(rot)) if rot else float("nan"),
        position_cm=float(np.median(pos)) if pos else float("nan"),
        per_frame=per_frame,
    )


def corner_sigmas(result: MarkerMapResult) -> dict:
    """The stated standard deviation of each mapped corner (m, per axis): a corner
    ``c = p + R o`` of a marker whose pose (rotation, centre) has the covariance ``S``
    (``result.marker_covariance``) has the covariance ``J S J^T``, ``J = [-[R o]x, I]``
    (:func:`~rs_localizer.mapping.corner_jacobian`);
    returned as ``sqrt(trace / 3)``. Returns id -> (4,)."""
    out = {}
    for m, c in result.corners.items():
        S = result.marker_covariance[m]
        p = result.marker_poses[m][1]
        sig = []
        for ro in np.asarray(c, float) - p:
            J = corner_jacobian(ro)
            sig.append(float(np.sqrt(max(np.trace(J @ S @ J.T), 0.0) / 3.0)))
        out[m] = np.array(sig)
    return out


def map_through_file(result: MarkerMapResult) -> dict:
    """The map as the node reads it: written by ``map-markers``' writer, loaded by
    :func:`rs_localizer.maps.load_marker_map` (id -> (4, 3) corners)."""
    import tempfile
    from pathlib import Path

    from ..mapping.outputs import write_map
    from ..maps import load_marker_map

    with tempfile.TemporaryDirectory() as d:
        path = write_map(Path(d) / "map.yaml", result, "DICT_APRILTAG_36h11")
        return load_marker_map(path)[1]


def same_video_but_readout(a: list, b: list, max_px: float = 50.0) -> bool:
    """Whether two lists of :class:`FrameDetections` are one video and its readout-free twin:
    the same stamps, the same markers detected in each frame, and every corner within
    ``max_px`` pixels of its twin (the rolling-shutter distortion: up to half the readout
    time's motion, about 20 px at the benchmark's fastest turns)."""
    if len(a) != len(b):
        return False
    for fa, fb in zip(a, b, strict=True):
        if fa.stamp != fb.stamp or sorted(fa.corners) != sorted(fb.corners):
            return False
        for m, c in fa.corners.items():
            if np.abs(np.asarray(c) - np.asarray(fb.corners[m])).max() > max_px:
                return False
    return True
