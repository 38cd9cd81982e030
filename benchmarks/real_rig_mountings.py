"""A TagSLAM recording's mountings calibrated as ``rs-localizer calibrate-rig`` calibrates
them (:func:`calibrate_estimates`, :func:`calibrate_every_camera`), measured against a
reference's extrinsics (:func:`calibrate`), and the rig posed with them, its poses within 3
sigma of the reference's (:func:`calibrated_rig_run`, :func:`within_3_sigma`): part 3 of
:mod:`benchmarks.bench_real_rig`, which :mod:`benchmarks.joint_reference`,
:mod:`benchmarks.gtsam_reference`, :mod:`benchmarks.held_out` and
:mod:`benchmarks.reference_fit` run too.
"""

from __future__ import annotations

import numpy as np

from benchmarks.tagslam_data import RealRig
from rs_localizer.estimation.rig import RIG_OPTIONS, estimate_rig_pose
from rs_localizer.frames import Mounting
from rs_localizer.geometry import matrix_to_rotvec, rotation_angle_deg

__all__ = [
    "TRACKED_GAP",
    "calibrate",
    "calibrate_estimates",
    "calibrate_every_camera",
    "calibrated_rig_run",
    "within_3_sigma",
]


def calibrate_estimates(
    rig: RealRig, min_inliers: int = 8, reference: str | None = None, time_offsets: bool = False
):
    """Every camera's mounting from the recording (every camera frame with tags, as
    ``calibrate-rig`` reads them, each tag's corners one group,
    :meth:`~benchmarks.tagslam_data.RealRig.groups`; ``reference``, default the first camera,
    at its reference extrinsics): :func:`~rs_localizer.calibration.calibrate_mountings`'s result
    (``time_offsets``: with each camera's time offset estimated, ``calibrate-rig
    --time-offsets``)."""
    from rs_localizer.calibration import calibrate_mountings
    from rs_localizer.tracking.localizer import CameraFrame

    ref = reference or next(iter(rig.cameras))
    cam_frames = [
        CameraFrame(
            int(round(stamp * 1e9)),
            rig.cameras[n],
            uv,
            X,
            camera_name=n,
            groups=rig.groups(stamp, n),
        )
        for stamp, views in rig.frames
        for n, (uv, X) in views.items()
    ]
    return calibrate_mountings(
        cam_frames,
        ref,
        reference_mount=rig.mountings[ref],
        min_inliers=min_inliers,
        estimate_time_offsets=time_offsets,
    )


def calibrate(
    rig: RealRig, min_inliers: int = 8, estimates: dict | None = None, mounts: dict | None = None
) -> dict:
    """Each camera's calibrated mounting (:func:`calibrate_estimates`, or ``estimates``)
    against the reference's (or ``mounts``, e.g. :func:`~benchmarks.tagslam_data.extrinsics`):
    camera -> ``{"error_deg", "error_mm", "std_deg", "std_mm", "frames", "rejected",
    "time_offset", "time_offset_std"}`` (the
    reference camera left out; a camera the calibration did not reach: None).
    ``calibrate(rig)["cam1"]`` is a stereo rig's second camera."""
    est = estimates if estimates is not None else calibrate_estimates(rig, min_inliers)
    mounts = rig.mounts if mounts is None else mounts
    out = {}
    for i, name in enumerate(rig.cameras):
        if i == 0:
            continue
        if name not in est or name not in mounts:
            out[name] = None
            continue
        e = est[name]
        R, c = mounts[name]
        out[name] = {
            "error_deg": rotation_angle_deg(e.mount.R, R),
            "error_mm": 1e3 * float(np.linalg.norm(e.mount.R.T @ e.mount.c - R.T @ c)),
            "std_deg": e.std_deg,
            "std_mm": e.std_mm,
            "frames": e.frames,
            "rejected": e.rejected,
            "time_offset": e.time_offset,
            "time_offset_std": e.time_offset_std,
        }
    return out


#: s; a tracker's twist from two posed rig frames at most this far apart and from the frame
TRACKED_GAP = 0.25


