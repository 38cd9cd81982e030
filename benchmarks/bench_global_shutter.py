"""Global-shutter and fast-readout cameras: ``python -m benchmarks.bench_global_shutter``.

A global-shutter camera (``rs.line_delay`` 0), or one whose readout is too short for a frame to
show motion (nanoseconds to a few microseconds per line), gives the rolling-shutter solver
nothing to fit its six velocity parameters to but the noise. The estimator then poses the
frame on the global-shutter model (``RSPoseEstimate.motion_model``): always with line delay 0,
and elsewhere when the frame's velocities are not significant under their own covariance
(:data:`rs_localizer.estimation.finalize.MOTION_SIGNIFICANCE_CHI2`).

Prints, for the paper protocol's frames of a camera at rest (:func:`rs_localizer.sim.synthetic
.make_frame` with ``rs_speed=0``: 1000x1000 px, 45 deg field of view, 1 px noise, 20 % outliers)
at each line delay, and then for a camera turning at ``--turn`` rad/s with a 2 us line delay:
the median rotation error of ``p3p`` and of the default solver ``r6p_1lin`` (deg; ground truth:
the simulated pose), their ratio, the frames each refuses and the frames P3P solves that
``r6p_1lin`` refuses, and how many of ``r6p_1lin``'s estimates took each motion model. The
targets (a camera at rest): ratio <= 1.05 and no frame refused that P3P solves. One BLAS thread.

Then the same for planar scenes (:func:`rs_localizer.sim.planar.make_planar_frame`: 640x480,
f = 600 px, 0.5 px noise, no outliers): ``board``, a 6x7-corner checkerboard with 8 cm
squares 0.8-2 m away, and ``3 tags``, three 10 cm square tags in a row 5 cm apart (12
corners) at the same places, at rest at each line delay and moving (1-3 rad/s, 0.2-1 m/s, a
hand-held camera) with a 30 us line delay, ``--planar-frames`` each. A planar frame refined
with the motion prior, and a frame of fewer than 50 inliers, switches to the global-shutter
model when its velocities lie within :data:`rs_localizer.estimation.finalize.STILL_CHI2` of
zero. Targets: at rest at line delays up to 2 us as above; moving, the rotation error is the
rolling-shutter estimator's (compare with a run of the previous version: within 1.05x).

Last (``--drive``), a robot driving past 3-5 markers of a simulated room (12-20 corners, not
coplanar, 30 ms readout: :func:`rs_localizer.sim.marker_mapping.drive_detections`, the frames
with 3 or more markers) on the true map: real motion that a few points determine loosely.

``--rig``: a rig of three cameras (:func:`rs_localizer.sim.synthetic.make_rig`: front, left, right,
5-20 cm levers) with equal stamps, turning at 0.3 rad/s and moving at 0.3 m/s, 40 points per
camera (10 % outliers, 0.5 px noise), at each line delay: the rig estimator's median rotation
error against the same rig frames with line delay 0 (the rig's generalized absolute pose), the
rig frames each refuses and how many took the global-shutter model. Target: ratio <= 1.05 and
no rig frame refused that line delay 0 poses, up to 2 us/line.

Last (``--real``, when ``../shared/data/real_markers`` is there): TagSLAM's test_23, a
RealSense D435 colour camera (640x480, rolling shutter, line delay unknown) watching a 3x3
board of 0.049 m tags that barely moves, 372 frames of 4-9 tags, each tag where TagSLAM's
solution puts it on the board (the printed 1.5-side pitch is up to 0.8 mm off): the camera's median
position (mm) and rotation (deg) error against TagSLAM's solution for ``p3p`` and
``r6p_1lin`` with line delay 0 and 30 us, and the motion models taken; then the video's
check of the rolling-shutter timing (``readout_suspect``, docs/video.md) at 30, 10 and 0 us.

    python -m benchmarks.bench_global_shutter [--frames 60] [--points 100]
        [--line-delays 0 1e-9 1e-7 1e-6 2e-6 3e-5] [--turn 10] [--planar-frames 60] [--drive]
        [--rig] [--real]
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from rs_localizer.camera import CameraModel
from rs_localizer.estimation import EstimateOptions, RansacOptions, estimate_rs_pose
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.planar import make_planar_frame, planar_camera
from rs_localizer.sim.synthetic import FRAME_SPAN, IMAGE_SIZE, make_frame, paper_camera
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import SequenceLocalizer, SequenceSettings

__all__ = ["d435_frames", "drive_frames", "main", "planar_frames", "real_d435", "run", "tags_frame"]

SOLVERS = ("p3p", "r6p_1lin")

#: the moving planar frames' line delay (s per line): a typical rolling-shutter camera
MOVING_LINE_DELAY = 30e-6


def tags_frame(seed: int, camera: CameraModel, moving: bool, tags: int = 3, side: float = 0.1):
    """A few square tags (``tags`` of ``side`` m in a row, ``side / 2`` apart: ``4 * tags``
    corners, ``z = 0``) at :func:`~rs_localizer.sim.planar.make_planar_frame`'s board pose
    and motion for ``seed`` (at rest unless ``moving``: 1-3 rad/s, 0.2-1 m/s), seen by
    ``camera`` with 0.5 px noise. Returns a namespace with ``points_px`` (N, 2), ``X`` (N, 3)
    and ``R`` (3, 3), the true world -> camera rotation at the reference line."""
    f = _board(seed, camera, moving)
    h, step = side / 2, 1.5 * side
    X = np.concatenate(
        [
            np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
            + [(i - (tags - 1) / 2) * step, 0.0, 0.0]
            for i in range(tags)
        ]
    )
    rng = np.random.default_rng(10_000 + seed)
    px = camera.project_rs(X, f.R, f.C, f.w, f.t) + rng.normal(0.0, 0.5, (len(X), 2))
    return SimpleNamespace(points_px=px, X=X, R=f.R)


def _board(seed: int, camera: CameraModel, moving: bool):
    speeds = {} if moving else {"angular_speed": (0.0, 0.0), "linear_speed": (0.0, 0.0)}
    return make_planar_frame(seed, "board", camera=camera, **speeds)


def planar_frames(scene: str, n: int, camera: CameraModel, moving: bool) -> list:
    """``n`` frames of ``scene`` (``board`` or ``3 tags``) seen by ``camera``: namespaces
    with ``points_px``, ``X`` and ``R`` (:func:`tags_frame`)."""
    if scene == "board":
        return [_board(k, camera, moving) for k in range(n)]
    return [tags_frame(k, camera, moving) for k in range(n)]


def drive_frames(num_frames: int = 120) -> tuple[CameraModel, list]:
    """The robot's drive of :func:`rs_localizer.sim.marker_mapping.drive_detections` in the
    room of :func:`~rs_localizer.sim.marker_mapping.room_scene`: its camera and the frames
    that see 3 or more markers (namespaces with ``points_px``, ``X`` on the true map and the
    true ``R``, world -> camera)."""
    from rs_localizer.sim.marker_mapping import drive_detections, room_scene

    room, camera, *_ = room_scene(90, anchor_frames=30)
    detections, truth = drive_detections(room, camera, num_frames=num_frames)
    corners = room.corners()
    frames = []
    for k, (_, d) in enumerate(detections):
        ids = [m for m in sorted(d) if m in corners]
        if len(ids) >= 3:
            frames.append(
                SimpleNamespace(
                    points_px=np.concatenate([d[m] for m in ids]),
                    X=np.concatenate([np.asarray(corners[m], float) for m in ids]),
                    R=np.asarray(truth["orientation"][k]).T,
                )
            )
    return camera, frames


#: TagSLAM's test_23 (README there: source, licence, format): ``shared/data/real_markers``
#: beside the checkout (or beside the folder of worktrees the checkout is in)
TEST_23 = (
    next(
        (
            p
            for p in (
                Path(__file__).resolve().parents[k] / ".." / "shared" / "data" / "real_markers"
                for k in (1, 2)
            )
            if p.is_dir()
        ),
        Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real_markers",
    )
    / "tagslam"
    / "test_23"
)


def d435_frames(folder: Path = TEST_23) -> tuple[CameraModel, list]:
    """test_23's camera (line delay 0) and frames: namespaces with ``points_px`` (the AprilTag
    library's corners as this package's detector returns them), ``X`` (the board's corners,
    tag ``3 row + column``, rows up, 1.5 sides apart, in the detector's order),
    ``position`` (3,) and ``orientation`` (3, 3): TagSLAM's camera in the board frame,
    ``stamp`` (s): the detection's."""
    import json

    from scipy.spatial.transform import Rotation

    from rs_localizer.frontends.marker_detection import (
        APRILTAG_PIXEL_OFFSET,
        APRILTAG_TO_ARUCO_ORDER,
    )

    def pose(q, t):
        M = np.eye(4)
        M[:3, :3] = Rotation.from_quat(q).as_matrix()
        M[:3, 3] = t
        return M

    h = 0.049 / 2
    tag = np.array([[h, -h, 0.0], [-h, -h, 0.0], [-h, h, 0.0], [h, h, 0.0]])  # BR, BL, TL, TR
    tf = {
        (t["parent"], t["child"]): t
        for t in json.loads((folder / "json/reference_final_tf.json").read_text())
    }
    # each tag where TagSLAM's solution puts it on the board (up to 0.8 mm and 0.15 deg from
    # the printed layout: a pitch of 1.5 sides would leave ~1 px of model error)
    board = {}
    for i in range(9):
        T = tf[("tag_board", f"tag_{i}")]
        M = pose(T["quat_xyzw"], T["translation"])
        board[i] = tag @ M[:3, :3].T + M[:3, 3]
    rig, cam = tf[("map", "rig")], tf[("rig", "cam0")]
    map_cam = pose(rig["quat_xyzw"], rig["translation"]) @ pose(
        cam["quat_xyzw"], cam["translation"]
    )
    odom = {
        round(o["stamp"], 4): o
        for o in map(json.loads, (folder / "json/reference_odom.jsonl").read_text().splitlines())
    }
    frames = []
    for line in (folder / "json/detections.jsonl").read_text().splitlines():
        d = json.loads(line)
        o = odom[round(d["stamp"], 4)]
        board_cam = np.linalg.inv(pose(o["quat_xyzw"], o["position"])) @ map_cam
        ids = sorted(t["id"] for t in d["tags"])
        px = {
            t["id"]: np.array(t["corners"])[list(APRILTAG_TO_ARUCO_ORDER)] - APRILTAG_PIXEL_OFFSET
            for t in d["tags"]
        }
        frames.append(
            SimpleNamespace(
                points_px=np.concatenate([px[i] for i in ids]),
                X=np.concatenate([board[i] for i in ids]),
                position=board_cam[:3, 3],
                orientation=board_cam[:3, :3],
                stamp=float(d["stamp"]),
            )
        )
    K = np.array([[612.569, 0, 319.370], [0, 612.861, 241.992], [0, 0, 1]])
    return CameraModel(K=K, width=640, height=480), frames


def real_d435(folder: Path = TEST_23) -> None:
    """Print test_23's rows (module docstring), or why not."""
    if not folder.is_dir():
        print(f"(--real: {folder} is absent)")
        return
    camera, frames = d435_frames(folder)
    print(f"D435 board (test_23, {len(frames)} frames) against TagSLAM's solution:")
    for delay in (0.0, 30e-6):
        cam = replace(camera, line_delay=delay)
        for solver in SOLVERS:
            pos, rot, models = [], [], []
            for f in frames:
                est = estimate_rs_pose(f.points_px, f.X, cam, solver)
                if est.success:
                    pos.append(1e3 * np.linalg.norm(est.pose.position - f.position))
                    rot.append(rotation_angle_deg(est.pose.orientation, f.orientation))
                    models.append(est.motion_model)
            gs = models.count("global_shutter")
            print(
                f"  {delay * 1e6:4g} us/line {solver:9s} {np.median(pos):7.2f} mm "
                f"{np.median(rot):7.3f} deg  refused {len(frames) - len(pos)}, "
                f"global-shutter model {gs}, rolling-shutter {len(models) - gs}"
            )
    print("the video's check of the rolling-shutter timing (SequenceLocalizer, r6p_1lin):")
    for delay in (30e-6, 10e-6, 0.0):
        cam = replace(camera, line_delay=delay)
        seq, first = SequenceLocalizer(SequenceSettings()), None
        for k, f in enumerate(frames):
            seq.process(CameraFrame(int(round(f.stamp * 1e9)), cam, f.points_px, f.X))
            if first is None and seq.tracking_values()["readout_suspect"] == "true":
                first = k + 1
        seq.flush()
        v = seq.tracking_values()
        print(
            f"  {delay * 1e6:4g} us/line: suspect {v['readout_suspect']} at the end "
            f"(contradicted {v['readout_contradicted']} of the last 30), first after "
            f"{first} frames; relocalized {v['relocalizations']}, twists refused "
            f"{v['twists_own_frame']} of {len(frames)}"
        )


def run(camera: CameraModel | float, frames: list, solvers=SOLVERS) -> dict:
    """Each solver's rotation errors (deg, None for a refused frame) and motion models on
    ``frames`` (``points_px``, ``X``, ``R``) seen by ``camera``, or by the protocol's camera
    with that line delay (s per line)."""
    if not isinstance(camera, CameraModel):
        camera = paper_camera(camera * IMAGE_SIZE)
    out = {}
    for solver in solvers:
        errors, models = [], []
        for k, f in enumerate(frames):
            est = estimate_rs_pose(
                f.points_px, f.X, camera, solver, EstimateOptions(ransac=RansacOptions(seed=k))
            )
            errors.append(rotation_angle_deg(est.model.R, f.R) if est.success else None)
            models.append(est.motion_model if est.success else None)
        out[solver] = (errors, models)
    return out


def _row(name: str, result: dict) -> tuple[float, int]:
    e_gs, _ = result["p3p"]
    e_rs, models = result["r6p_1lin"]
    med = [float(np.median([e for e in es if e is not None] or [np.nan])) for es in (e_gs, e_rs)]
    lost = sum(1 for a, b in zip(e_gs, e_rs, strict=True) if a is not None and b is None)
    counts = {m: models.count(m) for m in ("global_shutter", "rolling_shutter")}
    ratio = med[1] / med[0] if med[0] > 0 else np.nan
    print(
        f"{name:24s} {med[0]:9.4f} {med[1]:12.4f} {ratio:6.3f} {e_gs.count(None):8d} "
        f"{e_rs.count(None):12d} {lost:9d} {counts['global_shutter']:6d} "
        f"{counts['rolling_shutter']:7d}"
    )
    return ratio, lost


def rig_frames(line_delay: float, n: int) -> list:
    """``n`` rig frames (views, truth) of three cameras with equal stamps at ``line_delay``
    (s per line), turning at 0.3 rad/s: the same points and motion at every line delay (one
    seed per frame)."""
    from rs_localizer.sim import synthetic as sim_rig

    out = []
    for k in range(n):
        rng = np.random.default_rng(2000 + k)
        rig = sim_rig.make_rig(3, rng)
        cams = tuple(
            replace(c, camera=replace(c.camera, line_delay=line_delay), stamp_offset=0.0)
            for c in rig.cameras
        )
        truth = sim_rig.rig_motion(rng, 0.3, 0.3)
        frame = sim_rig.rig_frame(sim_rig.Rig(cams), truth, [40] * 3, rng, 0.5, 0.1)
        out.append((frame.views, truth))
    return out


def rig_rows(line_delays: list, n: int) -> bool:
    """Prints the ``--rig`` table; True when its target is met."""
    from rs_localizer.estimation.rig import estimate_rig_pose

    def errors(line_delay):
        errs, gs = [], 0
        for views, truth in rig_frames(line_delay, n):
            est = estimate_rig_pose(views)
            errs.append(rotation_angle_deg(est.model.R, truth.R) if est.success else None)
            gs += bool(est.success and est.motion_model == "global_shutter")
        return errs, gs

    base, _ = errors(0.0)
    med0 = float(np.median([e for e in base if e is not None]))
    print(f"\nrig of 3 cameras, {n} rig frames: {'line delay':>12s} {'rig (deg)':>10s} "
          f"{'ratio':>6s} {'refused':>8s} {'lost':>5s} {'GS':>4s}")  # fmt: skip
    ok = True
    for d in line_delays:
        errs, gs = errors(d)
        med = float(np.median([e for e in errs if e is not None] or [np.nan]))
        lost = sum(1 for a, b in zip(base, errs, strict=True) if a is not None and b is None)
        print(
            f"{'':30s} {d * 1e6:9g} us {med:10.4f} {med / med0:6.3f} {errs.count(None):8d} "
            f"{lost:5d} {gs:4d}"
        )
        if d <= 2e-6:
            ok &= med <= 1.05 * med0 and lost == 0
    print(
        "rig target up to 2 us/line (ratio <= 1.05 to line delay 0, no rig frame lost): "
        f"{'met' if ok else 'MISSED'}"
    )
    return ok


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_global_shutter",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--points", type=int, default=100)
    p.add_argument(
        "--line-delays", type=float, nargs="+", default=[0.0, 1e-9, 1e-7, 1e-6, 2e-6, 3e-5]
    )
    p.add_argument("--turn", type=float, default=10.0, help="rad/s of the turning camera")
    p.add_argument("--planar-frames", type=int, default=60, help="frames per planar row (0: none)")
    p.add_argument("--drive", action="store_true", help="also the robot's drive past markers")
    p.add_argument("--rig", action="store_true", help="also a rig of three such cameras")
    p.add_argument("--real", action="store_true", help="also the D435 recording (test_23)")
    args = p.parse_args(argv)
    if args.frames < 1 or args.points < 7 or args.planar_frames < 0:
        p.error("need --frames >= 1, --points >= 7 and --planar-frames >= 0")
    print(
        f"{'frames':24s} {'p3p (deg)':>9s} {'r6p_1lin (deg)':>12s} {'ratio':>6s} "
        f"{'p3p refused':>8s} {'r6p_1lin refused':>12s} {'P3P-solved lost':>9s} "
        f"{'GS':>6s} {'RS':>7s}"
    )
    ok = True
    with one_thread():
        still = [
            make_frame(k, n_points=args.points, rs_speed=0.0, noise_px=1.0, outlier_ratio=0.2)
            for k in range(args.frames)
        ]
        for d in args.line_delays:
            ratio, lost = _row(f"at rest, {d * 1e6:g} us/line", run(d, still))
            ok &= ratio <= 1.05 and lost == 0
        d = 2e-6
        turn = np.degrees(args.turn * d * IMAGE_SIZE)  # (deg per frame readout)
        moving = [
            make_frame(
                k,
                n_points=args.points,
                rot_per_frame_deg=turn,
                trans_per_frame=0.0,
                noise_px=1.0,
                outlier_ratio=0.2,
            )
            for k in range(args.frames)
        ]
        _row(f"{args.turn:g} rad/s, {d * 1e6:g} us/line", run(d, moving))
        print(f"(a frame span is {FRAME_SPAN:.3f} in r; 1000 lines)")
        for scene in ("board", "3 tags") if args.planar_frames else ():
            still = planar_frames(scene, args.planar_frames, planar_camera(0.0), False)
            for d in args.line_delays:
                ratio, lost = _row(f"{scene} at rest, {d * 1e6:g} us", run(planar_camera(d), still))
                if d <= 2e-6:
                    ok &= ratio <= 1.05 and lost == 0
            cam = planar_camera(MOVING_LINE_DELAY)
            moving = planar_frames(scene, args.planar_frames, cam, True)
            _row(f"{scene} moving, {MOVING_LINE_DELAY * 1e6:g} us", run(cam, moving))
        if args.drive:
            camera, frames = drive_frames()
            _row(f"drive, {camera.line_delay * 1e6:g} us", run(camera, frames))
        if args.rig:
            rig_rows(args.line_delays, min(args.frames, 30))
    if args.real:
        real_d435()
    print(
        "targets at rest up to 2 us/line (ratio <= 1.05, no P3P-solved frame lost): "
        f"{'met' if ok else 'MISSED'}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
