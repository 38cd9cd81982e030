"""A real rig of fisheye cameras: ``python -m benchmarks.bench_real_rig [--folder PATH]``.

Any test folder of TagSLAM's examples (berndpfrommer/tagslam_test, Apache-2.0; not shipped
with rs_localizer): ``cameras.yaml`` (each camera's intrinsics, distortion, resolution and
detection topic ``tagtopic``), ``tagslam.yaml`` (the tags' sizes: each body's
``default_tag_size``, a tag's own ``size``, a board's ``tag_size``) and either ``json/`` (the
bags converted as ``../shared/data/real_markers/README.md`` describes) or the ROS 1 bags
``tag_detections.bag`` and ``reference.bag`` (or their ``.bz2``), read with ``rosbags``. The
default is ``test_2`` (``../shared/data/real_markers/tagslam``, its README): two PointGrey
Chameleon 1280x1024 global-shutter cameras with equidistant (fisheye) lenses on a rig, about 13
AprilTags (0.16 m) on the floor and walls. TagSLAM's ``test_5`` to ``test_8`` carry four such
cameras in a ring (front, left, back, right), ``test_14`` four at 45 degrees. The corners are
those the recording's authors detected. Reference: TagSLAM's factor-graph solution from the
same detections (the tags' poses, the cameras' extrinsics in the rig, the rig's pose per
frame), not motion capture.

The tag map is built from the reference's tag poses (each tag's transform chain composed to
``map``; corners of the tag's side in its frame, :func:`~benchmarks.tagslam_data.tag_corners`);
a rig frame is every camera's detections of one stamp when the cameras share their stamps
(TagSLAM's recordings do: the benchmark prints how many stamps carry a message of every
camera), else of the stamps within ``--stamp-tolerance`` of the rig frame's first. Prints the
corners' errors at the reference's poses (:func:`reference_residuals`: in the image and in the
undistorted plane) and how far those poses lie from the least-squares fit of their own corners
(:func:`reference_self_fit`: 0 where the reference converged on each rig frame, TagSLAM's
``optimizer_mode: slow`` of ``test_8``; its incremental ``fast`` mode of the other recordings
publishes poses off that fit, and errors against them below that level measure the
reference), then:

1. the rig: every rig frame with tags posed by the rig estimator
   (:func:`~rs_localizer.estimation.rig.estimate_rig_pose`, :data:`RIG_OPTIONS`, the
   reference's extrinsics as the mountings, every camera global shutter) and by PoseLib's
   generalized absolute pose (``estimate_generalized_absolute_pose``, the cameras'
   ``OPENCV_FISHEYE`` models, the same threshold and iteration bounds:
   :func:`~rs_localizer.experiments.references.poselib_matched_options`): the rig's rotation
   (deg) and position (mm) error against the reference, median and 90th percentile, over the
   rig frames with tags in two or more cameras that both posed; the ratio ours / PoseLib; the
   rig frames posed; CPU time per rig frame (one thread, the two methods interleaved frame by
   frame, each first on every other frame); the corners' MSAC cost at the threshold
   (:func:`msac_cost`, the cost both methods score their models by) of the two methods' poses
   and of the reference's; the camera with the most corners posed alone
   (:func:`camera_alone`) against the reference, next to the two methods on the same rig
   frames (where it is closer to the reference than both, the cameras' corners through the
   reference's extrinsics pull the rig away from the reference's pose);
2. each camera alone on the same corners: the single camera's estimator
   (:func:`~rs_localizer.estimation.estimate_rs_pose`, default options), PoseLib's
   ``estimate_absolute_pose`` (matched options) and OpenCV's ``solvePnP`` on the undistorted
   corners (``SOLVEPNP_IPPE`` when one tag is seen, ``SOLVEPNP_ITERATIVE`` otherwise; no
   RANSAC): the camera's rotation and position errors against the reference (the rig's
   reference pose through the reference extrinsics) over the frames every method posed, and
   apart those of them ours posed from a few corners on more than one plane (too few for
   RANSAC: two tags on different planes);
3. every camera's mounting calibrated from the recording (:mod:`benchmarks.real_rig_mountings`:
   :func:`~rs_localizer.calibration.calibrate_mountings`, what ``rs-localizer calibrate-rig``
   runs; the first camera the reference, at its reference extrinsics; camera frames of at least
   20 inliers, the command's default, and of at least 8) against the reference's extrinsics:
   its error (deg, mm), its stated standard deviation (norm over the three axes), and whether
   the error is within twice it; then the rig frames with tags in two or more cameras posed
   with those mountings (the first ``--min-inliers`` that calibrates), taken as exact and with their
   covariance: how many rig poses are within 3 sigma of the reference (rotation and position
   NEES, 3 degrees of freedom each, below the 99.73 % quantile).

``--reference joint`` measures everything against the recording's joint solution instead of
TagSLAM's published poses (:func:`~benchmarks.joint_reference.joint_reference`: one bundle
adjustment of every rig pose, tag pose and mounting from all the corners, started at TagSLAM's
solution in its gauge, robust loss at ``--joint-scale`` px; cached in ``--joint-cache``): its
tag map, its mountings and its rig poses replace TagSLAM's; the output first prints both
references' corner fit and how far they are apart (:func:`compare_references`).

``--extrinsics FOLDER`` compares the calibrated mountings with another recording's reference
extrinsics of the same rig too (and prints how far the two references are apart).
``--time-offsets`` calibrates each camera's time offset with its mounting (``calibrate-rig
--time-offsets``) and prints it with its standard deviation (the rig posed with the calibrated
mountings is then left out: the reference's poses are at the stamps, the offsets would move
the rig frames' times).

``--video`` (instead of 2 and 3): the recording as a user's video (:func:`video_run`): every
camera's detection messages in stamp order into a
:class:`~rs_localizer.tracking.video.Localizer` (tracking with the prediction, the fused
twist; ``--stop-after`` and ``--max-gap`` its settings): how many of its rig frames are
exactly the benchmark's (by stamp and cameras with tags); the rig frames with tags in two or
more cameras it posed and refused (by reason), against the rig frames posed alone (part 1);
how many rig frames' measurements lie beyond the :data:`GATE` chi-square quantile of the
track's prediction (their normalized innovation squared, the fused states' ``nis``);
rotation and position errors against the reference over the rig frames both posed, of the
video, the rig frame alone and PoseLib; the frames only one of the two posed, with PoseLib's
errors on them; CPU time per rig frame with tags.

    python -m benchmarks.bench_real_rig [--folder PATH] [--frames N] [--threshold 2]
        [--min-inliers 20 8] [--stamp-tolerance 0.005] [--extrinsics FOLDER] [--time-offsets]
        [--video [--stop-after S] [--max-gap S]] [--reference {tagslam,joint}]
        [--joint-cache DIR] [--joint-scale 2]
"""

