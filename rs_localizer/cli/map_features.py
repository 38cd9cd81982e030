"""``rs-localizer map-features``: a feature map (``.npz``, the features front end's
``frontend_map``) from a COLMAP reconstruction, or from photos reconstructed with pycolmap."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import TextIO

from . import args as A

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``map-features`` parser to ``sub`` (``func`` = :func:`run`)."""
    p = sub.add_parser(
        "map-features",
        help="feature map for the features front end from a COLMAP model or from photos "
        "(needs pycolmap: pip install 'rs_localizer[mapping]')",
        formatter_class=A.HelpFormatter,
        description="Build the features front end's map (.npz) from a COLMAP sparse model and "
        "its database (--colmap), or reconstruct photos taken with one known camera first "
        "(--images with --camera). A reconstruction has no metric scale: give --scale or "
        "--align-markers (ArUco markers seen in the photos, with their marker map), else "
        "positions and velocities are in the model's units.",
    )
    p.add_argument("--colmap", metavar="MODEL_DIR", help="COLMAP sparse model (.bin or .txt)")
    p.add_argument("--database", metavar="DB", help="COLMAP database (default: beside the model)")
    p.add_argument(
        "--images",
        metavar="DIR",
        help="photos: reconstructed with pycolmap (needs --camera); with --colmap, only "
        "where --align-markers finds them",
    )
    p.add_argument(
        "--camera", dest="camera_yaml", metavar="CAMERA.yaml", help="calibration YAML of the photos"
    )
    p.add_argument("-o", "--out", required=True, metavar="MAP.npz", help="feature map to write")
    p.add_argument(
        "--min-track", type=A.positive_int, default=3, help="fewest photos that saw a point"
    )
    p.add_argument(
        "--max-error",
        type=A.positive_float,
        default=None,
        help="largest reprojection error of a point (px)",
    )
    scale = p.add_mutually_exclusive_group()
    scale.add_argument("--scale", type=A.positive_float, help="metres per model unit")
    scale.add_argument(
        "--align-markers",
        metavar="MARKERS.yaml",
        help="marker map (or scene) whose markers appear in the photos: the map is moved to "
        "its frame and scale",
    )
    p.add_argument(
        "--max-residual",
        type=A.positive_float,
        default=0.02,
        help="largest marker alignment RMS (m)",
    )
    p.add_argument(
        "--workdir",
        metavar="DIR",
        help="keep the reconstruction (database.db, model/) here (default: a temporary "
        "directory, removed)",
    )
    p.add_argument(
        "--matching",
        choices=["exhaustive", "sequential"],
        default="sequential",
        help="--images: match each photo with its next ones in name order (photos taken along "
        "a walk), or every pair of photos (photos in no order; on tiled textures it can bend "
        "the model)",
    )
    p.add_argument(
        "--attempts",
        type=int,
        default=3,
        help="--images with --align-markers: reconstructions tried when the alignment "
        "refuses a bent model (the other --matching, then another seed)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing map")
    p.set_defaults(func=run)
    return p


def _output_path(out: str, overwrite: bool) -> Path:
    path = Path(out)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    A.output_file(path, overwrite, "feature map")
    if not path.parent.is_dir():
        raise A.CliError(f"{path}: cannot write the feature map (no directory {path.parent})")
    return path


def run(args: argparse.Namespace, stream: TextIO | None = None) -> int:
    """Run ``map-features``. Raises ValueError / FileNotFoundError / FileExistsError for input
    a user can fix (nothing is written then)."""
    if not args.colmap and not (args.images and args.camera_yaml):
        raise ValueError("give --colmap MODEL_DIR, or --images DIR with --camera CAMERA.yaml")
    if args.align_markers and not args.images:
        raise ValueError("--align-markers needs the photos: --images DIR")
    out = _output_path(args.out, args.overwrite)
    if args.colmap:
        A.input_dir(args.colmap, "COLMAP sparse model directory")
    if args.database:
        A.input_file(args.database, "COLMAP database")
    if args.images:
        A.input_dir(args.images, "folder of photos")
    if args.camera_yaml:
        A.camera_file(args.camera_yaml)
    if args.align_markers:
        A.marker_map_file(args.align_markers)
    if args.workdir:
        A.writable_dir(args.workdir, "work directory")
    from ..mapping import colmap
    from ..mapping.outputs import camera_from_yaml

    try:
        colmap.import_pycolmap()
    except ModuleNotFoundError as e:
        raise ValueError(str(e)) from None
    if args.attempts < 1:
        raise ValueError(f"--attempts must be >= 1, got {args.attempts}")
    al, tried = None, []
    with tempfile.TemporaryDirectory(prefix="rs_localizer_colmap_") as tmp:
        if args.colmap:
            model, database = Path(args.colmap), args.database
        else:
            camera = camera_from_yaml(args.camera_yaml)  # (global shutter: still photos)
            work = Path(args.workdir) if args.workdir else Path(tmp)
            if args.align_markers:
                model, al, tried = colmap.reconstruct_aligned(
                    args.images,
                    camera,
                    work,
                    args.align_markers,
                    matching=args.matching,
                    attempts=args.attempts,
                    max_residual=args.max_residual,
                    progress=sys.stderr,
                )
            else:
                model = colmap.reconstruct(
                    args.images, camera, work, progress=sys.stderr, matching=args.matching
                )
            database = work / "database.db"
        fm = colmap.feature_map_from_colmap(
            model, database, min_track=args.min_track, max_error=args.max_error
        )
        lines = [
            f"{len(fm)} points (track >= {args.min_track}: median "
            f"{int(sorted(fm.track_length)[len(fm) // 2])} photos, reprojection error median "
            f"{sorted(fm.reprojection_error)[len(fm) // 2]:.2f} px), SIFT descriptors"
        ]
        if args.align_markers:
            if al is None:
                al = colmap.align_to_markers(
                    model, args.images, args.align_markers, max_residual=args.max_residual
                )
            fm = colmap.align_feature_map(fm, al)
            lines.append(
                f"aligned on markers {al.markers}: scale {al.scale:.5g} m/unit, residual "
                f"{al.residual_rms * 1000:.1f} mm RMS ({al.residual_max * 1000:.1f} mm max) "
                f"over {len(al.corners)} triangulated corners, marker centres "
                f"{sorted(al.reprojection_errors)[len(al.reprojection_errors) // 2]:.2f} px "
                f"median over {len(al.reprojection_errors)} detections"
            )
            for a in tried[:-1]:
                lines.append(f"refused first: {a.matching} matching, seed {a.seed}: {a.error}")
            if tried:
                lines.append(f"kept: {tried[-1].matching} matching, seed {tried[-1].seed}")
        elif args.scale is not None:
            fm = colmap.scale_feature_map(fm, args.scale)
            lines.append(f"scaled by {args.scale:g} m/unit")
        else:
            lines.append(
                "no metric scale: positions and velocities will be in the model's units, not "
                "metres (use --scale S or --align-markers MARKERS.yaml)"
            )
        fm.save(out)  # (whole or not at all)
    print(f"wrote {out}: " + "; ".join(lines), file=stream or sys.stdout)
    return 0
