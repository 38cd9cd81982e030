"""A real stereo rig: ``python -m benchmarks.bench_real_rig``.

TagSLAM's ``test_2`` (``../shared/data/real_markers/tagslam``, its README): two PointGrey
Chameleon 1280x1024 global-shutter cameras with equidistant (fisheye) lenses on a rig, about 13
AprilTags (0.16 m) on the floor and walls, the tags' corners as detected by the recording's
authors. Reference: TagSLAM's factor-graph solution from the same detections (the tags' poses,
the cameras' extrinsics in the rig, the rig's pose per frame), not motion capture.

The tag map is built from the reference's tag poses (corners of side 0.16 m in each tag's
frame, :func:`~benchmarks.bench_single_tag.tag_corners`); a rig frame is both cameras'
detections of one stamp (the two cameras share their stamps). Prints the corners' errors at
the reference's poses (:func:`reference_residuals`: in the image and in the undistorted plane),
then:

1. the rig: every rig frame with tags posed by the rig estimator
   (:func:`~rs_localizer.estimation.rig.estimate_rig_pose`, :data:`RIG_OPTIONS`, the
   reference's extrinsics as the mountings, both cameras global shutter) and by PoseLib's
   generalized absolute pose (``estimate_generalized_absolute_pose``, the cameras'
   ``OPENCV_FISHEYE`` models, the same threshold and iteration bounds:
   :func:`~rs_localizer.experiments.references.poselib_matched_options`): the rig's rotation
   (deg) and position (mm) error against the reference, median and 90th percentile, over the
   rig frames with tags in both cameras that both posed; the ratio ours / PoseLib; the rig
   frames posed; CPU time per rig frame (one thread, the two methods interleaved frame by
   frame);
2. each camera alone on the same corners: the single camera's estimator
   (:func:`~rs_localizer.estimation.estimate_rs_pose`, default options), PoseLib's
   ``estimate_absolute_pose`` (matched options) and OpenCV's ``solvePnP`` on the undistorted
   corners (``SOLVEPNP_IPPE`` when one tag is seen, ``SOLVEPNP_ITERATIVE`` otherwise; no
   RANSAC): the camera's rotation and position errors against the reference (the rig's
   reference pose through the reference extrinsics) over the frames every method posed;
3. the mounting of the second camera calibrated from the recording
   (:func:`~rs_localizer.calibration.calibrate_mountings`, what ``rs-localizer calibrate-rig``
   runs; camera frames of at least 20 inliers, the command's default, and of at least 8)
   against the reference's extrinsics: its error (deg, mm), its stated standard deviation
   (norm over the three axes), and whether the error is within twice it.

    python -m benchmarks.bench_real_rig [--frames N] [--threshold 2] [--min-inliers 20 8]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter, defaultdict
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from benchmarks.bench_single_tag import DATA, _quat_matrix, tag_corners
from rs_localizer.camera import CameraModel
from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.rig import RIG_OPTIONS, RigView, estimate_rig_pose
from rs_localizer.experiments.references import poselib_matched_options
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg

__all__ = [
    "FOLDER",
    "TAG_SIDE",
    "RealRig",
    "calibrate",
    "load_test2",
    "reference_residuals",
    "rig_run",
    "single_run",
    "summary",
]

#: the recording (absent: the benchmark says so and stops; the tests skip)
FOLDER = DATA / "test_2"
#: the tags' side (m): ``tagslam.yaml``'s ``default_tag_size``
TAG_SIDE = 0.160
#: the detection topic of each camera (``cameras.yaml``'s ``tagtopic``)
TOPICS = {"/stereo/left/tags": "cam0", "/stereo/right/tags": "cam1"}


class RealRig:
    """TagSLAM's ``test_2`` loaded (:func:`load_test2`).

    Attributes:
        cameras: name -> :class:`~rs_localizer.camera.CameraModel` (equidistant, global
            shutter).
        mounts: name -> ``(R (3, 3), c (3,) m)``: the reference's extrinsics as the rig
            estimator's mounting ``x_cam = R x_rig + c``.
        frames: ``(stamp s, {name: (uv (N, 2) px, X (N, 3) m)})`` per stamp with tags, in time
            order; a camera without tags at that stamp is absent.
        reference: stamp -> ``(R (3, 3) world -> rig, C (3,))``: TagSLAM's rig pose
            (``x_rig = R X + C``).
    """

    def __init__(self, cameras, mounts, frames, reference):
        self.cameras, self.mounts, self.frames, self.reference = cameras, mounts, frames, reference


def _pose(t: dict) -> tuple[np.ndarray, np.ndarray]:
    return _quat_matrix(t["quat_xyzw"]), np.asarray(t["translation"], dtype=float)


def load_test2(folder: Path = FOLDER) -> RealRig:
    """The cameras (``cameras.yaml``), the reference's extrinsics, tag map and rig poses, and
    every stamp's detections of tags in the map, as a :class:`RealRig`."""
    cameras = {
        "cam0": CameraModel(
            K=np.array([[470.338, 0, 620.702], [0, 470.294, 534.861], [0, 0, 1]]),
            D=[-0.0177484, -0.00281825, 0.00696388, -0.0030704],
            width=1280,
            height=1024,
            distortion_model="equidistant",
        ),
        "cam1": CameraModel(
            K=np.array([[471.126, 0, 629.016], [0, 471.106, 516.566], [0, 0, 1]]),
            D=[-0.0179247, 0.00439381, -0.000291545, -0.00076265],
            width=1280,
            height=1024,
            distortion_model="equidistant",
        ),
    }
    tf = json.loads((folder / "json" / "reference_final_tf.json").read_text())
    tags, mounts = {}, {}
    for t in tf:
        if t["parent"] == "perch" and t["child"].startswith("tag_"):
            R, p = _pose(t)  # tag -> perch (the perch is the map: the identity)
            tags[int(t["child"][4:])] = tag_corners(TAG_SIDE) @ R.T + p
        elif t["parent"] == "rig" and t["child"] in cameras:
            R, p = _pose(t)  # camera -> rig
            mounts[t["child"]] = (R.T, -R.T @ p)
    reference = {}
    for line in (folder / "json" / "reference_odom.jsonl").read_text().splitlines():
        m = json.loads(line)
        R = _quat_matrix(m["quat_xyzw"]).T  # (rig -> map, transposed)
        reference[round(m["stamp"], 6)] = (R, -R @ np.asarray(m["position"], dtype=float))
    by_stamp: dict = defaultdict(dict)
    for line in (folder / "json" / "detections.jsonl").read_text().splitlines():
        m = json.loads(line)
        known = [t for t in m["tags"] if t["id"] in tags]
        if m["topic"] not in TOPICS or not known:
            continue
        uv = np.concatenate([np.asarray(t["corners"], dtype=float) for t in known])
        X = np.concatenate([tags[t["id"]] for t in known])
        by_stamp[round(m["stamp"], 6)][TOPICS[m["topic"]]] = (uv, X)
    frames = sorted(by_stamp.items())
    return RealRig(cameras, mounts, frames, reference)