from __future__ import annotations

import argparse
import time
from collections import Counter, defaultdict
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from scipy.stats import chi2

from benchmarks.joint_reference import CACHE, joint_reference, with_reference
from benchmarks.real_rig_mountings import calibrate, calibrate_estimates, calibrated_rig_run
from benchmarks.tagslam_data import FOLDER, RealRig, errors, extrinsics, load_tagslam
from rs_localizer.camera import CameraModel
from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.rig import RIG_OPTIONS, estimate_rig_pose
from rs_localizer.estimation.view import View
from rs_localizer.experiments.references import poselib_matched_options
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.tracking.fusion import FusionOptions

#: the chi-square quantile of the track's prediction the ``--video`` output counts beyond (the
#: twist filter's default gate)
GATE = FusionOptions().gate

__all__ = [
    "camera_alone",
    "compare_references",
    "msac_cost",
    "reference_residuals",
    "reference_self_fit",
    "rig_run",
    "single_run",
    "summary",
    "video_run",
]


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
    rv = [View(uv, X, rig.cameras[n], rig.mountings[n], name=n) for n, (uv, X) in views.items()]
    e = estimate_rig_pose(rv, options)
    return (e.model.R, e.model.C) if e.success else e.failure


def pixel_refit(
    rig: RealRig, views: dict, R: np.ndarray, C: np.ndarray, scale: float = 2.0, loss="huber"
):
    """``(R, C)`` refined on the distorted pixels (SciPy ``least_squares``, Huber loss at
    ``scale`` px, or ``loss``, e.g. ``"linear"``: plain least squares; every corner, none left
    out as an outlier): the cost PoseLib's final refinement minimizes on its inliers.
    Printed next to the rig estimator, whose residuals are pixels of the measured image too:
    where the two differ, the difference is the corners the estimator left out (beyond
    ``FINAL_CUTOFF`` thresholds, or the inliers' own fit kept), not the cost."""
    from scipy.optimize import least_squares

    from rs_localizer.geometry import rotvec_to_matrix

    def residuals(p, views):
        Rp, Cp = rotvec_to_matrix(p[:3]) @ R, C + p[3:]
        out = []
        for n, (uv, X) in views.items():
            Rm, cm = rig.mounts[n]
            P = (X @ Rp.T + Cp) @ Rm.T + cm
            out.append((rig.cameras[n].project(P) - uv).ravel())
        return np.concatenate(out)

    # (corners the start does not project, e.g. behind their camera, left out)
    kept = {}
    for n, (uv, X) in views.items():
        ok = np.isfinite(residuals(np.zeros(6), {n: (uv, X)}).reshape(-1, 2)).all(axis=1)
        kept[n] = (uv[ok], X[ok])
    p = least_squares(lambda q: residuals(q, kept), np.zeros(6), loss=loss, f_scale=scale).x
    return rotvec_to_matrix(p[:3]) @ R, C + p[3:]


def reference_self_fit(rig: RealRig, frames: int | None = None) -> np.ndarray:
    """How far the reference's rig poses lie from the fit of their own corners: per rig frame
    with tags in two or more cameras and a reference pose (``frames``: among the first that
    many rig frames with tags), the rotation (deg) and position (mm) from the reference's pose
    to :func:`pixel_refit` of it with plain least squares (every corner, isotropic pixel
    noise in the distorted image: the cost TagSLAM's factor graph gives a rig pose, with its
    tag map and extrinsics held). (M, 2); near 0 where the reference converged on each rig
    frame with that map; where it is not (an incremental solution published as it went),
    errors against it below this level measure the reference, not the estimator."""
    out = []
    for stamp, views in rig.frames[:frames]:
        if stamp not in rig.reference or len(views) < 2:
            continue
        ref = rig.reference[stamp]
        out.append(errors(*pixel_refit(rig, views, *ref, loss="linear"), ref))
    return np.array(out).reshape(-1, 2)


