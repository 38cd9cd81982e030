"""Marker maps from rolling-shutter videos: ``python -m rs_localizer.evaluation.bench_mapping``.

The scene (:mod:`rs_localizer.sim.marker_room`): a 4.5 x 4 x 2.6 m room with 30 markers of
0.12-0.30 m (marker 0, 0.30 m, is the anchor; one on the floor, a third tilted out of their
wall); 640x480, f = 500 px, 30 ms readout, 30 fps, 0.4 px corner noise, the corners 0.19 px
inside their squares, and a detector error of 0.3 px that repeats when a marker is seen again
from the same viewpoint (:func:`~rs_localizer.sim.marker_room.view_dependent_error`). Corners
are projected with the camera pose at each line's own capture time (no images: detections
only). Three mapping videos unlike each other:

- **walk + anchor sweep**: 2 s in front of the anchor, looking at it from the left and the
  right at ~1 m (:class:`~rs_localizer.sim.marker_room.AnchorSweep`), a cut, then a hand-held
  walk turning around the room once every 5 s (up to ~2.2 rad/s);
- **one spot, small anchor**: the same layout with a 16 cm anchor, a hand-held video from one
  spot in a corner panning across the room (:class:`~rs_localizer.sim.marker_room.OneSpot`;
  the anchor 4.5 m away, seen head-on);
- **robot drive**: a robot driving a loop at 0.4 m height
  (:class:`~rs_localizer.sim.marker_room.RobotDrive`).

Each is mapped with three choices of the output frame (marker 0 at its true pose; the
best-observed marker, the default; marker 0 and the two markers seen most often, surveyed at
their true corners) and with the global-shutter model in the default frame (the rolling- to
global-shutter comparison is of the maps' shapes in that frame, which every video has: a
video need not see marker 0), and each video's floor: the same video taken with a global
shutter (the same motion, stamps, detected markers, noise and detector error; every corner
where a camera reading all its lines at the frame's stamp sees it:
``simulate_detections(readout_free=True)``), mapped by the same tool (the rolling-shutter
model, zero line delay) in the default frame, and the walk's also with marker 0 at its true
pose: the precision the detections allow when the shutter costs nothing. Its ratios to the
rolling- and global-shutter maps are printed per video (global shutter / floor: the most the
rolling- to global-shutter ratio can be with a map at the floor). Printed per map, in its
output frame: the marker-corner error (median, max; mm), the median after the least-squares
rigid alignment of all corners and after a robust one (Huber weights on each corner's distance,
scale 10 mm, :func:`robust_rigid_fit`: the map's shape, which a few markers far off do not
turn; the rolling- to global-shutter comparison uses it), the median stated standard
deviation of the marker centres (sqrt of the covariance's trace), the fraction of markers
whose centre error lies within the stated 3-sigma (Mahalanobis distance below chi2_3(0.9973)
= 14.16), the frame's true rotation (the best fit of the map's centres onto the truth)
against its stated std and whether that lies within the stated 3-sigma, the correlation of
the repeated detector errors found, the time. Then the walk and the drive mapped together;
then a second drive (the same loop, other noise) localized frame by frame against the true
map and the built maps (written and read as the node reads them; the walk's floor map; the
walk's map also with the correspondences scored by the markers' stated std, and with the
final fit weighing each corner by its stated std, :func:`corner_sigmas`, or by its shape-only std,
``MarkerMapResult.marker_shape_std``), each map's errors compared with the true
map's on the frames both solve, and the targets. One BLAS thread.

    python -m rs_localizer.evaluation.bench_mapping [--frames 240] [--anchor-frames 60]
        [--spot-frames 150] [--map-drive-frames 300] [--markers 30] [--seed 0]
        [--drive-frames 300] [--corner-bias 0.19] [--view-error 0.3]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..mapping import (
    FrameDetections,
    MappingOptions,
    MarkerMapResult,
    concatenate_videos,
    corner_jacobian,
    map_markers,
)
from ..sim.marker_room import (
    AnchorSweep,
    OneSpot,
    RobotDrive,
    RoomWalk,
    make_marker_room,
    room_camera,
    simulate_detections,
)
from .threads import one_thread

__all__ = [
    "CHI2_3_3SIGMA",
    "ROBUST_ALIGN_SCALE",
    "corner_sigmas",
    "drive_detections",
    "frame_errors",
    "localization_errors",
    "main",
    "map_errors",
    "paired_ratios",
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
    room,
    camera,
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


def truth_in_frame(result: MarkerMapResult, room, options: MappingOptions) -> tuple:
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
    camera,
    solver: str = "r6p_1lin",
    marker_std: dict | None = None,
    corner_sigma: dict | None = None,
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
    Returns:
        dict: ``frames`` (with at least one mapped marker), ``solved``, ``failed`` (a
        :class:`collections.Counter` of failure reasons), ``rotation_deg`` and
        ``position_cm`` (medians over the solved frames, against the truth), ``per_frame``
        (frame index -> ``(rotation_deg, position_cm)`` of each solved frame: for
        :func:`paired_ratios`).
    """
    from collections import Counter

    from ..estimation import estimate_rs_pose
    from ..frontends.aruco import marker_scores
    from ..geometry import rotation_angle_deg

    rot, pos, per_frame, failed, n = [], [], {}, Counter(), 0
    for k, (_, d) in enumerate(detections):
        ids = [m for m in sorted(d) if m in marker_corners]
        if not ids:
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
        rot.append(rotation_angle_deg(est.orientation, truth["orientation"][k]))
        pos.append(100 * np.linalg.norm(est.position - truth["position"][k]))
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
    (:func:`~rs_localizer.mapping.marker_ba.corner_jacobian`);
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


