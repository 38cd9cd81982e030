"""``rs-localizer map-markers``: a marker map from a rolling-shutter video (folder of images).

Detects the markers in every image, builds the map with the rolling-shutter bundle adjustment
(:func:`rs_localizer.mapping.marker_ba.map_markers`) and writes it in the marker-map format the
ArUco front end and the node's ``frontend_map`` read. The world frame is the anchor marker's
(x right, y up on its face, z out of it, origin at its centre) or ``--anchor-pose``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

__all__ = ["parse_sizes", "register", "run"]


def parse_sizes(text: str) -> dict:
    """``"12:0.30,14:0.1"`` -> {12: 0.30, 14: 0.1}. Raises ValueError on a malformed entry."""
    out = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        mid, sep, size = part.partition(":")
        try:
            if not sep:
                raise ValueError
            out[int(mid)] = float(size)
        except ValueError:
            raise ValueError(f"--marker-sizes: expected ID:SIZE, got {part!r}") from None
    return out


def run(args: argparse.Namespace) -> int:
    """Run the command (see :func:`register`); returns 0.

    Raises:
        FileExistsError: the output exists without ``--overwrite``. FileNotFoundError: no
        input folder, images or camera file. ValueError: bad sizes, dictionary, images of
        another size, no detections, anchor not in view (see ``map_markers``).
    """
    from scipy.spatial.transform import Rotation

    from ..mapping.marker_ba import MappingOptions, map_markers
    from ..mapping.outputs import camera_from_yaml, detect_folder, write_map, write_report

    out = Path(args.output)
    if out.exists() and not args.overwrite:
        raise FileExistsError(f"{out} exists (use --overwrite to replace it)")
    if not args.marker_size > 0:
        raise ValueError(f"--marker-size must be > 0, got {args.marker_size}")
    if args.readout_time < 0:
        raise ValueError(f"--readout-time must be >= 0, got {args.readout_time}")
    if args.camera is None:
        raise ValueError("a folder of images needs --camera CAMERA.yaml (ROS camera_info)")
    probe = camera_from_yaml(args.camera)
    camera = camera_from_yaml(args.camera, line_delay=args.readout_time / probe.lines)
    if not Path(args.input).is_dir():
        raise FileNotFoundError(
            f"{args.input}: not a folder of images (bags are not read by this command)"
        )
    t0 = time.perf_counter()
    frames, counts = detect_folder(
        args.input, camera, args.dictionary, args.fps, progress=not args.quiet
    )
    t_detect = time.perf_counter() - t0
    anchor_pose = None
    if args.anchor_pose is not None:
        v = np.asarray(args.anchor_pose, dtype=float)
        anchor_pose = (Rotation.from_quat(v[3:]).as_matrix(), v[:3])
    opts = MappingOptions(
        marker_size=args.marker_size,
        marker_sizes=parse_sizes(args.marker_sizes or ""),
        anchor=args.anchor,
        anchor_pose=anchor_pose,
        global_shutter=args.global_shutter,
        calibrate_readout=args.calibrate_readout,
    )
    result = map_markers(frames, camera, opts)
    result.timings["detection"] = t_detect
    write_map(out, result, args.dictionary, overwrite=args.overwrite)
    if args.report:
        write_report(args.report, result, counts)
    if not args.quiet:
        print(
            f"{out}: {len(result.corners)} markers (anchor {result.anchor}) from "
            f"{counts['images']} images ({counts['without_markers']} without markers, "
            f"{result.num_frames_skipped} without a pose); reprojection RMSE "
            f"{result.rmse_px:.2f} px, {result.num_rejected} detections rejected, line delay "
            f"{1e6 * result.line_delay:.2f} us"
        )
        for m, why in sorted(result.unmapped.items()):
            print(f"  marker {m} left out: {why}")
        for m, ps in sorted(result.inconsistent.items()):
            where = " and ".join(np.array2string(p, precision=2) for p in ps)
            print(f"  marker {m} left out: detected at places that disagree ({where})")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``map-markers`` subcommand to ``sub`` (sets ``func``)."""
    p = sub.add_parser(
        "map-markers",
        help="build a marker map from a rolling-shutter video (folder of images)",
        description=__doc__,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("input", help="folder of images (sorted by name, one frame each)")
    p.add_argument("-o", "--output", required=True, help="marker map YAML to write")
    p.add_argument("--camera", help="camera YAML (ROS camera_info / camera_calibration)")
    p.add_argument("--marker-size", type=float, required=True, help="marker side (m)")
    p.add_argument("--marker-sizes", help="other sides, ID:SIZE,... (m)")
    p.add_argument("--dictionary", default="DICT_APRILTAG_36h11", help="OpenCV dictionary")
    p.add_argument("--anchor", type=int, help="marker fixing the world (default: lowest id)")
    p.add_argument(
        "--anchor-pose",
        type=float,
        nargs=7,
        metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
        help="the anchor's centre (m) and orientation (marker -> world) in the world",
    )
    p.add_argument("--readout-time", type=float, default=0.03, help="frame readout time (s)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the images (Hz)")
    p.add_argument(
        "--calibrate-readout",
        action="store_true",
        help="estimate the line delay (starting from --readout-time)",
    )
    p.add_argument(
        "--global-shutter", action="store_true", help="global-shutter model (no velocities)"
    )
    p.add_argument("--report", help="folder for report.yaml and map.png")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    p.set_defaults(func=run)