def msac_cost(rig: RealRig, views: dict, R: np.ndarray, C: np.ndarray, threshold: float) -> float:
    """The MSAC cost (px^2) of the rig pose ``(R, C)`` on a rig frame's corners: each corner's
    error in the distorted image of its camera (through the reference's extrinsics),
    ``min(e^2, threshold^2)`` summed (a corner behind its camera: ``threshold^2``). The cost
    both methods score their models by."""
    cost = 0.0
    for n, (uv, X) in views.items():
        Rm, cm = rig.mounts[n]
        P = (X @ R.T + C) @ Rm.T + cm
        e = np.linalg.norm(rig.cameras[n].project(P) - uv, axis=1)
        e = np.where(np.isfinite(e) & (P[:, 2] > 0), e, np.inf)
        cost += float(np.minimum(e * e, threshold * threshold).sum())
    return cost


def camera_alone(rig: RealRig, views: dict):
    """The rig pose ``(R, C)`` from the camera of the rig frame with the most corners posed
    alone (:func:`~rs_localizer.estimation.estimate_rs_pose`, default options), mapped to the
    rig through the reference's extrinsics; None when it fails."""
    name = max(views, key=lambda n: len(views[n][0]))
    uv, X = views[name]
    e = estimate_rs_pose(uv, X, rig.cameras[name])
    if not e.success:
        return None
    Rm, cm = rig.mounts[name]
    return Rm.T @ e.model.R, Rm.T @ (e.model.C - cm)


def _timed(fn):
    t0 = time.thread_time()
    out = fn()
    return out, time.thread_time() - t0


def rig_run(rig: RealRig, frames: int | None = None, options=RIG_OPTIONS) -> list:
    """Per rig frame with a reference pose (``frames``: the first that many rig frames with
    tags): ``both`` (tags in two or more cameras), the errors ``(rotation deg, position mm)``
    of ``ours`` (None: refused, ``failure`` its reason), ``refit`` (:func:`pixel_refit` of
    ours), ``poselib`` and ``alone`` (:func:`camera_alone`, on rig frames of two or more
    cameras; None: not posed), ``cost``: the :func:`msac_cost` of ours (nan: refused),
    PoseLib's and the reference's poses at ``options``' threshold, and the two methods' CPU
    times (s), interleaved (each first on every other rig frame); both methods on
    ``options``."""
    out = []
    warm = next(v for _, v in rig.frames if len(v) >= 2)  # (compiles the kernels: untimed)
    ours_rig(rig, warm, options)
    poselib_rig(rig, warm, options)
    for k, (stamp, views) in enumerate(rig.frames[:frames]):
        if stamp not in rig.reference:
            continue
        ref = rig.reference[stamp]
        # (the order alternates from rig frame to rig frame: what runs first meets the caches
        # the refit below left)
        if k % 2:
            (R, C), t_pl = _timed(lambda v=views: poselib_rig(rig, v, options))
            mine, t_ours = _timed(lambda v=views: ours_rig(rig, v, options))
        else:
            mine, t_ours = _timed(lambda v=views: ours_rig(rig, v, options))
            (R, C), t_pl = _timed(lambda v=views: poselib_rig(rig, v, options))
        failure = mine if isinstance(mine, str) else None
        refit = pixel_refit(rig, views, *mine) if failure is None else None
        th = options.ransac.threshold_px
        cost = (
            msac_cost(rig, views, *mine, th) if failure is None else np.nan,
            msac_cost(rig, views, R, C, th),
            msac_cost(rig, views, *ref, th),
        )
        alone = camera_alone(rig, views) if len(views) >= 2 else None
        out.append(
            {
                "stamp": stamp,
                "both": len(views) >= 2,
                "cameras": len(views),
                "failure": failure,
                "ours": errors(*mine, ref) if failure is None else None,
                "refit": errors(*refit, ref) if refit is not None else None,
                "poselib": errors(R, C, ref),
                "alone": errors(*alone, ref) if alone is not None else None,
                "cost": cost,
                "t_ours": t_ours,
                "t_poselib": t_pl,
            }
        )
    return out


