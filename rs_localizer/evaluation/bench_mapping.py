"""Marker maps from a rolling-shutter video: ``python -m rs_localizer.evaluation.bench_mapping``.

The scene (:mod:`rs_localizer.sim.marker_room`): a 4.5 x 4 x 2.6 m room with 28 markers of
0.12-0.30 m (marker 0, 0.30 m, is the anchor; one on the floor, a third tilted out of their
wall), a hand-held walk that turns once around in 5 s (angular speed up to ~2.2 rad/s), 640x480,
f = 500 px, 30 ms readout, 0.4 px corner noise, 30 fps. Corners are projected with the camera
pose at each line's own capture time (no images: detections only).

Prints, for the rolling-shutter adjustment at the true line delay, the global-shutter one on the
same detections, and the rolling-shutter one calibrating the line delay from a start 20 % off:
the marker-corner error (median, max; mm) with the gauge fixed on the anchor only (its true
pose, no best-fit alignment), the same after a best-fit rigid alignment (the map's shape), the
fraction of markers whose centre error lies within its reported 3-sigma (Mahalanobis distance
below chi2_3(0.9973) = 14.16), the reprojection RMSE, the line delay error, and the time per
stage. One BLAS thread.

    python -m rs_localizer.evaluation.bench_mapping [--frames 150] [--markers 28] [--seed 0]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..mapping.marker_ba import FrameDetections, MappingOptions, MarkerMapResult, map_markers
from ..sim.marker_room import RoomWalk, make_marker_room, room_camera, simulate_detections
from .threads import one_thread

__all__ = ["CHI2_3_3SIGMA", "main", "map_errors", "room_scene"]

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
        error is within the reported 3-sigma).
    """
    ids = sorted(result.corners)
    A = np.concatenate([result.corners[m] for m in ids])
    B = np.concatenate([true_corners[m] for m in ids])
    e = np.linalg.norm(A - B, axis=1)
    ca, cb = A.mean(0), B.mean(0)
    rot, _ = Rotation.align_vectors(B - cb, A - ca)
    ea = np.linalg.norm((A - ca) @ rot.as_matrix().T + cb - B, axis=1)
    inside = []
    for m in ids:
        if m == result.anchor:
            continue
        d = result.marker_poses[m][1] - true_centres[m]
        S = result.marker_covariance[m][3:, 3:]
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
    )


def room_scene(num_frames: int, seed: int = 0, markers: int = 28) -> tuple:
    """The benchmark's scene: a 4.5 x 4 x 2.6 m room with ``markers`` markers of mixed sizes, the
    hand-held walk around its centre seen by a 640x480 camera with a 30 ms readout, and the
    corner detections of ``num_frames`` frames (0.4 px noise; ``seed``: layout and noise).

    Returns:
        ``(room, camera, walk, frames, truth, options)``: the
        :class:`~rs_localizer.sim.marker_room.MarkerRoom`, the camera model, the
        :class:`~rs_localizer.sim.marker_room.RoomWalk`, the :class:`FrameDetections`, the
        frames' true poses and velocities (:func:`simulate_detections`) and the
        :class:`MappingOptions` with the true sizes and marker 0 as the anchor at its true pose.
    """
    room = make_marker_room(markers, seed=seed, size=(4.5, 4.0, 2.6))
    camera = room_camera(readout_time=0.03)
    walk = RoomWalk(centre=(2.25, 2.0))
    dets, truth = simulate_detections(room, camera, walk, num_frames=num_frames, seed=seed)
    frames = [FrameDetections(s, d) for s, d in dets]
    options = MappingOptions(
        marker_size=0.16,
        marker_sizes={int(i): float(s) for i, s in zip(room.ids, room.sides, strict=True)},
        anchor=0,
        anchor_pose=(room.R[0], room.p[0]),
    )
    return room, camera, walk, frames, truth, options


def main(argv: list | None = None) -> int:
    """Run the benchmark and print its table; returns 0."""
    p = argparse.ArgumentParser(
        prog="python -m rs_localizer.evaluation.bench_mapping",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--frames", type=int, default=150, help="frames at 30 fps")
    p.add_argument("--markers", type=int, default=28, help="markers in the room")
    p.add_argument("--seed", type=int, default=0, help="layout and noise seed")
    args = p.parse_args(argv)
    room, camera, walk, frames, _, opts = room_scene(args.frames, args.seed, args.markers)
    true_corners = room.corners()
    true_centres = {int(i): room.p[i] for i in room.ids}
    runs = [
        ("rolling shutter", camera, opts),
        ("global shutter", camera, replace(opts, global_shutter=True)),
        (
            "RS, calibrate readout",
            room_camera(line_delay=1.2 * camera.line_delay),
            replace(opts, calibrate_readout=True),
        ),
    ]
    n_det = sum(len(f.corners) for f in frames)
    print(
        f"{args.frames} frames, {args.markers} markers ({n_det} detections, "
        f"{walk.max_angular_rate():.1f} rad/s max), 30 ms readout, 0.4 px noise; errors in mm; "
        "one BLAS thread"
    )
    head = (
        f"{'model':24s} {'mapped':>6s} {'median':>7s} {'max':>7s} {'al.med':>7s} {'al.max':>7s} "
        f"{'3-sig':>6s} {'rmse px':>7s} {'delay %':>7s} {'time s':>7s}  stages (s)"
    )
    print(head)
    medians = {}
    with one_thread():
        for name, cam, o in runs:
            t0 = time.perf_counter()
            res = map_markers(frames, cam, o)
            total = time.perf_counter() - t0
            e = map_errors(res, true_corners, true_centres)
            medians[name] = e["median_mm"]
            delay = 100 * (res.line_delay / camera.line_delay - 1)
            stages = ", ".join(f"{k} {v:.1f}" for k, v in res.timings.items() if k != "total")
            print(
                f"{name:24s} {len(res.corners):6d} {e['median_mm']:7.1f} {e['max_mm']:7.1f} "
                f"{e['aligned_median_mm']:7.1f} {e['aligned_max_mm']:7.1f} "
                f"{100 * e['honest']:5.0f}% {res.rmse_px:7.2f} {delay:+7.2f} {total:7.1f}  "
                f"{stages}"
            )
            if res.unmapped:
                print(f"{'':24s} left out: {res.unmapped}")
            if res.inconsistent:
                print(f"{'':24s} left out as seen at two places: {sorted(res.inconsistent)}")
    ratio = medians["global shutter"] / medians["rolling shutter"]
    print(f"global shutter / rolling shutter median corner error: {ratio:.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
