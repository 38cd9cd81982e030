"""``rs-localizer calibrate-rig``: every camera's mounting on a rig from a rig bag of a known
map, with its uncertainty, written as the node's rig parameters."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

import numpy as np

from . import args as A

if TYPE_CHECKING:
    from ..frames import Mounting

__all__ = ["register", "run"]

HELP = "estimate each rig camera's mounting from a rig bag of a known map"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``calibrate-rig`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    c = sub.add_parser(
        "calibrate-rig",
        help=HELP,
        description="Estimate every camera's mounting on the rig, with its covariance, from a "
        "rig bag (each camera's correspondences with a known map and camera_info, e.g. "
        "make-bag --rig N; with -p frontend its images through the front end), read as the rig "
        "node reads them; the cameras need only be connected through shared frames (a ring, a "
        "chain). Writes the node's rig parameters (rig.<camera>.mounting and "
        "mounting_covariance, each camera's RS timing); the cameras, their timing and "
        "max_points come from the bag's rig_params.yaml, then --params-file, then -p. The "
        "method: docs/rig_node.md#mountings-from-data-calibrate-rig.",
        formatter_class=A.HelpFormatter,
    )
    c.add_argument("bag", help="rig bag directory (make-bag --rig) or its .mcap file")
    c.add_argument("-o", "--output", help="parameter file to write (default: on stdout)")
    A.node_parameter_options(
        c, "the node's parameter file with rig.cameras and the cameras' RS timing (repeatable; "
        "later ones win; over the bag's rig_params.yaml)",
        "set a node parameter (YAML value, as ros2 run -p; repeatable; over the parameter "
        "files), e.g. frontend:=aruco with frontend_map:=BAG/markers.yaml to read each camera's "
        "images through its front end",
    )  # fmt: skip
    c.add_argument("--reference", help="the camera the others are measured from (default: the "
                   "first of rig.cameras)")  # fmt: skip
    c.add_argument("--optical-frame", action="store_true",
                   help="the rig frame is the reference camera's optical frame (the file's "
                   "base_frame its camera_info's frame_id); default: base_frame, the "
                   "reference at its mounting of the parameters, if any")  # fmt: skip
    c.add_argument("--window", type=A.nonneg_float, default=0.015,
                   help="s; camera frames further apart are not one rig frame")  # fmt: skip
    c.add_argument("--threshold", type=A.positive_float, default=2.0, help="RANSAC threshold (px)")
    c.add_argument("--min-inliers", type=A.positive_int, default=20,
                   help="camera frames posed with fewer inliers are left out of the pose-level "
                   "adjustment (a global-shutter rig's refinement on the corners takes their "
                   "corners)")  # fmt: skip
    c.add_argument("--time-offsets", action="store_true",
                   help="also estimate each camera's time offset against the reference's (s "
                   "added to its stamps), with its std, written as rig.<camera>.time_offset; a "
                   "rig that barely moves shows none (its std says so)")  # fmt: skip
    c.add_argument("--json", action="store_true",
                   help="print the mountings and their uncertainty as JSON (then -o for the "
                   "parameter file)")  # fmt: skip
    c.set_defaults(func=run)
    return c


#: s: a time offset estimated with a std above this is not shown by the video (a warning)
UNSEEN_OFFSET_STD = 0.005

#: fewer rig frames than this make the stated std a warning: it is the scatter of that few
#: frames, itself that uncertain (docs/rig_node.md#mountings-from-data-calibrate-rig)
MIN_RIG_FRAMES = 10


def params_yaml(stamp_row: float, cams: dict, report: dict, notes: list, base_frame: str) -> str:
    """The node's parameter file of the calibrated rig (``report``: camera -> its entry of the
    JSON report, :func:`run`): per camera its ``mounting`` and ``mounting_covariance`` (none
    for the reference), the RS timing it was read with (``cams``), its ``time_offset`` and
    ``time_offset_std`` (s, 7 decimals; the offset none when zero, the std none when not
    estimated: the node takes it whatever the offset); ``notes``: comment lines on top."""
    from ..ros.config import rig_parameter_file

    body_cams = {}
    for n, r in report.items():
        entry = {k: r[k] for k in ("mounting", "mounting_covariance") if r[k] is not None}
        entry.update({k: v for k in ("line_delay", "readout_time", "direction")
                      if (v := cams[n].get(k)) not in (None, "", -1.0)})  # fmt: skip
        if r["time_offset"]:
            entry["time_offset"] = round(float(r["time_offset"]), 7) + 0.0
        if r.get("time_offset_std", 0.0) > 0:
            entry["time_offset_std"] = round(float(r["time_offset_std"]), 7) + 0.0
        body_cams[n] = entry
    return rig_parameter_file(base_frame, stamp_row, body_cams, notes=notes)


#: a calibrated mounting further than this many of its std (rotation or position) from the
#: parameters' mounting of the camera is reported as a warning
PARAMETERS_OFF_STD = 3.0


def relative_to(mountings: dict[str, Mounting], ref: str) -> dict[str, Mounting]:
    """``mountings`` re-expressed in camera ``ref``'s optical frame (``x_ref = R_ref x_base +
    c_ref``); empty without ``ref``'s own mounting (the frames are then unrelated)."""
    from ..frames import Mounting
    from ..geometry import compose

    base = mountings.get(ref)
    if base is None:
        return {}
    return {n: Mounting(*compose(m.R, m.c, base.rotation, base.translation))
            for n, m in mountings.items()}  # fmt: skip


