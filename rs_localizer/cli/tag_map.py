"""``rs-localizer tag-map``: a marker map from tag poses (a ``{id, size, pose}`` YAML, WPILib's
field layout JSON, an ``apriltag_ros`` bundle YAML), the corners in the detector's order."""

from __future__ import annotations

import argparse

from . import args as A

__all__ = ["register", "run"]

HELP = "write a marker map from tag poses (poses YAML, WPILib field JSON, apriltag_ros bundle)"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``tag-map`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    p = sub.add_parser(
        "tag-map",
        help=HELP,
        description="Write the marker map (the node's frontend_map) of tags given by their "
        "pose: a YAML of {id, size, pose} entries, WPILib's field layout JSON or an "
        "apriltag_ros bundle YAML (docs/marker_maps.md, 'Maps from tag poses', states each "
        "format's tag frame). The corners are written in the order the detector of the "
        "dictionary returns them.",
        formatter_class=A.HelpFormatter,
    )
    p.add_argument("layout", help="the tag layout (YAML or JSON)")
    p.add_argument("-o", "--output", required=True, help="marker map YAML to write")
    p.add_argument(
        "--format",
        default="auto",
        choices=("auto", "poses", "wpilib", "apriltag_ros"),
        help="the layout's format (auto: from its keys)",
    )
    p.add_argument(
        "--dictionary",
        help="the tags' dictionary: an OpenCV name, an AprilTag family (tag36h11...) or a "
        "dictionary YAML (default: the file's 'dictionary', else DICT_APRILTAG_36h11)",
    )
    p.add_argument(
        "--marker-size",
        type=A.positive_float,
        help="side (m) of the tags the layout gives no size (WPILib's JSON gives none)",
    )
    p.add_argument(
        "--marker-sizes",
        type=A.marker_sizes,
        help="sides by id over the layout's: ID:SIZE or FIRST-LAST:SIZE, comma-separated, or "
        "a YAML file of them (m)",
    )
    p.add_argument("--bundle", help="apriltag_ros: the bundle to read (when there are several)")
    p.add_argument(
        "--opencv-images",
        action="store_true",
        help="AprilTags printed from OpenCV's marker images (generateImageMarker), which are "
        "the AprilTag images turned by 180 degrees",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing map")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Read the layout, write the map; returns 0. Raises CliError / ValueError (one line) for
    a bad layout (duplicate ids, a tag without size, a non-unit quaternion...), an unknown
    dictionary or an output that cannot be written: no map is written then."""
    import os

    from ..cv_compat import get_dictionary, is_dictionary_file
    from ..frontends.marker_detection import APRILTAG_FAMILIES
    from ..maps.tag_poses import read_tag_layout, write_tag_map

    A.input_file(args.layout, "tag layout")
    A.output_file(args.output, args.overwrite, "marker map")
    layout = read_tag_layout(
        args.layout, args.format, args.marker_sizes or {}, args.marker_size, args.bundle
    )
    dictionary = args.dictionary or layout.dictionary or "DICT_APRILTAG_36h11"
    if dictionary not in APRILTAG_FAMILIES:
        get_dictionary(dictionary)  # (ValueError: an unknown name or a bad dictionary file)
    if is_dictionary_file(dictionary):  # (the map names it relative to itself)
        out_dir = os.path.dirname(os.path.abspath(args.output))
        dictionary = os.path.relpath(os.path.abspath(dictionary), out_dir)
    out = write_tag_map(
        args.output, layout, dictionary, args.opencv_images, overwrite=args.overwrite
    )
    sizes = sorted({round(s, 6) for s, _, _ in layout.tags.values()})
    print(
        f"wrote {out}: {len(layout.tags)} tags ({dictionary}, sizes {sizes} m) from a "
        f"{layout.format} layout"
    )
    return 0
