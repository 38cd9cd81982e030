"""Marker maps from a rolling-shutter video: ``python -m rs_localizer.evaluation.bench_mapping``.

The scene (:mod:`rs_localizer.sim.marker_room`): a 4.5 x 4 x 2.6 m room with 30 markers of
0.12-0.30 m (marker 0, 0.30 m, is the anchor; one on the floor, a third tilted out of their
wall). The mapping video opens with 2 s in front of the anchor, looking at it from the left and
the right at ~1 m (:class:`~rs_localizer.sim.marker_room.AnchorSweep`), then a cut, then a
hand-held walk that turns around the room once every 5 s (angular speed up to ~2.2 rad/s);
640x480, f = 500 px, 30 ms readout, 0.4 px corner noise, 30 fps. Corners are projected with the
camera pose at each line's own capture time (no images: detections only).

Prints, for the rolling-shutter adjustment at the true line delay, the global-shutter one on the
same detections, the rolling-shutter one calibrating the line delay from a start 20 % off, and
the rolling-shutter one of the walk alone (without the views of the anchor): the marker-corner
error (median, max; mm) with the gauge fixed on the anchor only (its true pose, no best-fit
alignment), the same after a best-fit rigid alignment (the map's shape), the median reported
standard deviation of the marker centres (what the detections can fix), the fraction of
markers whose centre error lies within its reported 3-sigma (Mahalanobis distance below
chi2_3(0.9973) = 14.16), the reprojection RMSE, the line delay error, and the time per stage.

Then a second video in the same room (a robot driving a loop at 0.4 m,
:class:`~rs_localizer.sim.marker_room.RobotDrive`) is localized frame by frame against the
true map and against each built map (written and loaded as the node reads it): median rotation
and position errors against the truth and their ratio to the true map's. One BLAS thread.

    python -m rs_localizer.evaluation.bench_mapping [--frames 240] [--anchor-frames 60]
        [--markers 30] [--seed 0] [--drive-frames 300]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..mapping.marker_ba import FrameDetections, MappingOptions, MarkerMapResult, map_markers
from ..sim.marker_room import (
    AnchorSweep,
    RobotDrive,
    RoomWalk,
    make_marker_room,
    room_camera,
    simulate_detections,
)
from .threads import one_thread

__all__ = [
    "CHI2_3_3SIGMA",
    "drive_detections",
    "localization_errors",
    "main",
    "map_errors",
    "room_scene",
]

#: chi-square quantile of 3 degrees of freedom at the 3-sigma probability (0.9973)
CHI2_3_3SIGMA = 14.16


def map_errors(result: MarkerMapResult, true_corners: dict, true_centres: dict) -> dict:
    """Errors of a built map against the truth.

    Args:
        result: the map (world frame: the anchor placed at its true pose).
        true_corners: id -> (4, 3) true corners (m). true_centres: id -> (3,) true centres.
    Returns:
        dict: ``median_mm``, ``max_mm`` (corner errors as built), ``aligned_median_mm``,
        ``aligned_max_mm`` (after the best-fit rotation and translation of all corners, SciPy
        ``Rotation.align_vectors``), ``honest`` (fraction of non-anchor markers whose centre
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
    inside, stds = [], []
    for m in ids:
        if m == result.anchor:
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
        honest=float(np.mean(inside)) if inside else float("nan"),
        std_median_mm=1e3 * float(np.median(stds)) if stds else float("nan"),
    )


def room_scene(
    num_frames: int,
    seed: int = 0,
    markers: int = 28,
    anchor_frames: int = 0,
    corner_bias_px: float = 0.0,
) -> tuple:
    """The benchmark's scene: a 4.5 x 4 x 2.6 m room with ``markers`` markers of mixed sizes, the
    hand-held walk around its centre seen by a 640x480 camera with a 30 ms readout, and the
    corner detections of ``num_frames`` frames (0.4 px noise; ``seed``: layout and noise). With
    ``anchor_frames`` > 0 the video opens with that many frames of an
    :class:`~rs_localizer.sim.marker_room.AnchorSweep` 1 m in front of the anchor (marker 0),
    then a cut of 1 s, then the walk. ``corner_bias_px``: the detected corners lie that far
    inside their marker's square (:func:`simulate_detections`).

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
        room, camera, walk, num_frames=num_frames, seed=seed, corner_bias_px=corner_bias_px
    )
    if anchor_frames > 0:
        sweep = AnchorSweep(tuple(room.p[0]), tuple(room.R[0][:, 2]))
        d0, t0 = simulate_detections(
            room, camera, sweep, anchor_frames, seed=seed + 1000, corner_bias_px=corner_bias_px
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
    room, camera, num_frames: int = 300, seed: int = 7, corner_bias_px: float = 0.0
) -> tuple:
    """A second video in the benchmark's room: a robot driving one loop at 0.4 m height
    (:class:`~rs_localizer.sim.marker_room.RobotDrive`, 10 s) with the same camera, 0.4 px
    noise, ``corner_bias_px`` as :func:`room_scene`. Returns ``(detections, truth)`` as
    :func:`simulate_detections`."""
    return simulate_detections(
        room,
        camera,
        RobotDrive(centre=(2.25, 2.0)),
        num_frames=num_frames,
        seed=seed,
        corner_bias_px=corner_bias_px,
    )


def localization_errors(
    detections: list,
    truth: dict,
    marker_corners: dict,
    camera,
    solver: str = "r6p_1lin",
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
    Returns:
        dict: ``frames`` (with at least one mapped marker), ``solved``, ``failed`` (a
        :class:`collections.Counter` of failure reasons), ``rotation_deg`` and
        ``position_cm`` (medians over the solved frames, against the truth).
    """
    from collections import Counter

    from ..estimation import estimate_rs_pose
    from ..geometry import rotation_angle_deg

    rot, pos, failed, n = [], [], Counter(), 0
    for k, (_, d) in enumerate(detections):
        ids = [m for m in sorted(d) if m in marker_corners]
        if not ids:
            continue
        n += 1
        uv = np.concatenate([d[m] for m in ids])
        X = np.concatenate([np.asarray(marker_corners[m], float) for m in ids])
        est = estimate_rs_pose(uv, X, camera, solver=solver)
        if not est.success:
            failed[est.failure] += 1
            continue
        rot.append(rotation_angle_deg(est.orientation, truth["orientation"][k]))
        pos.append(100 * np.linalg.norm(est.position - truth["position"][k]))
    return dict(
        frames=n,
        solved=len(rot),
        failed=failed,
        rotation_deg=float(np.median(rot)) if rot else float("nan"),
        position_cm=float(np.median(pos)) if pos else float("nan"),
    )


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