def paired_ratios(result: dict, reference: dict) -> tuple[float, float, int]:
    """Errors against one map relative to another on the same frames: the medians of the
    rotation and position errors over the frames that both solve (:func:`localization_errors`
    results), as ratios ``result / reference``, and the number of those frames (NaN ratios
    when there are none). Frames one map solves and the other does not are not in the ratio
    (they are counted in each map's own ``solved`` and ``failed``): the medians of different
    frame sets would mix the map's error with which frames it happens to solve."""
    common = sorted(set(result["per_frame"]) & set(reference["per_frame"]))
    if not common:
        return float("nan"), float("nan"), 0
    a = np.array([result["per_frame"][k] for k in common])
    b = np.array([reference["per_frame"][k] for k in common])
    med_a, med_b = np.median(a, axis=0), np.median(b, axis=0)
    return float(med_a[0] / med_b[0]), float(med_a[1] / med_b[1]), len(common)


def _map_through_file(result: MarkerMapResult) -> dict:
    """The map as the node reads it: written by ``map-markers``' writer, loaded by
    :func:`rs_localizer.maps.load_marker_map` (id -> (4, 3) corners)."""
    import tempfile
    from pathlib import Path

    from ..mapping.outputs import write_map
    from ..maps import load_marker_map

    with tempfile.TemporaryDirectory() as d:
        path = write_map(Path(d) / "map.yaml", result, "DICT_APRILTAG_36h11")
        return load_marker_map(path)[1]


def _videos(args, readout_free: bool = False) -> dict:
    """The three mapping videos: name -> (room, detections as FrameDetections, options);
    ``readout_free``: the same videos taken with a global shutter (same stamps, detections,
    noise; :func:`~rs_localizer.sim.marker_room.simulate_detections`)."""
    bias, verr = args.corner_bias, args.view_error
    room, camera, _, frames, _, opts = room_scene(
        args.frames, args.seed, args.markers, args.anchor_frames, bias, verr, readout_free
    )
    out = {"walk + anchor sweep": (room, frames, opts)}
    small = make_marker_room(args.markers, seed=args.seed, size=(4.5, 4.0, 2.6), anchor_side=0.16)
    d, _ = simulate_detections(
        small,
        camera,
        OneSpot(),
        args.spot_frames,
        seed=args.seed + 3,
        corner_bias_px=bias,
        view_error_px=verr,
        view_seed=args.seed,
        readout_free=readout_free,
    )
    sizes = {int(i): float(s) for i, s in zip(small.ids, small.sides, strict=True)}
    out["one spot, small anchor"] = (
        small,
        [FrameDetections(s, c) for s, c in d],
        replace(opts, marker_sizes=sizes, anchor_pose=(small.R[0], small.p[0])),
    )
    d, _ = drive_detections(
        room, camera, args.map_drive_frames, args.seed + 11, bias, verr, args.seed, readout_free
    )
    out["robot drive"] = (room, [FrameDetections(s, c) for s, c in d], opts)
    return out


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