def errors(R, C, ref) -> tuple[float, float]:
    """Rotation (deg) and position (mm) error of ``x = R X + C`` against ``ref`` ``(R, C)``."""
    Rr, Cr = ref
    return rotation_angle_deg(R, Rr), 1e3 * float(np.linalg.norm(R.T @ C - Rr.T @ Cr))


def _poselib_camera(cam: CameraModel) -> dict:
    K = cam.K
    return {
        "model": "OPENCV_FISHEYE",
        "width": cam.width,
        "height": cam.height,
        "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *np.ravel(cam.D)[:4]],
    }


def poselib_rig(rig: RealRig, views: dict, options=RIG_OPTIONS):
    """PoseLib's generalized absolute pose of one rig frame: ``(R, C)`` world -> rig."""
    import poselib

    pts2, pts3, ext, cams = [], [], [], []
    for name, (uv, X) in views.items():
        e = poselib.CameraPose()
        e.R, e.t = rig.mounts[name]
        pts2.append(uv)
        pts3.append(X)
        ext.append(e)
        cams.append(_poselib_camera(rig.cameras[name]))
    pose, _ = poselib.estimate_generalized_absolute_pose(
        pts2, pts3, ext, cams, poselib_matched_options(options), {}
    )
    return np.asarray(pose.R), np.asarray(pose.t)


def ours_rig(rig: RealRig, views: dict, options=RIG_OPTIONS):
    """The rig estimator on one rig frame: ``(R, C)`` world -> rig, or its failure reason."""
    rv = [RigView(uv, X, rig.cameras[n], *rig.mounts[n], name=n) for n, (uv, X) in views.items()]
    e = estimate_rig_pose(rv, options)
    return (e.model.R, e.model.C) if e.success else e.failure


