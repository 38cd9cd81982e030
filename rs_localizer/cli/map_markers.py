"""``rs-localizer map-markers``: a marker map from a rolling-shutter video (a bag, or a folder
of images with a camera YAML).

Detects the markers in every image, builds the map with the rolling-shutter bundle adjustment
(:func:`rs_localizer.mapping.marker_map.map_markers`) and writes it in the marker-map format the
ArUco front end and the node's ``frontend_map`` read. The world frame is gravity-aligned
(REP 105: z up) from the first of the bag's accelerometer, markers on two or more walls, a floor
marker that the video offers, with its origin at the anchor's centre and x out of its wall (y
left, z up); or, with ``--anchor``/``--anchor-pose``/``--frame anchor``, the anchor marker's own
frame (x right, y up on its face, z out of it) or ``--anchor-pose``. Exit code 3: a video was
refused as another place, the map written from the other videos.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import args as A

__all__ = [
    "coverage_lines",
    "frames_from_bag",
    "parse_sizes",
    "register",
    "run",
    "up_from_imu",
]

#: the accelerometer's samples count as still-ish within this rate (rad/s; 2 rad/s turns 5 cm
#: from the IMU make 0.2 m/s^2) and this far from
#: 1 g (m/s^2); a frame's up is their mean within ``UP_WINDOW`` s of its stamp
STILL_RATE, STILL_ACCEL, UP_WINDOW = 2.0, 1.5, 0.25
GRAVITY = 9.81


def parse_sizes(text: str) -> dict:
    """``--marker-sizes``: ``"12:0.30,14:0.1"``, id ranges ``"0-9:0.165,10-52:0.1"`` or a YAML
    file of them -> {id: side (m)} (:func:`~rs_localizer.cli.args.parse_marker_sizes`).
    Raises ValueError on a malformed entry, an id given twice or a size that is not a finite
    number > 0."""
    return A.parse_marker_sizes(text)


def frames_from_bag(
    path: str | Path,
    image_topic: str | None,
    dictionary: str,
    readout_time: float,
    progress: bool = True,
    detector_options: object = None,
) -> tuple:
    """Marker detections of a bag's images (rosbags, no ROS installation needed), with the
    marker detector of ``dictionary`` and ``detector_options``
    (:class:`~rs_localizer.frontends.marker_detection.DetectorOptions`; None: its defaults).

    The camera is the first ``camera_info`` of the bag (K, D, binning and ROI;
    :func:`rs_localizer.ros.conversions.camera_model_from_camera_info`) with ``readout_time``
    seconds per frame; the images are ``sensor_msgs/Image`` or ``CompressedImage`` on
    ``image_topic`` (default: the bag's only image topic). A header stamp is the capture time
    of the line ``rs.stamp_row`` of the bag's ``sequence.json`` (default 0, the first line).

    Returns:
        ``(camera, frames, counts)`` as :func:`rs_localizer.mapping.outputs.detect_folder`.
    Raises:
        FileNotFoundError: not a bag directory. ValueError: no image topic (naming the bag's
        topics), several image topics without ``image_topic``, no camera_info, an image of
        another size than the camera, an undecodable image.
    """
    from ..frontends import ArucoFrontend
    from ..frontends.image import to_gray
    from ..mapping import FrameDetections
    from ..mapping.outputs import detect_image
    from ..ros import conversions as cv
    from ..ros.bags.bag_io import (
        CAMERA_INFO,
        COMPRESSED_IMAGE,
        IMAGE,
        bag_topics,
        first_message,
        iter_messages,
        read_bag_info,
        typestore,
    )
    from ..ros.image_codec import decode_image

    path = Path(path)
    if not (path / "metadata.yaml").exists():
        raise FileNotFoundError(f"{path}: neither a folder of images nor a bag (no metadata.yaml)")
    topics = bag_topics(path)
    images = sorted(t for t, mt in topics.items() if mt in (IMAGE, COMPRESSED_IMAGE))
    if not images:
        have = ", ".join(f"{t} ({mt})" for t, mt in sorted(topics.items())) or "none"
        raise ValueError(
            f"{path}: the bag has no image topic (sensor_msgs/Image or CompressedImage) to "
            f"detect markers in; its topics: {have}"
        )
    if image_topic is None:
        if len(images) != 1:
            raise ValueError(f"{path}: image topics {images}: choose one with --image-topic")
        image_topic = images[0]
    elif image_topic not in images:
        raise ValueError(f"{path}: no image topic {image_topic!r} (image topics: {images})")
    infos = sorted(t for t, mt in topics.items() if mt == CAMERA_INFO)
    if not infos:
        raise ValueError(f"{path}: no camera_info topic")
    ns = image_topic.rsplit("/", 1)[0]
    info_topic = next((t for t in infos if t.rsplit("/", 1)[0] == ns), infos[0])
    info = first_message(path, {info_topic})
    if info is None:
        raise ValueError(f"{path}: no camera_info message on {info_topic}")
    camera = cv.camera_model_from_camera_info(info, readout_time=readout_time)
    stamp_row = float(read_bag_info(path).get("rs", {}).get("stamp_row", 0.0))
    offset = float(camera.line_time(camera.reference_line) - camera.line_time(stamp_row))
    front = ArucoFrontend({}, dictionary, detector_options=detector_options)
    frames, counts = [], {"images": 0, "without_markers": 0, "duplicate_ids": 0}
    ts = typestore()
    msgs = iter_messages(path, {image_topic})
    if progress:
        from tqdm import tqdm

        msgs = tqdm(msgs, desc="detecting markers")
    for _, msgtype, _, raw in msgs:
        msg = ts.deserialize_cdr(raw, msgtype)
        img, enc = decode_image(msg, min_side=0)
        gray = to_gray(img, enc)
        if gray.shape != (camera.height, camera.width):
            raise ValueError(
                f"{path}: image is {gray.shape[1]}x{gray.shape[0]}, the camera "
                f"{camera.width}x{camera.height}"
            )
        dets, dup = detect_image(front, gray)
        counts["images"] += 1
        counts["duplicate_ids"] += dup
        counts["without_markers"] += not dets
        stamp = cv.stamp_to_ns(msg.header.stamp) * 1e-9 + offset
        frames.append(FrameDetections(stamp, dets))
    frames.sort(key=lambda f: f.stamp)
    return camera, frames, counts


def up_from_imu(
    path: str | Path,
    stamps: np.ndarray,
    imu_topic: str | None = None,
    R_cam_imu: np.ndarray | None = None,
) -> tuple[dict, str]:
    """Up in the camera's optical frame at the frames of a bag, from its ``sensor_msgs/Imu``
    accelerometer: the mean specific force (up when still: the accelerometer feels the
    floor's push, not gravity) of the samples within ``UP_WINDOW`` s of a frame's stamp that
    are still-ish (rate below ``STILL_RATE``, magnitude within ``STILL_ACCEL`` of 1 g),
    rotated by the camera-IMU mounting ``R_cam_imu`` (IMU -> camera; default: the bag's
    ``sequence.json`` ``imu.rotation_imu_from_camera``, transposed).

    Args:
        path: the bag directory. stamps: (N,) the frames' stamps (s, the bag's clock).
        imu_topic: the IMU topic (default: the bag's only one).
    Returns:
        ``(up, why)``: frame index -> (3,) unit up, camera frame (frames without still
        samples left out), and why it is empty (no IMU, mounting unknown, never still).
    """
    from ..ros.bags.bag_io import IMU, bag_topics, iter_messages, read_bag_info, typestore

    path = Path(path)
    if not (path / "metadata.yaml").exists():
        return {}, "not a bag (no IMU)"
    imus = sorted(t for t, mt in bag_topics(path).items() if mt == IMU)
    if not imus:
        return {}, "the bag has no sensor_msgs/Imu"
    if imu_topic is None:
        if len(imus) != 1:
            return {}, f"IMU topics {imus}: choose one with --imu-topic"
        imu_topic = imus[0]
    elif imu_topic not in imus:
        return {}, f"no IMU topic {imu_topic!r} (IMU topics: {imus})"
    if R_cam_imu is None:
        R_ic = read_bag_info(path).get("imu", {}).get("rotation_imu_from_camera")
        if R_ic is None:
            return {}, (
                "the IMU's mounting is unknown: give --imu-rotation QX QY QZ QW (the node's "
                "imu.rotation, IMU -> camera)"
            )
        R_cam_imu = np.asarray(R_ic, float).reshape(3, 3).T
    ts = typestore()
    t, w, f = [], [], []
    for _, msgtype, _, raw in iter_messages(path, {imu_topic}):
        m = ts.deserialize_cdr(raw, msgtype)
        t.append(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec)
        w.append([m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z])
        a = m.linear_acceleration
        f.append([a.x, a.y, a.z])
    if not t:
        return {}, f"no messages on {imu_topic}"
    t, w, f = np.array(t), np.array(w), np.array(f)
    still = (np.linalg.norm(w, axis=1) < STILL_RATE) & (
        np.abs(np.linalg.norm(f, axis=1) - GRAVITY) < STILL_ACCEL
    )
    out = {}
    for k, s in enumerate(np.asarray(stamps, float)):
        sel = still & (np.abs(t - s) < UP_WINDOW)
        if sel.sum() >= 3:
            u = np.asarray(R_cam_imu) @ f[sel].mean(0)
            out[k] = u / np.linalg.norm(u)
    return out, "" if out else "the IMU is never still-ish near a frame"


def _detect(src: Path, args: argparse.Namespace) -> tuple:
    """``(camera, frames, counts)`` of one input (a bag, or a folder of images with
    ``--camera``)."""
    from ..mapping.outputs import camera_from_yaml, detect_folder

    if (src / "metadata.yaml").exists():
        return frames_from_bag(
            src,
            args.image_topic,
            args.dictionary,
            args.readout_time,
            progress=not args.quiet,
            detector_options=_detector_options(args),
        )
    if not src.is_dir():
        raise FileNotFoundError(f"{src}: neither a folder of images nor a bag")
    if args.camera_file is None:
        raise ValueError("a folder of images needs --camera CAMERA.yaml (ROS camera_info)")
    probe = camera_from_yaml(args.camera_file)
    camera = camera_from_yaml(args.camera_file, line_delay=args.readout_time / probe.lines)
    frames, counts = detect_folder(
        src,
        camera,
        args.dictionary,
        args.fps,
        progress=not args.quiet,
        detector_options=_detector_options(args),
    )
    return camera, frames, counts


def _detector_options(args: argparse.Namespace):
    """The marker detector's options from the command line
    (:class:`~rs_localizer.frontends.marker_detection.DetectorOptions`)."""
    from ..frontends.marker_detection import DetectorOptions

    return DetectorOptions(
        detector=args.detector,
        quad_decimate=args.quad_decimate,
        nthreads=args.nthreads,
        quad_sigma=args.quad_sigma,
        refine_edges=not args.no_refine_edges,
        decode_sharpening=args.decode_sharpening,
        max_hamming=args.max_hamming,
        min_decision_margin=args.min_decision_margin,
    )


def _options(args: argparse.Namespace):
    """:class:`MappingOptions` from the command line. Raises ValueError on a surveyed-marker
    file without markers, or ``--anchor`` with ``--survey``."""
    from scipy.spatial.transform import Rotation

    from ..mapping import MappingOptions

    anchor_pose, anchors = None, None
    if args.anchor_pose is not None:
        v = np.asarray(args.anchor_pose, dtype=float)
        anchor_pose = (Rotation.from_quat(v[3:]).as_matrix(), v[:3])
    if getattr(args, "survey", None):
        from ..maps import load_marker_map

        if args.anchor is not None or anchor_pose is not None:
            raise ValueError("--survey fixes the frame by its markers: drop --anchor/--anchor-pose")
        _, anchors = load_marker_map(args.survey)
        if not anchors:
            raise ValueError(f"{args.survey}: no markers")
    frame = args.frame
    explicit = args.anchor is not None or anchor_pose is not None or anchors is not None
    if frame is None:
        frame = "anchor" if explicit else "auto"
    frame = {"gravity": "auto"}.get(frame, frame)
    if frame != "anchor" and (anchor_pose is not None or anchors is not None):
        raise ValueError(
            f"--frame {args.frame}: --anchor-pose and --survey give the frame themselves"
        )
    return MappingOptions(
        marker_size=args.marker_size,
        marker_sizes=parse_sizes(args.marker_sizes or ""),
        anchor=args.anchor,
        anchor_pose=anchor_pose,
        anchors=anchors,
        global_shutter=args.global_shutter,
        calibrate_readout=args.calibrate_readout,
        corner_offset=not args.no_corner_offset,
        coverage_std=args.coverage_std / 1000.0,
        frame=frame,
        floor_markers=tuple(int(m) for m in (args.floor_markers or "").split(",") if m.strip()),
    )


def _offset_note(result) -> str:
    """The corner offset's std, and whether the detector needs the term: not when the offset
    found is within 2 std of zero and the video fixes it to 0.025 px (std) or better."""
    co, std = result.corner_offset_px, result.corner_offset_std_px
    if not np.isfinite(std):
        return ""
    note = f" (std {std:.2f} px)"
    if abs(co) <= 2 * std and std <= 0.025:
        note += (
            "; no offset within its std: this detector's corners need no corner-offset term "
            "(--no-corner-offset)"
        )
    return note


def _summary(out: Path, result, counts: dict, opts, lines: int | None = None) -> list:
    """The lines the command prints about a map: size, fit, the frame and its uncertainty
    (with a warning naming the remedy above the bounds), markers left out and the markers
    whose stated std exceeds ``--coverage-std`` with what would help."""
    from ..mapping.outputs import readout_line

    f = result.frame
    what = {
        "gravity": f"gravity-aligned (z up), origin at marker {f.anchors[0]}'s centre, x out "
        "of its wall, y left",
        "best-observed": "the best-observed marker's own frame (z out of its face)",
        "anchor": "the anchor's own frame (z out of its face)"
        if opts.anchor_pose is None
        else "the anchor at --anchor-pose",
        "surveyed": "the best fit to the surveyed markers",
    }.get(f.kind, f.kind)
    lines = [
        f"{out}: {len(result.corners)} markers from {counts['images']} images "
        f"({counts['without_markers']} without markers, {result.num_frames_skipped} without a "
        f"pose); reprojection RMSE {result.rmse_px:.2f} px, {result.num_rejected} detections "
        f"rejected, detected corners {result.corner_offset_px:+.2f} px inside the markers"
        + _offset_note(result),
        f"  {readout_line(result, lines)}",
        f"  map frame: {what}" + (f"; {f.note}" if f.note else ""),
        f"  frame: {f.kind} ({', '.join(map(str, f.anchors))}"
        + (f", residual {f.residual_mm:.1f} mm RMS" if f.kind == "surveyed" else "")
        + f"); its own uncertainty against the map as a whole: {f.rotation_std_deg:.2f} deg, "
        f"{f.position_std_mm:.0f} mm (std, largest axis); marker std in the map frame: median "
        f"{1e3 * np.median([s[3:].max() for s in result.marker_std.values()]):.1f} mm",
    ]
    if f.rotation_std_deg > opts.max_frame_rotation_deg or (
        f.position_std_mm > opts.max_frame_position_mm
    ):
        lever = _lever_arm(result, f)
        lines.append(
            f"  WARNING: the frame is poorly fixed ({f.rotation_std_deg:.2f} deg, "
            f"{f.position_std_mm:.0f} mm){lever}: every marker far from "
            f"{'the anchor' if f.kind != 'surveyed' else 'the surveyed markers'} inherits it. "
            "Look at the anchor from closer and from several directions, or fix the frame by "
            "a better-observed marker (leave out --anchor) or by several surveyed markers "
            "(--survey MARKERS.yaml)"
            + (
                ". At several degrees the stated marker precision, a linearization, "
                "understates the turn: do not rely on this frame"
                if f.rotation_std_deg > 5.0
                else ""
            )
        )
    lines += coverage_lines(result.coverage, opts.coverage_std)
    for m, why in sorted(result.unmapped.items()):
        lines.append(f"  marker {m} left out: {why}")
    for m, ps in sorted(result.inconsistent.items()):
        where = " and ".join(np.array2string(p, precision=2) for p in ps)
        lines.append(f"  marker {m} left out: detected at places that disagree ({where})")
    return lines


def coverage_lines(coverage: dict, bound_m: float) -> list:
    """One line per reason for the markers whose stated std exceeds ``bound_m`` (m):
    ``coverage`` is ``MarkerMapResult.coverage`` (id -> ``std N mm: reason, reason (...);
    remedy``); the markers of each reason listed with their std range (the report keeps
    each marker's details)."""
    import re

    if not coverage:
        return []
    kinds: dict = {}
    stds = {}
    for m, why in coverage.items():
        head, _, rest = why.partition(": ")
        stds[m] = float(head.split()[1]) if head.startswith("std ") else float("nan")
        reasons = re.sub(r"\s*\([^)]*\)", "", rest.split(";")[0])
        for r in reasons.split(", "):
            r = re.sub(r"^seen in \d+ frames$", "seen in fewer than 10 frames", r.strip())
            kinds.setdefault(r, []).append(m)
    out = [
        f"  {len(coverage)} markers above --coverage-std {1e3 * bound_m:.0f} mm; views from "
        "closer and at an angle would fix them (each marker's reasons: --report):"
    ]
    for r, ms in sorted(kinds.items(), key=lambda kv: -len(kv[1])):
        v = [stds[m] for m in ms]
        out.append(
            f"    {r}: {len(ms)} markers, std {min(v):.0f}-{max(v):.0f} mm: "
            + ", ".join(str(m) for m in sorted(ms))
        )
    return out


def _lever_arm(result, f) -> str:
    """The part of the frame's position std that is its rotation std acting over the distance
    from the anchor to the map's origin (``--anchor-pose`` far from the origin), said in words;
    "" when the origin is near the anchor."""
    if f.kind != "anchor" or result.anchor not in result.marker_poses:
        return ""
    d = float(np.linalg.norm(result.marker_poses[result.anchor][1]))
    arm = np.radians(f.rotation_std_deg) * d * 1e3
    if d < 0.5 or arm < 0.3 * f.position_std_mm:
        return ""
    return (
        f"; of the {f.position_std_mm:.0f} mm, about {arm:.0f} mm is the frame's rotation "
        f"uncertainty acting over the {d:.1f} m from the anchor to the map's origin (a lever "
        "arm: the origin is fixed by the anchor's tilt, not only its position; markers near "
        "the anchor do not inherit it)"
    )


#: the exit code when a video was refused (another place) and the map written from the others
EXIT_REFUSED_VIDEO = 3


def run(args: argparse.Namespace) -> int:
    """Run the command (see :func:`register`); returns 0, or ``EXIT_REFUSED_VIDEO`` (3) when
    a video was refused as another place and the map written from the other videos.

    Raises:
        FileExistsError: the output exists without ``--overwrite``. FileNotFoundError: no
        input folder, images or camera file. ValueError: bad sizes, dictionary, images of
        another size, no detections, anchor not in view, surveyed markers that disagree with
        the video, a video of another place (see ``map_markers``).
    """
    from ..mapping import concatenate_videos, map_markers
    from ..mapping.outputs import readout_line, write_map, write_report

    out = A.output_file(args.output, args.overwrite, "marker map")
    if args.report:
        A.writable_dir(args.report, "report folder")
    if args.anchor_pose is not None and not np.linalg.norm(args.anchor_pose[3:]) > 1e-9:
        raise A.CliError("--anchor-pose: the quaternion QX QY QZ QW must not be zero")
    opts = _options(args)
    from ..frontends.marker_detection import make_marker_detector

    # (an unknown dictionary or a missing AprilTag library, before any work)
    detector = make_marker_detector(args.dictionary, _detector_options(args))
    if not args.quiet:
        print(f"marker detector: {detector.describe()}")
    inputs = args.input if isinstance(args.input, list) else [args.input]
    # (every input checked before any detection)
    inputs = [A.map_input(src, args.camera_file) for src in inputs]
    for src in inputs:
        if not Path(src).is_dir():
            raise FileNotFoundError(f"{src}: neither a folder of images nor a bag")
    t0 = time.perf_counter()
    detected = [_detect(Path(src), args) for src in inputs]
    camera = detected[0][0]
    for src, (cam, _, _) in zip(inputs, detected, strict=True):
        if (cam.width, cam.height) != (camera.width, camera.height) or not np.allclose(
            cam.K, camera.K
        ):
            raise ValueError(f"{src}: another camera than {inputs[0]}'s: map one camera at a time")
    frames = concatenate_videos([d[1] for d in detected])
    videos = [i for i, d in enumerate(detected) for _ in d[1]]
    counts = {k: sum(d[2][k] for d in detected) for k in detected[0][2]}
    t_detect = time.perf_counter() - t0
    up_in_camera, imu_note = None, ""
    if opts.frame in ("auto", "imu"):
        R_ci = None
        if args.imu_rotation is not None:
            from scipy.spatial.transform import Rotation

            R_ci = Rotation.from_quat(np.asarray(args.imu_rotation, float)).as_matrix()
        up_in_camera, off, notes = {}, 0, []
        for src, d in zip(inputs, detected, strict=True):
            ups, why = up_from_imu(src, np.array([fr.stamp for fr in d[1]]), args.imu_topic, R_ci)
            up_in_camera.update({off + k: u for k, u in ups.items()})
            off += len(d[1])
            if why:
                notes.append(f"{src}: {why}")
        imu_note = "; ".join(notes)
        if opts.frame == "imu" and not up_in_camera:
            raise ValueError(f"--frame imu: {imu_note}")
    several = len(inputs) > 1
    result = map_markers(
        frames,
        camera,
        opts,
        progress=not args.quiet,
        videos=videos if several else None,
        video_names=[str(src) for src in inputs] if several else None,
        up_in_camera=up_in_camera or None,
    )
    result.timings["detection"] = t_detect
    if imu_note and result.frame is not None and result.frame.up_source != "imu":
        result.frame.note = (result.frame.note + "; " if result.frame.note else "") + (
            f"accelerometer not used ({imu_note})"
        )
    for why in result.refused_videos.values():  # (the map is built from the other videos)
        print(f"WARNING: {why}", file=sys.stderr)
    singles = []
    if several and not args.quiet:  # precision of each video alone, for the report
        for v, d in enumerate(detected):
            if v in result.refused_videos:
                singles.append("refused, see above")
                continue
            try:
                singles.append(map_markers(d[1], camera, opts))
            except ValueError as e:
                singles.append(str(e))
    write_map(out, result, args.dictionary, overwrite=args.overwrite, lines=camera.lines)
    if args.report:
        write_report(args.report, result, counts)
    if args.quiet and opts.calibrate_readout:  # (the value asked for, even under --quiet)
        print(readout_line(result, camera.lines))
    if not args.quiet:
        print("\n".join(_summary(out, result, counts, opts, camera.lines)))
        for src, single in zip(inputs, singles, strict=False):
            if isinstance(single, str):
                print(f"  {src} alone: no map ({single})")
                continue
            common = sorted(set(single.marker_std) & set(result.marker_std))
            before = np.median([single.marker_std[m][3:].max() for m in common])
            after = np.median([result.marker_std[m][3:].max() for m in common])
            print(
                f"  {src} alone: {len(single.corners)} markers; median std of the markers it "
                f"maps {1e3 * before:.1f} mm alone, {1e3 * after:.1f} mm with all videos"
            )
    if result.refused_videos:  # (said even under --quiet, and in the exit code)
        print(
            f"{out}: written from {len(inputs) - len(result.refused_videos)} of the "
            f"{len(inputs)} videos, {len(result.refused_videos)} refused (exit code "
            f"{EXIT_REFUSED_VIDEO})",
            file=sys.stderr,
        )
        return EXIT_REFUSED_VIDEO
    return 0


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``map-markers`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    p = sub.add_parser(
        "map-markers",
        help="build a marker map from a rolling-shutter video (a bag or a folder of images)",
        description=__doc__,
        formatter_class=A.HelpFormatter,
    )
    p.add_argument(
        "input",
        nargs="+",
        help="bag directory, or folder of images (sorted by name, one frame each); several: "
        "videos of one place adjusted together into one map",
    )
    p.add_argument("-o", "--output", required=True, help="marker map YAML to write")
    p.add_argument(
        "--camera",
        dest="camera_file",
        help="camera YAML for a folder of images (ROS camera_info / calibration)",
    )
    p.add_argument("--image-topic", help="image topic of a bag (default: its only one)")
    p.add_argument("--marker-size", type=A.positive_float, required=True, help="marker side (m)")
    p.add_argument(
        "--marker-sizes",
        help="other sides: ID:SIZE or FIRST-LAST:SIZE, comma-separated, or a YAML file of them (m)",
    )
    p.add_argument("--dictionary", default="DICT_APRILTAG_36h11", help="OpenCV dictionary")
    p.add_argument(
        "--anchor",
        type=A.nonneg_int,
        help="marker fixing the world (default: the best-observed marker, whose pose the "
        "video fixes best)",
    )
    p.add_argument(
        "--anchor-pose",
        type=A.finite_float,
        nargs=7,
        metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
        help="the anchor's centre (m) and orientation (marker -> world) in the world",
    )
    p.add_argument(
        "--frame",
        choices=("gravity", "auto", "anchor", "imu", "walls", "floor"),
        help="the map's frame: gravity (= auto: z up from the first of the bag's "
        "accelerometer, markers on two or more walls, a floor marker; origin at the anchor's "
        "centre, x out of its wall, y left; the default without --anchor, --anchor-pose or "
        "--survey), one of those sources only (imu, walls, floor), or anchor (the anchor's "
        "own frame, z out of its face; the default with --anchor)",
    )
    p.add_argument(
        "--floor-markers", metavar="ID,...", help="markers lying on the floor (up: their normal)"
    )
    p.add_argument("--imu-topic", help="the bag's sensor_msgs/Imu topic (default: its only one)")
    p.add_argument(
        "--imu-rotation",
        type=A.finite_float,
        nargs=4,
        metavar=("QX", "QY", "QZ", "QW"),
        help="IMU -> camera optical frame rotation (the node's imu.rotation; default: the "
        "bag's sequence.json)",
    )
    p.add_argument(
        "--readout-time", type=A.nonneg_float, default=0.03, help="frame readout time (s)"
    )
    p.add_argument(
        "--fps", type=A.positive_float, default=30.0, help="frame rate of a folder of images"
    )
    p.add_argument(
        "--calibrate-readout",
        action="store_true",
        help="estimate the line delay (starting from --readout-time)",
    )
    p.add_argument(
        "--global-shutter", action="store_true", help="global-shutter model (no velocities)"
    )
    p.add_argument(
        "--no-corner-offset",
        action="store_true",
        help="do not estimate the detector's corner offset (corners inside the markers' "
        "squares along the diagonals, e.g. by the subpixel refinement of blurred corners)",
    )
    p.add_argument(
        "--survey",
        metavar="MARKERS.yaml",
        help="marker map of surveyed markers (their corners in your frame): the map's frame is "
        "the best fit of these markers (instead of --anchor)",
    )
    p.add_argument(
        "--coverage-std",
        type=float,
        default=10.0,
        help="mm: name the markers whose stated position std exceeds this, with what would help",
    )
    p.add_argument("--report", help="folder for report.yaml and map.png")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    _add_detector_arguments(p)
    p.set_defaults(func=run)
    return p


def _add_detector_arguments(p: argparse.ArgumentParser) -> None:
    """The marker detector's flags (the AprilTag library's option names)."""
    from ..frontends.marker_detection import DETECTOR_BACKENDS, DetectorOptions

    d = DetectorOptions()
    g = p.add_argument_group(
        "marker detector",
        "AprilTag families with the AprilTag 3 library, ArUco dictionaries with OpenCV",
    )
    g.add_argument(
        "--detector",
        choices=DETECTOR_BACKENDS,
        default=d.detector,
        help="auto: the AprilTag library for AprilTag families when installed (else OpenCV, "
        "saying so); apriltag: require it; opencv: OpenCV's ArUco detector for every dictionary",
    )
    g.add_argument(
        "--quad-decimate",
        type=A.nonneg_float,
        default=d.quad_decimate,
        help="AprilTag: find quads on the image decimated by this factor (1, 1.5 or an "
        "integer; 1: full resolution, finds smaller tags, slower; 0: by image size, 1.5 up to "
        "640x480, 2 above)",
    )
    g.add_argument(
        "--nthreads",
        type=A.positive_int,
        default=d.nthreads,
        help="AprilTag: detector threads (the library before 3.4.3 may crash at its first "
        "detection with more than one)",
    )
    g.add_argument(
        "--quad-sigma",
        type=A.nonneg_float,
        default=d.quad_sigma,
        help="AprilTag: Gaussian blur (px std) before finding quads (noisy images: 0.8)",
    )
    g.add_argument(
        "--no-refine-edges",
        action="store_true",
        help="AprilTag: do not snap the quad edges to the image gradients",
    )
    g.add_argument(
        "--decode-sharpening",
        type=A.nonneg_float,
        default=d.decode_sharpening,
        help="AprilTag: sharpening of the decoded samples",
    )
    g.add_argument(
        "--max-hamming",
        type=int,
        choices=(0, 1, 2),
        default=d.max_hamming,
        help="AprilTag: most corrected bits of a kept tag",
    )
    g.add_argument(
        "--min-decision-margin",
        type=A.nonneg_float,
        default=d.min_decision_margin,
        help="AprilTag: smallest decision margin of a kept tag (default: the binding's)",
    )