def _tracked_twist(last: list, stamp: float) -> tuple | None:
    """The rig's twist ``(w rad/s, t m/s)`` in the model's convention (``x_rig = expm(tau
    [w]x) R X + C + tau t``) at constant velocity from the last two posed rig frames
    ``last`` (``(stamp s, model)``), None without two within :data:`TRACKED_GAP` of each other
    and of ``stamp``."""
    if len(last) < 2:
        return None
    (s0, m0), (s1, m1) = last
    dt = s1 - s0
    if not (0 < dt <= TRACKED_GAP and stamp - s1 <= TRACKED_GAP):
        return None
    return matrix_to_rotvec(m1.R @ m0.R.T) / dt, (m1.C - m0.C) / dt


def calibrate_every_camera(rig: RealRig, min_inliers=(20, 8), failed=None) -> tuple:
    """:func:`calibrate_estimates` with the first of ``min_inliers`` that calibrates every
    camera of ``rig``: ``(estimates, that min_inliers)``; when none does, the last that
    calibrated some (its estimates lack cameras); ``(None, None)`` when each raised.
    ``failed(min_inliers, exc)``, if given, hears each ValueError raised."""
    est, used = None, None
    for mi in min_inliers:
        try:
            est, used = calibrate_estimates(rig, mi), mi
        except ValueError as exc:
            if failed is not None:
                failed(mi, exc)
            continue
        if len(est) == len(rig.cameras):
            break
    return est, used


def within_3_sigma(cov: np.ndarray, R: np.ndarray, C: np.ndarray, ref: tuple) -> bool:
    """The rig pose ``x_rig = R X + C`` within 3 sigma of ``ref`` ``(R, C)`` in ``cov`` (its
    first 6 rows and columns: rotation (rig -> world, world axes), position (world)): the
    rotation's and the position's NEES (3 degrees of freedom each) below the 99.73 % quantile
    of a chi-square of 3."""
    from scipy.stats import chi2

    k = chi2.ppf(0.9973, 3)
    Rr, Cr = ref
    e_r = matrix_to_rotvec(R.T @ Rr)  # (rig -> world, world axes)
    e_p = Rr.T @ Cr - R.T @ C  # (the position's error, world)
    return bool(
        e_r @ np.linalg.solve(cov[:3, :3], e_r) <= k
        and e_p @ np.linalg.solve(cov[3:6, 3:6], e_p) <= k
    )


def calibrated_rig_run(rig: RealRig, estimates: dict, frames: int | None = None) -> dict:
    """The rig frames with tags in two or more cameras and a reference pose, posed by the rig
    estimator with the calibrated mountings (``estimates``: camera -> ``MountingEstimate``)
    taken as exact (``"exact"``) and with their covariance and time offset std
    (``"covariance"``; the rig's twist for the offsets' share, :func:`_tracked_twist`, from
    the two rig frames posed before, as a tracker predicts it): per variant ``(poses within
    3 sigma of the reference, poses, rig frames)``; within 3 sigma: the rotation's and the
    position's NEES (3 degrees of freedom each) below the 99.73 % quantile
    (:func:`within_3_sigma`)."""
    out = {}
    for label, exact in (("exact", True), ("covariance", False)):
        inside = posed = total = 0
        last: list = []  # (the last two posed rig frames: stamp, model)
        for stamp, views in rig.frames[:frames]:
            if stamp not in rig.reference or len(views) < 2:
                continue
            if any(n not in estimates for n in views):
                continue
            total += 1
            mountings = {}
            for n in views:
                e = estimates[n]
                m = Mounting(e.mount.R, e.mount.c)
                s_t = e.time_offset_std if e.time_offset and np.isfinite(e.time_offset_std) else 0
                mountings[n] = m if exact else Mounting(m.R, m.c, e.mount.covariance, s_t)
            rv = rig.views(stamp, views, mountings)
            e = estimate_rig_pose(rv, RIG_OPTIONS, twist=_tracked_twist(last, stamp))
            if not e.success or e.covariance is None:
                continue
            last = [*last[-1:], (stamp, e.model)]
            posed += 1
            inside += within_3_sigma(e.covariance, e.model.R, e.model.C, rig.reference[stamp])
        out[label] = (inside, posed, total)
    return out