def _optical_frame_id(bag, camera: str, names: list[str]) -> str:
    """``camera``'s optical frame in a bag of the rig ``names``: its first camera_info's
    ``frame_id`` (on the topic its frames are read from), else ``<camera>_optical_frame``."""
    from ..ros.bags.bag_io import RigTopics, first_message, rig_namespace

    topic = RigTopics(rig_namespace(bag, names), tuple(names)).topic(camera, "info")
    info = first_message(bag, {topic})
    frame_id = "" if info is None else str(info.header.frame_id).strip()
    return frame_id or f"{camera}_optical_frame"


def _camera_notes(
    n: str, e, given: Mounting | None, rig_refined: bool = False
) -> tuple[list[str], dict]:
    """The lines printed on a non-reference camera's estimate ``e`` (``rig_refined``: the rig's
    mountings were refined on the corners) and, with the parameters' mounting ``given``, how
    far that is (lines, and ``parameters_off_deg``/``_mm``)."""
    from scipy.stats import chi2

    from ..geometry import rotation_angle_deg

    notes = [
        f"{n}: {e.frames} rig frames ({e.rejected} left out), std {e.std_deg:.4f} deg "
        f"{e.std_mm:.2f} mm (one frame about the rig: {e.scatter_deg:.3f} deg "
        f"{e.scatter_mm:.1f} mm)"
    ]
    if e.corners_refined:
        notes.append(
            f"{n}: refined on the corners; its std is the corners' solve's plus the error the "
            f"cameras' poses and the corners disagree by (misfit {e.corner_misfit:.1f}: how "
            "far the refinement moved the mountings in the pose-level std, squared, per degree "
            "of freedom; 1: none added)"
        )
    elif rig_refined:
        notes.append(
            f"{n}: not refined on the corners: none of its corners is in the corners' solve "
            "(its frames share no rig frame with another camera's there), so its mounting, "
            "std and time offset are the pose-level adjustment's"
        )
    if np.isfinite(e.time_offset_std):
        notes.append(
            f"{n}: time offset {1e3 * e.time_offset:+.2f} ms, std "
            f"{1e3 * e.time_offset_std:.2f} ms (added to its stamps)"
        )
        std = f"std {1e3 * e.time_offset_std:.0f} ms"
        if e.time_offset_std > UNSEEN_OFFSET_STD:
            # (refined with offsets: the rig moved enough to show one, so the runs of rig
            # frames disagree on it; else the rig hardly moved)
            notes.append(f"WARNING: {n}: " + (
                f"its time offset changes over the video ({std} over runs of rig frames): the "
                "cameras do not seem to be triggered together; its mounting's std includes the "
                "rig's motion over that change; trigger the cameras together"
                if e.corners_refined
                else f"the video does not show its time offset ({std}): the rig hardly moves "
                "in the rig frames it shares; record one that moves"
            ))  # fmt: skip
    if np.isfinite(e.exposure_offset):
        how = (
            "the mountings were refined on the corners with a time offset per camera (above)"
            if e.corners_refined
            else f"the others' mountings were refined on the corners with a time offset per "
            f"camera, {n}'s not (above)"
            if rig_refined
            else "the mountings were not refined on the corners; --time-offsets estimates "
            "the offsets"
        )
        notes.append(
            f"NOTE: {n}: the cameras do not seem to expose together ({n} about "
            f"{1e3 * e.exposure_offset:+.1f} ms from the reference while the rig turns): {how}"
        )
    if e.frames < MIN_RIG_FRAMES:  # (the error may exceed the std by the 95 % bound
        # sqrt((n - 1) / chi2_0.05(n - 1)) of a std from n frames' scatter)
        dof = max(e.frames - 1, 1)
        notes.append(
            f"WARNING: {n}: only {e.frames} rig frames: the std is their scatter, which that few "
            f"frames fix poorly (the error may be up to {np.sqrt(dof / chi2.ppf(0.05, dof)):.1f}x "
            f"the std, 95 % bound); record {MIN_RIG_FRAMES} or more rig frames"
        )
    if given is None:
        return notes, {}
    deg = float(rotation_angle_deg(e.mount.R, given.R))
    mm = float(np.linalg.norm(e.mount.position - given.position) * 1e3)
    k_deg, k_mm = deg / max(e.std_deg, 1e-12), mm / max(e.std_mm, 1e-12)
    notes.append(
        f"{n}: the parameters' mounting is {deg:.3f} deg, {mm:.1f} mm from this one "
        f"({k_deg:.1f} and {k_mm:.1f} std)"
    )
    if max(k_deg, k_mm) > PARAMETERS_OFF_STD:
        notes.append(
            f"WARNING: {n}: the mounting in the parameters is off by {deg:.2f} deg, "
            f"{mm:.1f} mm (more than {PARAMETERS_OFF_STD:g} std): use the one written here"
        )
    return notes, {"parameters_off_deg": deg, "parameters_off_mm": mm}