def pixel_refit(rig: RealRig, views: dict, R: np.ndarray, C: np.ndarray, scale: float = 2.0):
    """``(R, C)`` refined on the distorted pixels (SciPy ``least_squares``, Huber loss at
    ``scale`` px, every corner): the cost PoseLib minimizes. Printed next to the rig estimator
    to show how much of the gap to PoseLib is the estimator's cost (errors in the undistorted
    image plane times the focal length, which stretch a fisheye lens's radial errors towards
    the image's edge) rather than its search."""
    from scipy.optimize import least_squares

    from rs_localizer.geometry import rotvec_to_matrix

    def residuals(p):
        Rp, Cp = rotvec_to_matrix(p[:3]) @ R, C + p[3:]
        out = []
        for n, (uv, X) in views.items():
            Rm, cm = rig.mounts[n]
            P = (X @ Rp.T + Cp) @ Rm.T + cm
            out.append((rig.cameras[n].project(P) - uv).ravel())
        return np.concatenate(out)

    p = least_squares(residuals, np.zeros(6), loss="huber", f_scale=scale).x
    return rotvec_to_matrix(p[:3]) @ R, C + p[3:]


def _timed(fn):
    t0 = time.thread_time()
    out = fn()
    return out, time.thread_time() - t0


def rig_run(rig: RealRig, frames: int | None = None, options=RIG_OPTIONS) -> list:
    """Per rig frame with a reference pose (``frames``: the first that many stamps with
    tags): ``both`` (tags in both cameras), the errors ``(rotation deg, position mm)`` of
    ``ours`` (None: refused, ``failure`` its reason), ``refit`` (:func:`pixel_refit` of ours)
    and ``poselib``, and their CPU times (s), interleaved; both methods on ``options``."""
    out = []
    warm = next(v for _, v in rig.frames if len(v) == 2)  # (compiles the kernels: untimed)
    ours_rig(rig, warm, options)
    poselib_rig(rig, warm, options)
    for stamp, views in rig.frames[:frames]:
        if stamp not in rig.reference:
            continue
        ref = rig.reference[stamp]
        mine, t_ours = _timed(lambda v=views: ours_rig(rig, v, options))
        (R, C), t_pl = _timed(lambda v=views: poselib_rig(rig, v, options))
        failure = mine if isinstance(mine, str) else None
        refit = pixel_refit(rig, views, *mine) if failure is None else None
        out.append(
            {
                "both": len(views) == 2,
                "cameras": len(views),
                "failure": failure,
                "ours": errors(*mine, ref) if failure is None else None,
                "refit": errors(*refit, ref) if refit is not None else None,
                "poselib": errors(R, C, ref),
                "t_ours": t_ours,
                "t_poselib": t_pl,
            }
        )
    return out


def opencv_pnp(uv: np.ndarray, X: np.ndarray, cam: CameraModel):
    """OpenCV's ``solvePnP`` on the undistorted corners: IPPE for one tag (4 coplanar
    corners), iterative (Levenberg-Marquardt from OpenCV's own start) otherwise."""
    x = cam.undistort(uv)
    flag = cv2.SOLVEPNP_IPPE if len(uv) == 4 else cv2.SOLVEPNP_ITERATIVE
    ok, rvec, tvec = cv2.solvePnP(np.ascontiguousarray(X), x, np.eye(3), None, flags=flag)
    return (cv2.Rodrigues(rvec)[0], np.ravel(tvec)) if ok else None


def single_run(rig: RealRig, frames: int | None = None) -> dict:
    """Each camera alone, every frame of it with a reference pose: camera name -> list of
    ``{method: (rotation deg, position mm) or None}`` (``ours``, ``poselib``, ``opencv``) and
    ``failure`` (ours: its reason, or None) and ``points``."""
    import poselib

    out: dict = {n: [] for n in rig.cameras}
    for stamp, views in rig.frames[:frames]:
        if stamp not in rig.reference:
            continue
        Rr, Cr = rig.reference[stamp]
        for name, (uv, X) in views.items():
            Rm, cm = rig.mounts[name]
            ref = (Rm @ Rr, Rm @ Cr + cm)
            cam = rig.cameras[name]
            e = estimate_rs_pose(uv, X, cam)
            pose, _ = poselib.estimate_absolute_pose(
                uv, X, _poselib_camera(cam), poselib_matched_options(RIG_OPTIONS), {}
            )
            cv = opencv_pnp(uv, X, cam)
            out[name].append(
                {
                    "ours": errors(e.model.R, e.model.C, ref) if e.success else None,
                    "failure": None if e.success else e.failure,
                    "points": len(uv),
                    "poselib": errors(np.asarray(pose.R), np.asarray(pose.t), ref),
                    "opencv": errors(*cv, ref) if cv is not None else None,
                }
            )
    return out


