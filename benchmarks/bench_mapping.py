"""Marker maps from rolling-shutter videos: ``python -m benchmarks.bench_mapping``.

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

    python -m benchmarks.bench_mapping [--frames 240] [--anchor-frames 60]
        [--spot-frames 150] [--map-drive-frames 300] [--markers 30] [--seed 0]
        [--drive-frames 300] [--corner-bias 0.19] [--view-error 0.3]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from rs_localizer.experiments.timing import one_thread
from rs_localizer.mapping import (
    FrameDetections,
    MappingOptions,
    concatenate_videos,
    map_markers,
)
from rs_localizer.sim.marker_mapping import (
    corner_sigmas,
    drive_detections,
    frame_errors,
    localization_errors,
    map_errors,
    map_through_file,
    room_scene,
    same_video_but_readout,
    truth_in_frame,
)
from rs_localizer.sim.marker_room import (
    OneSpot,
    make_marker_room,
    room_camera,
    simulate_detections,
)

__all__ = ["main", "paired_ratios"]


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
        prog="python -m benchmarks.bench_mapping",
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
                maps[vname] = map_through_file(built[(vname, "anchor 0")])
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
        maps["merged"] = map_through_file(merged)

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
            rows.append(("walk, no readout (floor)", map_through_file(floor_walk), None, None))
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
