"""``rs-localizer marker-map``: the ArUco marker map of a simulated scene (the file the node's
``frontend_map`` and the ArUco front end read)."""

from __future__ import annotations

import argparse

from . import args as A

__all__ = ["register", "run"]

HELP = "write the marker map of a simulated scene (for the ArUco front end)"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``marker-map`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    mm = sub.add_parser(
        "marker-map",
        help=HELP,
        description="Write the ArUco markers of a built-in or YAML scene as a marker map, for "
        "the node's frontend_map with the aruco front end (a real room's map: map-markers).",
        formatter_class=A.HelpFormatter,
    )
    mm.add_argument("scene", help="built-in scene (aruco_room, textured_room) or scene YAML")
    mm.add_argument("out", help="marker map YAML to write")
    mm.set_defaults(func=run)
    return mm


def run(args: argparse.Namespace) -> int:
    """Write the map; returns 0. Raises CliError / ValueError for an unknown scene or an output
    that cannot be written."""
    from ..maps.markers import write_marker_map
    from ..sim.render.scene import load_scene

    A.output_file(args.out, True, "marker map")
    scene = load_scene(args.scene)
    out = write_marker_map(args.out, scene.dictionary, scene.marker_corners(), scene=scene.name)
    print(f"wrote {out}: {len(scene.markers)} markers ({scene.dictionary}) of scene {scene.name}")
    return 0