def calibrate(rig: RealRig, min_inliers: int = 8) -> dict:
    """The second camera's mounting from the recording (every camera frame with tags, as
    ``calibrate-rig`` reads them; ``cam0`` the rig frame) against the reference's:
    ``{"error_deg", "error_mm", "std_deg", "std_mm", "frames", "rejected"}``."""
    from rs_localizer.calibration import calibrate_mountings
    from rs_localizer.tracking.rig import RigCameraFrame

    cam_frames = [
        RigCameraFrame(n, int(round(stamp * 1e9)), rig.cameras[n], uv, X)
        for stamp, views in rig.frames
        for n, (uv, X) in views.items()
    ]
    est = calibrate_mountings(cam_frames, "cam0", min_inliers=min_inliers)["cam1"]
    R, c = rig.mounts["cam1"]
    err_deg = rotation_angle_deg(est.mount.R, R)
    err_mm = 1e3 * float(np.linalg.norm(est.mount.R.T @ est.mount.c - R.T @ c))
    return {
        "error_deg": err_deg,
        "error_mm": err_mm,
        "std_deg": est.std_deg,
        "std_mm": est.std_mm,
        "frames": est.frames,
        "rejected": est.rejected,
    }


def reference_residuals(rig: RealRig) -> np.ndarray:
    """Every corner of the stamps with a reference pose, projected with the reference's poses:
    (N, 3) its distance from the principal point (px), its error in the image (distorted px)
    and in the undistorted image plane times the focal length (the estimator's residual)."""
    rows = []
    for stamp, views in rig.frames:
        if stamp not in rig.reference:
            continue
        R, C = rig.reference[stamp]
        for name, (uv, X) in views.items():
            cam = rig.cameras[name]
            Rm, cm = rig.mounts[name]
            P = (X @ R.T + C) @ Rm.T + cm
            px = np.linalg.norm(cam.project(P) - uv, axis=1)
            und = cam.mean_focal * np.linalg.norm(P[:, :2] / P[:, 2:] - cam.undistort(uv), axis=1)
            rows.append(np.column_stack([np.linalg.norm(uv - cam.K[:2, 2], axis=1), px, und]))
    return np.concatenate(rows)


def _stats(e: np.ndarray) -> str:
    return f"{np.median(e):7.3f} {np.percentile(e, 90):7.3f}"