def _frame_choices(room, frames: list, opts: MappingOptions) -> dict:
    """Frame choices measured: the anchor (marker 0 at its true pose), the best-observed
    marker, and three surveyed markers (their true corners: marker 0 and the two markers
    the video detects most often besides it)."""
    corners = room.corners()
    count: dict = {}
    for f in frames:
        for m in f.corners:
            count[m] = count.get(m, 0) + (m != 0)
    seen = sorted(sorted(count, key=lambda m: -count[m])[:2])
    return {
        "anchor 0": opts,
        "best-observed": replace(opts, anchor=None, anchor_pose=None),
        "surveyed 0," + ",".join(map(str, seen)): replace(
            opts, anchor=None, anchor_pose=None, anchors={m: corners[m] for m in [0, *seen]}
        ),
    }


def main(argv: list | None = None) -> int:
    """Run the benchmark and print its tables and targets; returns 0."""
    p = argparse.ArgumentParser(
        prog="python -m rs_localizer.evaluation.bench_mapping",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--frames", type=int, default=240, help="frames of the walk at 30 fps")
    p.add_argument(
        "--anchor-frames",
        type=int,
        default=60,
        help="frames in front of the anchor before the walk (0: the walk only)",
    )
    p.add_argument("--spot-frames", type=int, default=150, help="frames of the one-spot video")
    p.add_argument(
        "--map-drive-frames", type=int, default=300, help="frames of the robot drive mapped"
    )
    p.add_argument("--markers", type=int, default=30, help="markers in the room")
    p.add_argument("--seed", type=int, default=0, help="layout and noise seed")
    p.add_argument("--drive-frames", type=int, default=300, help="frames of the second video")
    p.add_argument(
        "--corner-bias",
        type=float,
        default=0.19,
        help="px: detected corners inside their marker's square (OpenCV's on rendered images)",
    )
    p.add_argument(
        "--view-error",
        type=float,
        default=0.3,
        help="px: the detector's error that repeats from one viewpoint (rms per axis)",
    )
    args = p.parse_args(argv)
    camera = room_camera(readout_time=0.03)
    print(
        f"marker maps: 640x480, 30 ms readout, 0.4 px noise, corners {args.corner_bias} px "
        f"inside, {args.view_error} px detector error repeating from one viewpoint; "
        "errors in mm in each map's output frame; one BLAS thread"
    )
    print(
        f"{'video':24s} {'frame':22s} {'mapped':>6s} {'median':>7s} {'max':>7s} {'al.med':>7s} "
        f"{'rob.med':>7s} {'std':>6s} {'3-sig':>6s} {'frame deg':>9s} {'stated':>7s} {'cov.':>5s} "
        f"{'rho':>5s} {'time s':>7s}"
    )
    targets, medians, shapes, maps, built, floors = [], {}, {}, {}, {}, []
    floor_camera = room_camera(readout_time=0.0)
    with one_thread():
        floor_videos = _videos(args, readout_free=True)
        videos = _videos(args)
        for vname, (room, frames, opts) in videos.items():
            floor_frames = floor_videos[vname][1]
            if not same_video_but_readout(frames, floor_frames):
                raise RuntimeError(f"{vname}: the readout-free twin is not the same video")
            choices = _frame_choices(room, frames, opts)
            # the global-shutter model in the default frame (the best-observed marker): a frame
            # every video has (a video need not see marker 0)
            gs = replace(choices["best-observed"], global_shutter=True)
            runs = [(f, o, frames, camera) for f, o in choices.items()]
            runs.append(("GS, best-observed", gs, frames, camera))
            # the floor: the same video taken with a global shutter, mapped by the same tool
            # (rolling-shutter model, zero line delay) in the default frame; the walk's also
            # with marker 0 at its true pose, to localize against
            runs.append(
                ("no readout (floor)", choices["best-observed"], floor_frames, floor_camera)
            )
            if vname == "walk + anchor sweep":
                runs.append(
                    ("no readout, anchor 0", choices["anchor 0"], floor_frames, floor_camera)
                )
            for fname, o, fr, cam in runs:
                t0 = time.perf_counter()
                try:
                    res = map_markers(fr, cam, o)
                except ValueError as e:
                    print(f"{vname:24s} {fname:22s} refused: {e}")
                    continue
                total = time.perf_counter() - t0
                tc, tp = truth_in_frame(res, room, o)
                e = map_errors(res, tc, tp)
                fe = frame_errors(res, tp)
                medians[(vname, fname)] = e["median_mm"]
                shapes[(vname, fname)] = e["robust_median_mm"]
                built[(vname, fname)] = res
                print(
                    f"{vname:24s} {fname:22s} {len(res.corners):6d} {e['median_mm']:7.1f} "
                    f"{e['max_mm']:7.1f} {e['aligned_median_mm']:7.1f} "
                    f"{e['robust_median_mm']:7.1f} {e['std_median_mm']:6.1f} "
                    f"{100 * e['honest']:5.0f}% {fe['rotation_deg']:9.3f} "
                    f"{fe['stated_deg']:7.3f} {'yes' if fe['covered'] else 'no':>5s} "
                    f"{res.frame.shared_error_correlation:5.2f} {total:7.1f}"
                )
                if fname.startswith(("GS", "no readout")):
                    continue
                targets.append(
                    (
                        f"{vname}, {fname}: >= 90 % of markers within 3 stated sigmas",
                        f"{100 * e['honest']:.0f} %",
                        e["honest"] >= 0.9,
                    )
                )
                targets.append(
                    (
                        f"{vname}, {fname}: frame rotation within its stated 3 sigma",
                        f"{fe['rotation_deg']:.3f} deg (std {fe['stated_deg']:.3f})",
                        fe["covered"],
                    )
                )
            if (vname, "GS, best-observed") in shapes and (vname, "best-observed") in shapes:
                # (the map's shape: after the robust rigid fit, both in the default frame)
                gs_mm, rs_mm = (
                    shapes[(vname, "GS, best-observed")],
                    shapes[(vname, "best-observed")],
                )
                r = gs_mm / rs_mm
                targets.append(
                    (
                        f"{vname}: GS / RS median corner error after the robust rigid fit, >= 3x",
                        f"{r:.1f}x ({gs_mm:.1f} / {rs_mm:.1f} mm)",
                        r >= 3,
                    )
                )
            if (vname, "anchor 0") in built:
                maps[vname] = _map_through_file(built[(vname, "anchor 0")])
            keys = [
                (vname, f) for f in ("best-observed", "GS, best-observed", "no readout (floor)")
            ]
            if all(k in shapes for k in keys):
                rs, gs_, fl = (shapes[k] for k in keys)
                rs0, gs0, fl0 = (medians[k] for k in keys)
                floors.append(
                    f"  {vname}: robust median RS {rs:.1f}, GS {gs_:.1f}, floor {fl:.1f} mm: "
                    f"RS/floor {rs / fl:.2f}x, GS/floor {gs_ / fl:.2f}x (the most GS/RS can be "
                    f"with a map at the floor); as built RS/floor {rs0 / fl0:.2f}x, GS/floor "
                    f"{gs0 / fl0:.2f}x"
                )

        print(
            "\nthe floor: each video taken with a global shutter (same motion, stamps, "
            "detections and noise), mapped by the same tool, best-observed frame"
        )
        for line in floors:
            print(line)

        # two videos merged
        room, walk_frames, opts = videos["walk + anchor sweep"]
        _, drive_frames, _ = videos["robot drive"]
        merged = map_markers(concatenate_videos([walk_frames, drive_frames]), camera, opts)
        tc, tp = truth_in_frame(merged, room, opts)
        em = map_errors(merged, tc, tp)
        singles = [
            medians.get((v, "anchor 0"), np.inf) for v in ("walk + anchor sweep", "robot drive")
        ]
        std_single = [
            map_errors(built[(v, "anchor 0")], tc, tp)["std_median_mm"]
            for v in ("walk + anchor sweep", "robot drive")
            if (v, "anchor 0") in built
        ]
        print(
            f"\ntwo videos merged (walk + anchor sweep, robot drive), anchor 0: median "
            f"{em['median_mm']:.1f} mm (singles: "
            + ", ".join(
                f"{s:.1f}" if np.isfinite(s) else "not mappable in this frame" for s in singles
            )
            + "), stated std "
            f"median {em['std_median_mm']:.1f} mm (singles "
            + ", ".join(f"{s:.1f}" for s in std_single)
            + f"), {100 * em['honest']:.0f} % within 3 sigma"
        )
        r = em["median_mm"] / min(singles)
        targets.append(
            (
                "two videos merged: median corner error <= 0.7x the better single",
                f"{r:.2f}x",
                r <= 0.7,
            )
        )
        maps["merged"] = _map_through_file(merged)

        dets, truth = drive_detections(
            room,
            camera,
            args.drive_frames,
            seed=args.seed + 7,
            corner_bias_px=args.corner_bias,
            view_error_px=args.view_error,
            view_seed=args.seed,
        )
        print(
            f"\nlocalization of a second video ({args.drive_frames} frames, a robot driving a "
            "loop at 0.4 m), r6p_1lin frame by frame, default options, medians against the "
            "truth; 'vs true map': ratio of the medians over the frames solved against both "
            "this map and the true map ('both': how many)"
        )
        print(
            f"{'map':24s} {'frames':>6s} {'solved':>6s} {'rot deg':>8s} {'pos cm':>7s} "
            f"{'both':>5s} {'vs true map':>12s}  not solved"
        )
        ref = None
        walk = built.get(("walk + anchor sweep", "anchor 0"))
        rows = [
            ("true map", room.corners(), None, None),
            *((k, v, None, None) for k, v in maps.items()),
        ]
        if ("walk + anchor sweep", "no readout, anchor 0") in built:
            floor_walk = built[("walk + anchor sweep", "no readout, anchor 0")]
            rows.append(("walk, no readout (floor)", _map_through_file(floor_walk), None, None))
        if walk is not None:
            std = {m: float(s[3:].max()) for m, s in walk.marker_std.items()}
            rows.append(("walk, scored by std", maps["walk + anchor sweep"], std, None))
            rows.append(
                ("walk, weighted by std", maps["walk + anchor sweep"], None, corner_sigmas(walk))
            )
            rows.append(
                (
                    "walk, by shape std",
                    maps["walk + anchor sweep"],
                    None,
                    walk.marker_shape_std,
                )
            )
        for name, corners, std, sigma in rows:
            if name == "one spot, small anchor":
                continue  # (another room)
            r = localization_errors(
                dets, truth, corners, camera, marker_std=std, corner_sigma=sigma
            )
            if ref is None:
                ref = r
            rr, rp, both = paired_ratios(r, ref)
            print(
                f"{name:24s} {r['frames']:6d} {r['solved']:6d} {r['rotation_deg']:8.3f} "
                f"{r['position_cm']:7.2f} {both:5d} {f'{rr:.2f}x {rp:.2f}x':>12s}  "
                f"{dict(r['failed'])}"
            )
            what = {
                "walk + anchor sweep": "the walk's map",
                "merged": "the merged map (walk + drive)",
                "walk, weighted by std": "the walk's map, corners weighted by their std",
                "walk, by shape std": "the walk's map, corners weighted by their shape-only std",
            }.get(name)
            if what is not None:
                targets.append(
                    (
                        f"localization against {what} within 1.5x of the true map",
                        f"{rr:.2f}x rotation, {rp:.2f}x position ({both} frames; solved "
                        f"{r['solved']} against it, {ref['solved']} against the true map)",
                        max(rr, rp) <= 1.5,
                    )
                )
    print("\ntargets")
    for what, got, ok in targets:
        print(f"  [{'met' if ok else 'MISSED'}] {what}: {got}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
