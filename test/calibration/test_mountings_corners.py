"""calibrate_mountings on a rig of global-shutter cameras: the mountings are refined on the
corners (each corner's error in the distorted image through one rig pose per rig frame), the
optimum an independent bundle adjustment of the same corners finds; a camera whose stamps are
off from its exposures gets its time offset estimated there."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from helpers.rig import T0, mounts_of
from scipy.optimize import least_squares

from rs_localizer.calibration import calibrate_mountings
from rs_localizer.calibration import mountings as mountings_module
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.trajectory import default_camera, default_rig, generate_rig_video, rig_truth
from rs_localizer.tracking.localizer import CameraFrame


def _video():
    """1 s of three synchronized global-shutter cameras (150 points, 0.5 px noise, no
    outliers): the camera frames and the truth."""
    cams = [replace(c, camera=default_camera(line_delay=0.0)) for c in default_rig(3, (0.0,) * 4)]
    frames, _, traj = generate_rig_video(cams, duration=1.0, num_points=150, outlier_ratio=0.0,
                                         seed=5)  # fmt: skip
    by = {c.name: c.camera for c in cams}
    fr = [CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name) for f in frames]
    return cams, fr, traj


def _bundle_adjustment(fr, cams, traj):
    """The corners' optimum, solved here from the truth: every rig frame's pose and the left
    and right cameras' mountings (the front camera's given), each corner's error in the
    distorted image, soft_l1 at 2 px. Returns name -> (R_rig_cam, p_rig_cam)."""
    stamps = sorted({f.stamp_ns for f in fr})
    idx = {s: i for i, s in enumerate(stamps)}
    R0 = [rig_truth(traj, (s - T0) * 1e-9)[0] for s in stamps]
    P0 = [rig_truth(traj, (s - T0) * 1e-9)[1] for s in stamps]
    cam = {c.name: c for c in cams}
    free = ["left", "right"]

    def mount(x, n):
        c = cam[n]
        if n not in free:
            return c.R_rig_cam, c.p_rig_cam
        k = 6 * (len(stamps) + free.index(n))
        return rotvec_to_matrix(x[k : k + 3]) @ c.R_rig_cam, c.p_rig_cam + x[k + 3 : k + 6]

    def fun(x):
        out = []
        for f in fr:
            i = idx[f.stamp_ns]
            R = rotvec_to_matrix(x[6 * i : 6 * i + 3]) @ R0[i]
            p = P0[i] + x[6 * i + 3 : 6 * i + 6]
            Rm, pm = mount(x, f.camera_name)
            P = ((f.points3d - p) @ R - pm) @ Rm
            out.append((f.camera.project(P) - f.points2d).ravel())
        return np.concatenate(out)

    res = least_squares(fun, np.zeros(6 * (len(stamps) + 2)), loss="soft_l1", f_scale=2.0,
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)  # fmt: skip
    return {n: mount(res.x, n) for n in free}


def test_global_shutter_mountings_are_the_corners_optimum(monkeypatch):
    """The left and right cameras' mountings within 5e-4 deg and 0.02 mm of the independent
    bundle adjustment's (the pose-level adjustment alone is not), and of the truth within 3
    of their stated std."""
    cams, fr, traj = _video()
    truth = mounts_of(cams)
    out = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    best = _bundle_adjustment(fr, cams, traj)
    # the pose-level adjustment alone (the corners' stage left out) for comparison
    monkeypatch.setattr(mountings_module, "_refine_on_corners", lambda *a: None)
    alone = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    for n in ("left", "right"):
        Rb, pb = best[n]
        e = out[n]
        deg = rotation_angle_deg(e.mount.R.T, Rb)
        mm = 1e3 * np.linalg.norm(e.mount.position - pb)
        assert deg < 5e-4 and mm < 0.02, (n, deg, mm)
        # (which the pose-level adjustment is not: 0.001-0.004 deg, 0.16-0.20 mm off here)
        a = alone[n]
        far = (rotation_angle_deg(a.mount.R.T, Rb), 1e3 * np.linalg.norm(a.mount.position - pb))
        assert far[0] > 2e-3 or far[1] > 0.08, (n, far)
        # and the truth within 3 of the stated std
        deg_t = rotation_angle_deg(e.mount.R, truth[n].R)
        mm_t = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        assert deg_t < 3 * e.std_deg and mm_t < 3 * e.std_mm, (n, deg_t, mm_t, e)


def test_a_camera_that_exposes_apart_gets_its_time_offset_on_the_corners(monkeypatch):
    """The left camera's frames stamped 10 ms after its exposures (the others' exact): the
    video shows that offset, so the mountings are refined on the corners with a time offset
    per camera: the left camera's about -10 ms (added to its stamps; within 0.6 ms and 3 of
    its std), the right camera's within 3 of its std of 0; the mountings closer to the truth
    than the pose-level adjustment's without offsets, within 3 of their std; the estimate
    says what the pose-level adjustment saw. With exact stamps no camera shows an offset and
    none is estimated."""
    cams, fr, _ = _video()
    truth = mounts_of(cams)
    late = [replace(f, stamp_ns=f.stamp_ns + 10_000_000) if f.camera_name == "left" else f
            for f in fr]  # fmt: skip
    out = calibrate_mountings(late, "front", reference_mount=truth["front"])
    synced = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    assert all(e.corners_refined and np.isnan(e.exposure_offset) for e in synced.values())
    assert all(np.isnan(e.time_offset_std) for e in synced.values())
    assert all(e.corners_refined for e in out.values())
    left, right = out["left"], out["right"]
    assert abs(left.exposure_offset + 0.010) < 1e-3, left
    assert np.isnan(right.exposure_offset) and np.isnan(out["front"].exposure_offset)
    assert abs(left.time_offset + 0.010) < min(6e-4, 3 * left.time_offset_std), left
    assert abs(right.time_offset) < 3 * right.time_offset_std, right
    monkeypatch.setattr(mountings_module, "_refine_on_corners", lambda *a: None)
    alone = calibrate_mountings(late, "front", reference_mount=truth["front"])
    for n in ("left", "right"):
        e, a = out[n], alone[n]
        deg = rotation_angle_deg(e.mount.R, truth[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        assert deg < 3 * e.std_deg and mm < 3 * e.std_mm, (n, deg, mm, e)
        deg_a = rotation_angle_deg(a.mount.R, truth[n].R)
        mm_a = 1e3 * np.linalg.norm(a.mount.position - truth[n].position)
        assert deg < deg_a and mm < mm_a, (n, deg, deg_a, mm, mm_a)


def test_a_regrouping_that_leaves_a_camera_no_corner_is_not_taken():
    """The front and left cameras expose together, the right one 16.5 ms later (about half a
    frame: further than the 15 ms window from either front frame) but its stamps say 2.5 ms
    (14 ms early), so it starts grouped with the front camera. Regrouped at the offset the
    corners find, it would share no rig frame: that regrouping is not taken, and every
    camera's mounting and time offset are those of the last solve that saw them all, each
    with a std that covers its error against the truth (3 std; never 0)."""
    cams = [replace(c, camera=default_camera(line_delay=0.0))
            for c in default_rig(3, (0.0, 0.0, 0.0165))]  # fmt: skip
    frames, _, _ = generate_rig_video(cams, duration=1.0, num_points=150, outlier_ratio=0.0,
                                      seed=5)  # fmt: skip
    by = {c.name: c.camera for c in cams}
    early = {"right": 14_000_000}
    fr = [CameraFrame(f.stamp_ns - early.get(f.name, 0), by[f.name], f.uv, f.xyz,
                      camera_name=f.name) for f in frames]  # fmt: skip
    truth = mounts_of(cams)
    out = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    assert all(e.corners_refined for e in out.values())
    right = out["right"]
    assert abs(right.exposure_offset - 0.014) < 1e-3, right
    for n, e in out.items():
        if n == "front":
            continue
        assert e.std_deg > 0 and e.std_mm > 0 and e.time_offset_std > 0, e
        deg = rotation_angle_deg(e.mount.R, truth[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        assert deg < 3 * e.std_deg and mm < 3 * e.std_mm, (n, deg, mm, e)
        dt = e.time_offset - early.get(n, 0) * 1e-9
        assert abs(dt) < 3 * e.time_offset_std, (n, dt, e)


def test_a_camera_no_corner_constrains_keeps_its_pose_level_estimate(monkeypatch):
    """A camera with no corner left in the corners' solve (here: the right camera's corners
    dropped from it) keeps the pose-level adjustment's mounting and std, is not marked refined
    and gets no misfit; the left camera is still refined."""
    cams, fr, _ = _video()
    truth = mounts_of(cams)
    refine = mountings_module._refine_on_corners

    def without_right(rig_frames, every, *a):
        return refine(rig_frames, {**every, "right": []}, *a)

    monkeypatch.setattr(mountings_module, "_refine_on_corners", without_right)
    out = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    monkeypatch.setattr(mountings_module, "_refine_on_corners", lambda *a: None)
    alone = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    assert out["left"].corners_refined and not out["right"].corners_refined
    r, a = out["right"], alone["right"]
    assert np.isnan(r.corner_misfit) and r.std_deg == a.std_deg and r.std_mm == a.std_mm
    np.testing.assert_array_equal(r.mount.R, a.mount.R)
    np.testing.assert_array_equal(r.mount.covariance, a.mount.covariance)


def test_frames_with_few_corners_enter_the_corners_refinement():
    """Every other camera frame of the left and right cameras thinned to 10 corners (fewer
    than ``min_inliers``, so the pose-level adjustment leaves them out): the refined
    mountings are the bundle adjustment's of all the corners, thin frames included (within
    5e-4 deg and 0.02 mm), not that of the full frames alone, which lies further away; the
    truth within 3 of the stated std."""
    cams, fr, traj = _video()
    truth = mounts_of(cams)
    thin, k = [], {}
    for f in fr:
        i = k[f.camera_name] = k.get(f.camera_name, -1) + 1
        if f.camera_name != "front" and i % 2:
            f = replace(f, points2d=f.points2d[:10], points3d=f.points3d[:10])
        thin.append(f)
    out = calibrate_mountings(thin, "front", reference_mount=truth["front"], min_inliers=20)
    best = _bundle_adjustment(thin, cams, traj)
    full = _bundle_adjustment([f for f in thin if len(f.points2d) > 10], cams, traj)
    for n in ("left", "right"):
        Rb, pb = best[n]
        e = out[n]
        assert e.corners_refined
        deg = rotation_angle_deg(e.mount.R.T, Rb)
        mm = 1e3 * np.linalg.norm(e.mount.position - pb)
        assert deg < 5e-4 and mm < 0.02, (n, deg, mm)
        Rf, pf = full[n]
        assert rotation_angle_deg(Rf, Rb) > 4 * deg or np.linalg.norm(pf - pb) * 1e3 > 4 * mm
        deg_t = rotation_angle_deg(e.mount.R, truth[n].R)
        mm_t = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        assert deg_t < 3 * e.std_deg and mm_t < 3 * e.std_mm, (n, deg_t, mm_t, e)


def test_a_camera_whose_exposures_drift_gets_their_mean_and_its_scatter():
    """The left camera's frames stamped 5 ms after its exposures at the start of the video and
    15 ms at the end (a camera that runs free of the reference): its time offset is their
    mean, about -10 ms, within 3 of its std, which shows the drift (above 0.5 ms, where a
    constant offset is fixed to 0.03 ms); its mounting within 3 of its std of the truth."""
    cams, fr, _ = _video()
    truth = mounts_of(cams)
    t0, t1 = min(f.stamp_ns for f in fr), max(f.stamp_ns for f in fr)
    late = [replace(f, stamp_ns=f.stamp_ns + int(5e6 + 10e6 * (f.stamp_ns - t0) / (t1 - t0)))
            if f.camera_name == "left" else f for f in fr]  # fmt: skip
    out = calibrate_mountings(late, "front", reference_mount=truth["front"])
    left = out["left"]
    assert left.corners_refined and np.isfinite(left.exposure_offset), left
    assert abs(left.time_offset + 0.010) < 3 * left.time_offset_std, left
    assert 5e-4 < left.time_offset_std < 5e-3, left
    for n in ("left", "right"):
        e = out[n]
        deg = rotation_angle_deg(e.mount.R, truth[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        assert deg < 3 * e.std_deg and mm < 3 * e.std_mm, (n, deg, mm, e)