def _frames_read(frames: list, name: str, min_inliers: int) -> str:
    """``back: no frame in the bag ...``, ``back: 40 frames read, none with 20
    correspondences or more ...`` or ``back: 40 frames read, 12 with 20 correspondences or
    more ...``: whether a camera the calibration could not connect had frames at all (its
    topics), saw the map (the camera sees too little of it) or too few of its frames were
    posed near another camera's."""
    mine = [f for f in frames if f.camera_name == name]
    if not mine:
        return (
            f"{name}: no frame in the bag (no {name}/correspondences, or {name}/image_raw with "
            "a front end, under the rig's namespace)"
        )
    seen = sum(len(f.points2d) >= min_inliers for f in mine)
    if seen == 0:
        return (
            f"{name}: {len(mine)} frames read, none with {min_inliers} correspondences or more "
            "(the camera sees too little of the map)"
        )
    return (
        f"{name}: {len(mine)} frames read, {seen} with {min_inliers} correspondences or more, "
        "too few of them posed near another camera's (lower --min-inliers?)"
    )


def run(args: argparse.Namespace) -> int:
    from ..calibration import calibrate_mountings
    from ..ros.bags.bag_frames import read_rig_frames
    from ..ros.config import (
        mounting_covariance_values,
        mounting_values,
        rig_base_frame,
        rig_mounting,
    )
    from ..ros.params import ConfigError
    from ..runtime.background import frames_alone_options

    bag = A.bag_dir(args.bag, require_messages=True)
    out_path = A.output_file(args.output, what="parameter file") if args.output else None
    A.parameter_files(args.params_file)
    try:
        read = read_rig_frames(bag, args.params_file, A.param_overrides(args.param))
    except ConfigError as e:
        raise A.CliError(f"invalid parameters: {e}") from None
    values, cams = read.values, read.cameras
    names = list(cams)  # (rig.cameras, named as the rig node names them)
    ref = args.reference or names[0]
    if ref not in names:
        raise A.CliError(f"--reference {ref!r} is not a camera of the rig {names}")
    # the mountings the parameters give (the node's reading: it refuses a bad one, naming it)
    given = {n: rig_mounting(n, cams[n]["mounting"]) for n in names if cams[n].get("mounting")}
    ref_mount = None if args.optical_frame else given.get(ref)
    options = frames_alone_options(args.threshold)
    est = calibrate_mountings(
        read.frames, ref, reference_mount=ref_mount, window=args.window,
        stamp_row=float(values["rs.stamp_row"]), min_inliers=args.min_inliers, options=options,
        time_offsets=read.settings.time_offsets,
        estimate_time_offsets=args.time_offsets,
    )  # fmt: skip
    missing = [n for n in names if n not in est]
    if missing:
        raise A.CliError(
            f"camera(s) {missing} share no rig frame with the reference camera {ref!r}, "
            f"directly or through other cameras (frames posed alone with --min-inliers "
            f"{args.min_inliers} or more inliers, within --window {args.window} s of each "
            f"other): {'; '.join(_frames_read(read.frames, n, args.min_inliers) for n in missing)}"
        )
    if ref_mount is None:  # (the rig frame is the reference camera's optical frame)
        frame = _optical_frame_id(bag, ref, names)
        where = f"camera {ref}'s optical frame: z forward, x right, y down"
        given = relative_to(given, ref)
    else:
        frame = rig_base_frame(values)
        where = f"base_frame, camera {ref} at its mounting of the parameters"
    notes = [
        f"rs-localizer calibrate-rig {bag.name}: mountings relative to camera {ref!r} "
        f"in the rig frame {frame} ({where})"
    ]
    notes += [  # (each camera's rows and clouds left out, named as replay names them)
        f"{n}: " + ", ".join(f"{k} {v}" for k, v in read.counts[n].items())
        + " (rows with a NaN or inf dropped; clouds of more than max_points "
        f"{int(values['max_points'])} rows capped to it; clouds not read: no u, v, x, y, z "
        "fields (bad_input), a header stamp out of range (bad_stamp))"
        for n in names if any(read.counts[n].values())
    ]  # fmt: skip
    report = {}
    for n in names:
        e = est[n]
        report[n] = {
            "mounting": mounting_values(e.mount),
            **{k: getattr(e, k) for k in ("frames", "rejected", "std_deg", "std_mm")},
            "mounting_covariance": mounting_covariance_values(e.mount),
            **{k: getattr(e, k) for k in ("scatter_deg", "scatter_mm", "time_offset")},
            "corners_refined": e.corners_refined,
            **read.counts[n],
            **({"time_offset_std": e.time_offset_std} if np.isfinite(e.time_offset_std) else {}),
            **({"corner_misfit": e.corner_misfit} if n != ref and e.corners_refined else {}),
        }
        if n == ref:
            notes.append(f"{n}: the reference (in {e.frames} rig frames)")
        else:
            lines, off = _camera_notes(n, e, given.get(n), est[ref].corners_refined)
            notes += lines
            report[n].update(off)
    text = params_yaml(values["rs.stamp_row"], cams, report, notes, frame)
    if out_path is not None:
        out_path.write_text(text)
    for line in notes:
        print(line, file=sys.stderr)
    if ref_mount is None:
        again = "without --optical-frame" if args.optical_frame else "with it"
        print(
            f"the rig frame is {frame}, camera {ref}'s optical frame (base_frame: {frame} in "
            "the file): the node publishes that camera's pose. To publish the robot's base "
            f"instead, give camera {ref}'s pose in it (rig.{ref}.mounting: [x, y, z, qx, qy, "
            f"qz, qw], e.g. from 'ros2 run tf2_ros tf2_echo base_link {frame}') and the "
            f"base's name (base_frame) in a --params-file and run again {again}: every "
            "mounting is then written in the base's frame",
            file=sys.stderr,
        )
    if args.json:
        print(json.dumps({"reference": ref, "rig_frame": frame, "cameras": report}, indent=2))
    elif out_path is None:
        sys.stdout.write(text)
    else:
        print(f"wrote {out_path}", file=sys.stderr)
    return 0 if np.isfinite([r["std_deg"] for r in report.values()]).all() else 1