def summary(res: list) -> dict:
    """Medians and 90th percentiles over the rig frames with tags in both cameras that both
    methods posed: ``{"ours": (rot (2,), pos (2,)), "poselib": ..., "posed", "both",
    "ratio_rot", "ratio_pos", "ms_ours", "ms_poselib"}`` (median CPU ms per rig frame)."""
    both = [r for r in res if r["both"]]
    ok = [r for r in both if r["ours"] is not None]
    s = {"posed": len(ok), "both": len(both), "frames": len(res)}
    s["posed_any"] = sum(r["ours"] is not None for r in res)
    for key in ("ours", "poselib", "refit"):
        e = np.array([r[key] for r in ok])
        s[key] = e
    s["ratio_rot"] = np.median(s["ours"][:, 0]) / np.median(s["poselib"][:, 0])
    s["ratio_pos"] = np.median(s["ours"][:, 1]) / np.median(s["poselib"][:, 1])
    s["ratio_refit"] = (
        np.median(s["refit"][:, 0]) / np.median(s["poselib"][:, 0]),
        np.median(s["refit"][:, 1]) / np.median(s["poselib"][:, 1]),
    )
    s["ms_ours"] = 1e3 * np.median([r["t_ours"] for r in res])
    s["ms_poselib"] = 1e3 * np.median([r["t_poselib"] for r in res])
    return s


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=None, help="the first N stamps with tags")
    ap.add_argument(
        "--threshold", type=float, default=2.0, help="inlier threshold (px) of both methods"
    )
    ap.add_argument(
        "--min-inliers",
        type=int,
        nargs="+",
        default=[20, 8],
        help="calibrate-rig: fewest inliers of a camera frame used (20: the command's default)",
    )
    a = ap.parse_args(argv)
    if not FOLDER.is_dir():
        print(f"{FOLDER} absent: nothing to measure")
        return
    rig = load_test2(FOLDER)
    res = reference_residuals(rig)
    far = res[:, 0] > 400
    print(
        f"the reference's poses: corners' error median {np.median(res[:, 1]):.2f} px in the "
        f"image, {np.median(res[:, 2]):.2f} in the undistorted plane times the focal length; "
        f"the {far.sum()} corners beyond 400 px from the centre: {np.median(res[far, 1]):.2f}"
        f" and {np.median(res[far, 2]):.2f} (p90 {np.percentile(res[far, 1], 90):.2f} and "
        f"{np.percentile(res[far, 2], 90):.2f})"
    )
    options = replace(RIG_OPTIONS, ransac=replace(RIG_OPTIONS.ransac, threshold_px=a.threshold))
    with one_thread():
        runs = rig_run(rig, a.frames, options)
        s = summary(runs)
        print(
            f"test_2 rig, {s['frames']} rig frames with tags and a reference, {s['both']} with "
            f"tags in both cameras: posed {s['posed']} of {s['both']} ({s['posed_any']} of "
            f"{s['frames']} in all)"
        )
        print("                      rotation deg     position mm    median ms/rig frame")
        print("                      median   p90    median   p90")
        for key, name in (("ours", "rig estimator"), ("poselib", "PoseLib generalized")):
            e = s[key]
            print(f"  {name:20s} {_stats(e[:, 0])} {_stats(e[:, 1])}  {s['ms_' + key]:7.2f}")
        e = s["refit"]
        print(f"  {'ours, pixel refit':20s} {_stats(e[:, 0])} {_stats(e[:, 1])}")
        print(
            f"  ratio ours / PoseLib (medians): rotation {s['ratio_rot']:.2f}, position "
            f"{s['ratio_pos']:.2f}; time {s['ms_ours'] / s['ms_poselib']:.1f}x; refit on the "
            f"distorted pixels / PoseLib: rotation {s['ratio_refit'][0]:.2f}, position "
            f"{s['ratio_refit'][1]:.2f}"
        )
        refused = Counter((r["cameras"], r["failure"]) for r in runs if r["failure"])
        print(
            "  refused (cameras with tags, reason): "
            + ", ".join(f"{m} {f} {k}" for (m, f), k in sorted(refused.items()))
        )
        single = single_run(rig, a.frames)
        for name, rows in single.items():
            ok = [r for r in rows if all(r[k] is not None for k in ("ours", "poselib", "opencv"))]
            print(
                f"{name} alone: {len(rows)} frames with tags, ours posed "
                f"{sum(r['ours'] is not None for r in rows)}; over the {len(ok)} every method "
                "posed, median (p90) rotation deg, position mm:"
            )
            for key, label in (
                ("ours", "estimate_rs_pose"),
                ("poselib", "PoseLib absolute"),
                ("opencv", "OpenCV solvePnP"),
            ):
                e = np.array([r[key] for r in ok])
                print(
                    f"  {label:18s} {np.median(e[:, 0]):.3f} ({np.percentile(e[:, 0], 90):.3f})"
                    f"  {np.median(e[:, 1]):.1f} ({np.percentile(e[:, 1], 90):.1f})"
                )
            refused = Counter((r["points"], r["failure"]) for r in rows if r["failure"])
            print(
                "  refused (corners, reason): "
                + ", ".join(f"{n} {f} {k}" for (n, f), k in sorted(refused.items()))
            )
        for mi in a.min_inliers:
            c = calibrate(rig, mi)
            covered = c["error_deg"] <= 2 * c["std_deg"] and c["error_mm"] <= 2 * c["std_mm"]
            print(
                f"calibrate-rig (min_inliers {mi}), cam1's mounting vs the reference's "
                f"extrinsics: {c['error_deg']:.3f} deg, {c['error_mm']:.1f} mm; std "
                f"{c['std_deg']:.3f} deg, {c['std_mm']:.1f} mm; {c['frames']} rig frames, "
                f"{c['rejected']} camera frames rejected; error within 2 std: "
                f"{'yes' if covered else 'no'}"
            )


if __name__ == "__main__":
    main()