def main(argv: list | None = None) -> int:
    """Run the benchmark and print its tables; returns 0."""
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
    p.add_argument("--markers", type=int, default=30, help="markers in the room")
    p.add_argument("--seed", type=int, default=0, help="layout and noise seed")
    p.add_argument("--drive-frames", type=int, default=300, help="frames of the second video")
    p.add_argument(
        "--corner-bias",
        type=float,
        default=0.19,
        help="px: detected corners inside their marker's square (OpenCV's on rendered images)",
    )
    args = p.parse_args(argv)
    room, camera, walk, frames, _, opts = room_scene(
        args.frames, args.seed, args.markers, args.anchor_frames, args.corner_bias
    )
    true_corners = room.corners()
    true_centres = {int(i): room.p[i] for i in room.ids}
    runs = [
        ("rolling shutter", camera, opts, frames),
        ("global shutter", camera, replace(opts, global_shutter=True), frames),
        (
            "RS, calibrate readout",
            room_camera(line_delay=1.2 * camera.line_delay),
            replace(opts, calibrate_readout=True),
            frames,
        ),
    ]
    if args.anchor_frames > 0:
        runs.append(("RS, walk only", camera, opts, frames[args.anchor_frames :]))
    if args.corner_bias:
        runs.append(("RS, no corner offset", camera, replace(opts, corner_offset=False), frames))
    n_det = sum(len(f.corners) for f in frames)
    print(
        f"{len(frames)} frames ({args.anchor_frames} in front of the anchor, then the walk), "
        f"{args.markers} markers ({n_det} detections, {walk.max_angular_rate():.1f} rad/s max), "
        f"30 ms readout, 0.4 px noise, corners {args.corner_bias} px inside; errors in mm, the "
        "anchor at its true pose; one BLAS thread"
    )
    head = (
        f"{'model':24s} {'mapped':>6s} {'median':>7s} {'max':>7s} {'al.med':>7s} {'al.max':>7s} "
        f"{'std':>6s} {'3-sig':>6s} {'rmse px':>7s} {'delay %':>7s} {'offs px':>7s} {'time s':>7s}"
        "  stages (s)"
    )
    print(head)
    medians, maps = {}, {}
    with one_thread():
        for name, cam, o, fr in runs:
            t0 = time.perf_counter()
            res = map_markers(fr, cam, o)
            total = time.perf_counter() - t0
            e = map_errors(res, true_corners, true_centres)
            medians[name] = e["median_mm"]
            maps[name] = _map_through_file(res)
            delay = 100 * (res.line_delay / camera.line_delay - 1)
            stages = ", ".join(f"{k} {v:.1f}" for k, v in res.timings.items() if k != "total")
            print(
                f"{name:24s} {len(res.corners):6d} {e['median_mm']:7.1f} {e['max_mm']:7.1f} "
                f"{e['aligned_median_mm']:7.1f} {e['aligned_max_mm']:7.1f} "
                f"{e['std_median_mm']:6.1f} {100 * e['honest']:5.0f}% {res.rmse_px:7.2f} "
                f"{delay:+7.2f} {res.corner_offset_px:+7.3f} {total:7.1f}  {stages}"
            )
            if res.unmapped:
                print(f"{'':24s} left out: {res.unmapped}")
            if res.inconsistent:
                print(f"{'':24s} left out as seen at two places: {sorted(res.inconsistent)}")
        ratio = medians["global shutter"] / medians["rolling shutter"]
        print(f"global shutter / rolling shutter median corner error: {ratio:.1f}x")

        dets, truth = drive_detections(
            room, camera, args.drive_frames, seed=args.seed + 7, corner_bias_px=args.corner_bias
        )
        print(
            f"\nlocalization of a second video ({args.drive_frames} frames, a robot driving a "
            "loop at 0.4 m), r6p_1lin frame by frame, default options, medians against the "
            "truth; 'vs true map': ratio to the same frames against the true map"
        )
        print(
            f"{'map':24s} {'frames':>6s} {'solved':>6s} {'rot deg':>8s} {'pos cm':>7s} "
            f"{'vs true map':>12s}  not solved"
        )
        ref = None
        for name, corners in [("true map", true_corners), *maps.items()]:
            r = localization_errors(dets, truth, corners, camera)
            if ref is None:
                ref = r
            ratio = (
                f"{r['rotation_deg'] / ref['rotation_deg']:.2f}x"
                f" {r['position_cm'] / ref['position_cm']:.2f}x"
            )
            print(
                f"{name:24s} {r['frames']:6d} {r['solved']:6d} {r['rotation_deg']:8.3f} "
                f"{r['position_cm']:7.2f} {ratio:>12s}  {dict(r['failed'])}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