def video_run(
    rig: RealRig,
    frames: int | None = None,
    options=RIG_OPTIONS,
    stop_after: float | None = None,
    max_gap: float | None = None,
) -> dict:
    """The rig's video path: every camera's detection message (its tags' corners matched to
    the map, none when it saw no tag of the map; each tag's corners one group,
    :meth:`~benchmarks.tagslam_data.RealRig.groups`) fed in stamp order into a
    :class:`~rs_localizer.tracking.video.Localizer` (the reference's extrinsics as the
    mountings, ``options``, :class:`~rs_localizer.tracking.video.LocalizerSettings`' defaults:
    tracking with the prediction and the fused twist; ``stop_after`` and the tracking's
    ``max_gap`` s when given), then ``close()`` (``frames``: up to the last of the first
    that many rig frames with tags). A rig frame of the benchmark split over two rig frames
    out is compared by its part with the most cameras with tags.

    Returns:
        ``{"rows": stamp s -> {"cameras": cameras with tags, "failure": the refusal or None,
        "path", "video": (rotation deg, position mm) or None}`` per rig frame with tags and a
        reference pose, ``"grouping": (rig frames out, rig frames out that are exactly one
        of the benchmark's by stamp and cameras with tags)``, ``"cpu_s"``: CPU time of every
        ``add`` and ``close``, ``"rig_frames"``: rig frames out, ``"with_tags"``: rig frames
        with tags fed, ``"innovations"``: ``(NIS, dimension)`` of each posed rig frame's
        measurement against the track's prediction (its fused state's ``nis``; a rig frame that
        started the track has none), ``"counts"``: the localizer's counters, ``"outputs"``: its
        :class:`~rs_localizer.tracking.video.LocalizerOutput` s, ``"settings"``}``.
    """
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.tracker import TrackerOptions
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    settings = LocalizerSettings({n: rig.mountings[n] for n in rig.cameras}, options=options)
    if stop_after is not None:
        settings = replace(settings, stop_after=stop_after)
    if max_gap is not None:
        settings = replace(settings, tracking=TrackerOptions(max_gap=max_gap))
    views_of = dict(rig.frames)
    last = rig.frames[:frames][-1][0] if rig.frames[:frames] else -np.inf
    empty = (np.zeros((0, 2)), np.zeros((0, 3)))
    video = []
    for stamp, name, group in rig.messages:
        if group > last:
            break
        uv, X = views_of.get(group, {}).get(name, empty)
        groups = rig.groups(group, name) if len(uv) else None
        stamp_ns = int(round(stamp * 1e9))
        video.append(
            CameraFrame(stamp_ns, rig.cameras[name], uv, X, tag=group, camera_name=name,
                        groups=groups)
        )  # fmt: skip
    warm = Localizer(settings)  # (compiles the tracking's kernels: untimed)
    for f in video[: 20 * len(rig.cameras)]:
        warm.add(f)
    warm.close()
    loc = Localizer(settings)
    outs, cpu = [], 0.0
    for f in video:
        got, t = _timed(lambda f=f: loc.add(f))
        outs += got
        cpu += t
    got, t = _timed(loc.close)
    outs += got
    cpu += t
    rows, exact = {}, 0
    for o in outs:
        groups = {f.tag for f in o.frames.values()}
        with_tags = {n for n, f in o.frames.items() if len(f.points2d)}
        # (the benchmark's rig frame: its stamp, or the one its frames were grouped into)
        stamp = next(iter(groups)) if len(groups) == 1 else round(o.stamp_ns * 1e-9, 6)
        exact += len(groups) == 1 and with_tags == set(views_of.get(stamp, {}))
        if stamp not in rig.reference or not with_tags:
            continue
        if stamp in rows and rows[stamp]["cameras"] >= len(with_tags):
            continue  # (a split rig frame: its part with the most cameras)
        failure = None if o.success else (o.estimate.failure if o.estimate else "error")
        rows[stamp] = {
            "cameras": len(with_tags),
            "failure": failure,
            "path": o.path,
            "video": errors(o.estimate.model.R, o.estimate.model.C, rig.reference[stamp])
            if o.success
            else None,
        }
    ests = {o.stamp_ns: o.estimate for o in outs if o.success}
    nis = [
        (f.state.nis, 12 if ests[f.pose.stamp_ns].twist_covariance is not None else 6)
        for o in outs
        for f in o.fused
        if f.state is not None and np.isfinite(f.state.nis) and f.pose.stamp_ns in ests
    ]
    return {
        "rows": rows,
        "innovations": nis,
        "grouping": (len(outs), exact),
        "cpu_s": cpu,
        "rig_frames": len(outs),
        "with_tags": len(rig.frames[:frames]),
        "counts": loc.counts,
        "outputs": outs,
        "settings": settings,
    }


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
    ``failure`` (ours: its reason, or None), ``points`` and ``few`` (ours posed it from a few
    points on more than one plane, too few for RANSAC)."""
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
                    # (posed from a few points on more than one plane, without RANSAC)
                    "few": bool(e.success and e.few_points and not e.single_tag),
                    "poselib": errors(np.asarray(pose.R), np.asarray(pose.t), ref),
                    "opencv": errors(*cv, ref) if cv is not None else None,
                }
            )
    return out


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


#: px; a reference misses a camera's corners in a rig frame beyond this (median) in
#: :func:`compare_references`' count
MISFIT_PX = 2.0


def _camera_misses(rig: RealRig, stamp: float, views: dict) -> list:
    """Each camera's median corner error (px, the image) at the reference's pose of ``stamp``."""
    R, C = rig.reference[stamp]
    out = []
    for n, (uv, X) in views.items():
        Rm, cm = rig.mounts[n]
        out.append(np.median(np.linalg.norm(rig.cameras[n].project((X @ R.T + C) @ Rm.T + cm)
                                            - uv, axis=1)))  # fmt: skip
    return out


def compare_references(rig: RealRig, other: RealRig) -> dict:
    """Two references of one recording (e.g. TagSLAM's and
    :func:`~benchmarks.joint_reference.with_reference`'s): ``"fit"``: each one's corners'
    error in the image at its own poses (px, :func:`reference_residuals`), ``(median, p90)``
    per reference; ``"poses"``: the rig poses' rotation (deg) and position (mm) differences
    over the stamps both hold, ``(median, max)`` each; ``"mounts"``: camera -> ``(deg, mm)``
    between the two mountings; ``"misfit"``: per reference, its rig frames with tags in two or
    more cameras where a camera's corners miss its pose by more than ``MISFIT_PX`` (median)."""
    fit, misfit = [], []
    for r in (rig, other):
        e = reference_residuals(r)[:, 1]
        fit.append((float(np.median(e)), float(np.percentile(e, 90))))
        misfit.append(sum(len(v) >= 2 and max(_camera_misses(r, s, v)) > MISFIT_PX
                          for s, v in r.frames if s in r.reference))  # fmt: skip
    d = np.array([errors(*other.reference[s], rig.reference[s]) for s in rig.reference
                  if s in other.reference]).reshape(-1, 2)  # fmt: skip
    mounts = {}
    for n, (R, c) in rig.mounts.items():
        R1, c1 = other.mounts[n]
        mounts[n] = (rotation_angle_deg(R, R1), 1e3 * float(np.linalg.norm(R.T @ c - R1.T @ c1)))
    return {
        "fit": fit,
        "misfit": misfit,
        "poses": (tuple(np.median(d, axis=0)), tuple(np.max(d, axis=0))),
        "mounts": mounts,
    }


def _stats(e: np.ndarray) -> str:
    return f"{np.median(e):7.3f} {np.percentile(e, 90):7.3f}"


def _ours_and_poselib(rows: list) -> str:
    """The median rotation and position errors of ``rows``' ``ours`` and ``poselib``."""
    o, p = (np.array([r[k] for r in rows]) for k in ("ours", "poselib"))
    return (
        f"ours {np.median(o[:, 0]):.3f} deg, {np.median(o[:, 1]):.1f} mm; PoseLib "
        f"{np.median(p[:, 0]):.3f} deg, {np.median(p[:, 1]):.1f} mm"
    )


def summary(res: list) -> dict:
    """Medians and 90th percentiles over the rig frames with tags in both cameras that both
    methods posed: ``{"ours": (rot (2,), pos (2,)), "poselib": ..., "posed", "both",
    "ratio_rot", "ratio_pos", "ms_ours", "ms_poselib"}`` (median CPU ms per rig frame),
    ``"cost"`` ((n, 3) :func:`msac_cost` of ours, PoseLib's and the reference's poses) and
    ``"alone"`` ((n, 2) the errors of :func:`camera_alone` with ours' and PoseLib's on the
    rig frames it posed: (n, 3, 2))."""
    both = [r for r in res if r["both"]]
    ok = [r for r in both if r["ours"] is not None]
    s = {"posed": len(ok), "both": len(both), "frames": len(res)}
    s["posed_any"] = sum(r["ours"] is not None for r in res)
    for key in ("ours", "poselib", "refit"):
        e = np.array([r[key] for r in ok])
        s[key] = e
    s["cost"] = np.array([r["cost"] for r in ok]).reshape(-1, 3)
    s["alone"] = np.array(
        [(r["alone"], r["ours"], r["poselib"]) for r in ok if r["alone"] is not None]
    ).reshape(-1, 3, 2)
    s["ratio_rot"] = np.median(s["ours"][:, 0]) / np.median(s["poselib"][:, 0])
    s["ratio_pos"] = np.median(s["ours"][:, 1]) / np.median(s["poselib"][:, 1])
    s["ratio_refit"] = (
        np.median(s["refit"][:, 0]) / np.median(s["poselib"][:, 0]),
        np.median(s["refit"][:, 1]) / np.median(s["poselib"][:, 1]),
    )
    s["ms_ours"] = 1e3 * np.median([r["t_ours"] for r in res])
    s["ms_poselib"] = 1e3 * np.median([r["t_poselib"] for r in res])
    return s


def _print_video(rig: RealRig, runs: list, v: dict, share: str) -> None:
    """The video path's table (:func:`video_run`) next to the rig frames posed alone
    (:func:`rig_run`'s ``runs``)."""
    alone = {r["stamp"]: r for r in runs}
    rows = {t: r for t, r in v["rows"].items() if r["cameras"] >= 2 and t in alone}
    posed = [t for t, r in rows.items() if r["failure"] is None]
    n_alone = sum(alone[t]["ours"] is not None for t in rows)
    out, exact = v["grouping"]
    own: dict = defaultdict(list)
    for stamp, name, _ in rig.messages:
        own[name].append(stamp)
    interval = np.median([np.median(np.diff(x)) for x in own.values() if len(x) > 1])
    print(
        f"{rig.name} video (Localizer, every camera's {len(rig.messages)} detection "
        f"messages in stamp order, a camera's frame interval {1e3 * interval:.0f} ms median; "
        f"stop_after {v['settings'].stop_after} s, max_gap {v['settings'].max_gap} s): "
        f"{out} rig frames out, {exact} of them exactly a rig frame "
        f"of the benchmark (its stamp, its cameras with tags); rig frames with tags in {share} "
        f"and a reference: posed {len(posed)} of {len(rows)} (posed alone: {n_alone})"
    )
    refused = Counter(r["failure"] for r in rows.values() if r["failure"])
    lost = Counter(
        r["failure"] for t, r in rows.items() if r["failure"] and alone[t]["ours"] is not None
    )
    gained = sum(r["failure"] is None and alone[t]["ours"] is None for t, r in rows.items())
    paths = Counter(r["path"] for r in rows.values())
    print(
        "  refused: "
        + (", ".join(f"{f} {k}" for f, k in sorted(refused.items())) or "none")
        + "; of them posed alone: "
        + (", ".join(f"{f} {k}" for f, k in sorted(lost.items())) or "none")
        + f"; posed by the video only: {gained}; paths: "
        + ", ".join(f"{p} {k}" for p, k in sorted(paths.items(), key=lambda x: str(x[0])))
    )
    inn = v["innovations"]
    beyond = sum(n > chi2.ppf(GATE, m) for n, m in inn)
    print(
        f"  the track's prediction: {beyond} of the {len(inn)} rig frames' measurements fused or "
        f"gated against it are beyond its {100 * GATE:g} % gate (normalized innovation squared)"
    )
    both = [t for t in posed if alone[t]["ours"] is not None]
    print(
        f"  over the {len(both)} rig frames both the video and the rig frame alone posed:"
        "\n                          rotation deg     position mm"
        "\n                          median   p90    median   p90"
    )
    if not both:
        return
    e = {
        "video": np.array([rows[t]["video"] for t in both]),
        "alone": np.array([alone[t]["ours"] for t in both]),
        "poselib": np.array([alone[t]["poselib"] for t in both]),
    }
    for key, label in (
        ("video", "video (Localizer)"),
        ("alone", "rig frame alone"),
        ("poselib", "PoseLib generalized"),
    ):
        print(f"  {label:22s} {_stats(e[key][:, 0])} {_stats(e[key][:, 1])}")
    gained = [t for t, r in rows.items() if r["failure"] is None and alone[t]["ours"] is None]
    lost = [t for t, r in rows.items() if r["failure"] and alone[t]["ours"] is not None]
    for ts, key, label in ((gained, "video", "posed by the video only"),
                           (lost, "ours", "refused by the video, posed alone")):  # fmt: skip
        if not ts:
            continue
        mine = np.array([rows[t]["video"] if key == "video" else alone[t]["ours"] for t in ts])
        pl = np.array([alone[t]["poselib"] for t in ts])
        print(
            f"  {label} ({len(ts)}): {_stats(mine[:, 0])} {_stats(mine[:, 1])}; PoseLib on "
            f"them {_stats(pl[:, 0])} {_stats(pl[:, 1])}"
        )
    med = {k: np.median(x, axis=0) for k, x in e.items()}
    ms_alone = 1e3 * np.mean([r["t_ours"] for r in runs])
    ms_video = 1e3 * v["cpu_s"] / max(v["with_tags"], 1)
    print(
        f"  ratio video / PoseLib (medians): rotation {med['video'][0] / med['poselib'][0]:.2f},"
        f" position {med['video'][1] / med['poselib'][1]:.2f}; video / alone: rotation "
        f"{med['video'][0] / med['alone'][0]:.2f}, position "
        f"{med['video'][1] / med['alone'][1]:.2f}"
    )
    print(
        f"  CPU ms per rig frame with tags (mean): video {ms_video:.2f} (every add and close), "
        f"alone {ms_alone:.2f}"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--folder",
        type=Path,
        default=FOLDER,
        help="a TagSLAM test folder (cameras.yaml, tagslam.yaml, json/ or the ROS 1 bags)",
    )
    ap.add_argument("--frames", type=int, default=None, help="the first N rig frames with tags")
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
    ap.add_argument(
        "--stamp-tolerance",
        type=float,
        default=None,
        help="s; group the cameras' detections into rig frames within this (default: by "
        "stamp when the cameras share their stamps, else half a frame interval)",
    )
    ap.add_argument(
        "--extrinsics",
        type=Path,
        default=None,
        help="another TagSLAM folder of the same rig: the calibrated mountings are compared "
        "with its reference extrinsics too",
    )
    ap.add_argument(
        "--time-offsets",
        action="store_true",
        help="calibrate-rig --time-offsets: each camera's time offset estimated with its "
        "mounting (printed with its std)",
    )
    ap.add_argument(
        "--video",
        action="store_true",
        help="also pose the recording as a video (Localizer: tracking, the fused twist) "
        "and compare with the rig frames posed alone; leaves out the single cameras and the "
        "calibration",
    )
    ap.add_argument(
        "--stop-after",
        type=float,
        default=None,
        help="--video: LocalizerSettings.stop_after s (default its default; a camera's frame "
        "interval at least this splits rig frames)",
    )
    ap.add_argument(
        "--max-gap",
        type=float,
        default=None,
        help="--video: the tracking's max_gap s (default its default)",
    )
    ap.add_argument(
        "--reference",
        choices=("tagslam", "joint"),
        default="tagslam",
        help="what to measure against: TagSLAM's published solution, or the joint bundle "
        "adjustment of the recording (benchmarks.joint_reference) started at it",
    )
    ap.add_argument(
        "--joint-cache",
        type=Path,
        default=CACHE,
        help="--reference joint: the folder keeping the joint solutions (reruns read them)",
    )
    ap.add_argument(
        "--joint-scale",
        type=float,
        default=2.0,
        help="--reference joint: px; the joint bundle adjustment's robust loss scale (soft_l1; "
        "a large value: plain least squares, TagSLAM's own cost)",
    )
    a = ap.parse_args(argv)
    if not a.folder.is_dir():
        print(f"{a.folder} absent: nothing to measure")
        return
    rig = load_tagslam(a.folder, a.stamp_tolerance)
    if len(rig.cameras) < 2:  # (test_22 and test_23: benchmarks.bench_single_tag's)
        print(f"{rig.name}: {len(rig.cameras)} camera, not a rig: nothing to measure here")
        return
    if a.reference == "joint":
        sol = joint_reference(rig, a.joint_cache, a.joint_scale)
        joint = with_reference(rig, sol)
        d = compare_references(rig, joint)
        (m0, p0), (m1, p1) = d["fit"]
        (rm, pm), (rx, px) = d["poses"]
        print(
            f"{rig.name} references, corners' error in the image (px) median, p90: TagSLAM's "
            f"{m0:.3f}, {p0:.3f}; the joint solution's {m1:.3f}, {p1:.3f} ({sol.info['corners']} "
            f"corners, {sol.info['outliers']} not projected at the start and left out); rig "
            f"frames with tags in two or more cameras where it misses a camera's corners by "
            f"more than {MISFIT_PX:g} px (median): TagSLAM's {d['misfit'][0]}, the joint "
            f"solution's {d['misfit'][1]}"
        )
        print(
            f"  joint vs TagSLAM: rig poses {rm:.4f} deg, {pm:.3f} mm median (max {rx:.4f} deg,"
            f" {px:.3f} mm); mountings "
            + ", ".join(f"{n} {r:.4f} deg {t:.3f} mm" for n, (r, t) in d["mounts"].items())
        )
        print("  measured below against the joint solution (its tag map, mountings, rig poses)")
        rig = joint
    n_cams = len(rig.cameras)
    share = "two or more cameras" if n_cams > 2 else "both cameras"
    how = (
        "a rig frame is one stamp"
        if rig.tolerance == 0
        else f"a rig frame is the stamps within {1e3 * rig.tolerance:.1f} ms of its first"
    )
    print(
        f"{rig.name}: {n_cams} cameras; {rig.stamps_shared[0]} of {rig.stamps_shared[1]} "
        f"stamps carry a message of every camera, {rig.stamps_shared[2]} messages are alone at "
        f"their stamp with another camera's within half a frame interval: {how}"
    )
    res = reference_residuals(rig)
    far = res[:, 0] > 400
    beyond = "no corner beyond 400 px from the centre"
    if far.any():  # (a recording whose tags stay near the image centres has none)
        beyond = (
            f"the {far.sum()} corners beyond 400 px from the centre: "
            f"{np.median(res[far, 1]):.2f} and {np.median(res[far, 2]):.2f} (p90 "
            f"{np.percentile(res[far, 1], 90):.2f} and {np.percentile(res[far, 2], 90):.2f})"
        )
    print(
        f"the reference's poses: corners' error median {np.median(res[:, 1]):.2f} px in the "
        f"image, {np.median(res[:, 2]):.2f} in the undistorted plane times the focal length; "
        f"{beyond}"
    )
    own = reference_self_fit(rig, a.frames)
    if len(own):
        print(
            f"  the reference's rig poses from the least-squares fit of their own corners "
            f"(reference_self_fit; every corner in the image, its map and extrinsics held), "
            f"{len(own)} rig frames with tags in {share}: "
            f"rotation, position {_stats(own[:, 0])} {_stats(own[:, 1])} (median, p90; 0 for a "
            f"reference converged on each rig frame: errors against it below this level "
            f"measure the reference)"
        )
    options = replace(RIG_OPTIONS, ransac=replace(RIG_OPTIONS.ransac, threshold_px=a.threshold))
    with one_thread():
        runs = rig_run(rig, a.frames, options)
        if not any(r["both"] and r["ours"] is not None for r in runs):
            print(
                f"no rig frame with tags in {share} was posed among the {len(runs)} rig frames "
                "read: nothing to compare (more with --frames)"
            )
            return
        s = summary(runs)
        print(
            f"{rig.name} rig, {s['frames']} rig frames with tags and a reference, {s['both']} "
            f"with tags in {share}: posed {s['posed']} of {s['both']} ({s['posed_any']} of "
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
        cost = s["cost"]
        c_ours, c_pl, c_ref = (np.median(cost[:, i]) for i in range(3))
        print(
            f"  the corners' MSAC cost at the threshold (px^2, distorted pixels; msac_cost), "
            f"median: ours {c_ours:.1f}, PoseLib {c_pl:.1f}, the reference's pose {c_ref:.1f}; "
            f"ours at most PoseLib's in {int(np.sum(cost[:, 0] <= cost[:, 1] + 1e-9))} of "
            f"{len(cost)} rig "
            f"frames, the reference's above both in "
            f"{int(np.sum(cost[:, 2] > np.maximum(cost[:, 0], cost[:, 1])))}"
        )
        alone = s["alone"]
        if len(alone):
            e = [f"{_stats(alone[:, k, 0])} {_stats(alone[:, k, 1])}" for k in range(3)]
            print(
                "  the camera with the most corners alone (estimate_rs_pose through the "
                f"reference's extrinsics), {len(alone)} of those rig frames: rotation, position "
                f"{e[0]}; on the same rig frames ours {e[1]}, PoseLib {e[2]}"
            )
        refused = Counter((r["cameras"], r["failure"]) for r in runs if r["failure"])
        print(
            "  refused (cameras with tags, reason): "
            + ", ".join(f"{m} {f} {k}" for (m, f), k in sorted(refused.items()))
        )
        one = [r for r in runs if r["cameras"] == 1]
        both_one = [r for r in one if r["ours"] is not None]
        if both_one:
            print(
                f"  rig frames with tags in one camera: posed {len(both_one)} of {len(one)}; "
                "median rotation, position from the reference (its fit of the same corners: "
                f"agreement, not accuracy): {_ours_and_poselib(both_one)}"
            )
        if a.video:
            v = video_run(rig, a.frames, options, a.stop_after, a.max_gap)
            _print_video(rig, runs, v, share)
            return
        single = single_run(rig, a.frames)
        for name, rows in single.items():
            ok = [r for r in rows if all(r[k] is not None for k in ("ours", "poselib", "opencv"))]
            print(
                f"{name} alone: {len(rows)} frames with tags, ours posed "
                f"{sum(r['ours'] is not None for r in rows)}; over the {len(ok)} every method "
                "posed, median (p90) rotation deg, position mm:"
            )
            if not ok:
                continue
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
            few = [r for r in ok if r["few"]]
            if few:
                print(
                    f"  of them {len(few)} posed from a few corners on more than one plane "
                    f"(too few for RANSAC), medians: {_ours_and_poselib(few)}"
                )
            refused = Counter((r["points"], r["failure"]) for r in rows if r["failure"])
            print(
                "  refused (corners, reason): "
                + ", ".join(f"{n} {f} {k}" for (n, f), k in sorted(refused.items()))
            )
        first, first_mi = None, None
        for mi in a.min_inliers:
            try:
                est = calibrate_estimates(rig, mi, time_offsets=a.time_offsets)
            except ValueError as exc:
                print(f"calibrate-rig (min_inliers {mi}): {exc}")
                continue
            if first is None:
                first, first_mi = est, mi
            for name, c in calibrate(rig, mi, est).items():
                if c is None:
                    print(
                        f"calibrate-rig (min_inliers {mi}), {name}: not calibrated (shares no "
                        "rig frame with the others)"
                    )
                    continue
                covered = c["error_deg"] <= 2 * c["std_deg"] and c["error_mm"] <= 2 * c["std_mm"]
                offset = (
                    f"; time offset {1e3 * c['time_offset']:+.1f} ms, std "
                    f"{1e3 * c['time_offset_std']:.1f} ms"
                    if np.isfinite(c["time_offset_std"])
                    else ""
                )
                print(
                    f"calibrate-rig (min_inliers {mi}), {name}'s mounting vs the reference's "
                    f"extrinsics: {c['error_deg']:.3f} deg, {c['error_mm']:.1f} mm; std "
                    f"{c['std_deg']:.3f} deg, {c['std_mm']:.1f} mm; {c['frames']} rig frames, "
                    f"{c['rejected']} camera frames rejected; error within 2 std: "
                    f"{'yes' if covered else 'no'}{offset}"
                )
        if first is not None and a.extrinsics is not None:
            other = extrinsics(a.extrinsics)
            for name, c in calibrate(rig, first_mi, first, other).items():
                if c is None:
                    continue
                R0, c0 = rig.mounts[name]
                R1, c1 = other[name]
                print(
                    f"calibrate-rig (min_inliers {first_mi}), {name}'s mounting vs "
                    f"{a.extrinsics.name}'s extrinsics: {c['error_deg']:.3f} deg, "
                    f"{c['error_mm']:.1f} mm (the two references differ by "
                    f"{rotation_angle_deg(R0, R1):.3f} deg, "
                    f"{1e3 * np.linalg.norm(R0.T @ c0 - R1.T @ c1):.1f} mm)"
                )
        if first is not None and n_cams > 2 and not a.time_offsets:
            for label, (inside, posed, total) in calibrated_rig_run(rig, first, a.frames).items():
                what = "taken as exact" if label == "exact" else "with their covariance"
                print(
                    f"the rig with the calibrated mountings (min_inliers {first_mi}) "
                    f"{what}: {inside} of {posed} rig poses within 3 sigma of the reference "
                    f"({100 * inside / max(posed, 1):.0f} %; {posed} of {total} rig frames with "
                    f"tags in {share} posed)"
                )


if __name__ == "__main__":
    main()
