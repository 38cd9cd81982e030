"""Calibrated mountings and the rig's covariance: each camera's mounting calibrated on one
synthetic rig video (calibrate_mountings; rs_localizer.sim.trajectory.generate_rig_video: the
corridor walk, 150 points per frame, 0.5 px noise, 20 % outliers), a second video (another seed)
localized with those mountings, with and without their covariance.

    python -m benchmarks.bench_rig_mountings [--cameras 3] [--calibrate 3] [--localize 10]

Prints each mounting's error against the truth and its stated std, then, for the mountings
taken as exact and with their covariance, how many rig poses are within 3 sigma of the truth:
rotation and position NEES (3 degrees of freedom each) below the 99.73 % quantile.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.stats import chi2

from rs_localizer.calibration import calibrate_mountings
from rs_localizer.frames import Mounting
from rs_localizer.geometry import matrix_to_rotvec, rotation_angle_deg
from rs_localizer.sim.trajectory import default_rig, generate_rig_video, rig_truth
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.video import Localizer, LocalizerSettings

T0 = 1_700_000_000_000_000_000


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=3)
    ap.add_argument("--calibrate", type=float, default=3.0, help="s of the calibration video")
    ap.add_argument("--localize", type=float, default=10.0, help="s of the localized video")
    a = ap.parse_args(argv)
    cams = default_rig(a.cameras)
    by = {c.name: c.camera for c in cams}
    truth = {c.name: Mounting.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}
    cal, _, _ = generate_rig_video(cams, duration=a.calibrate, num_points=150, seed=21)
    fr = [CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name) for f in cal]
    est = calibrate_mountings(fr, cams[0].name, reference_mount=truth[cams[0].name])
    for n, e in est.items():
        deg = rotation_angle_deg(e.mount.R, truth[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        print(f"{n}: error {deg:.4f} deg {mm:.2f} mm, stated std {e.std_deg:.4f} deg "
              f"{e.std_mm:.2f} mm")  # fmt: skip
    loc, _, traj = generate_rig_video(cams, duration=a.localize, num_points=150, seed=22)
    k = chi2.ppf(0.9973, 3)
    for label, exact in (("mountings taken as exact", True), ("with their covariance", False)):
        mounts = {n: Mounting(e.mount.R, e.mount.c) if exact else e.mount for n, e in est.items()}
        rig = Localizer(LocalizerSettings(mounts))
        outs = []
        for f in loc:
            outs += rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
        outs += rig.close()
        inside, er, ep = [], [], []
        for o in outs:
            if not o.success:
                continue
            m = o.estimate
            R, p, _, _ = rig_truth(traj, (o.stamp_ns - T0) * 1e-9)
            e_r = matrix_to_rotvec(m.pose.orientation @ R.T)
            e_p = m.pose.position - p
            C = m.covariance
            inside.append(
                e_r @ np.linalg.solve(C[:3, :3], e_r) <= k
                and e_p @ np.linalg.solve(C[3:6, 3:6], e_p) <= k
            )
            er.append(np.degrees(np.linalg.norm(e_r)))
            ep.append(1e3 * np.linalg.norm(e_p))
        print(f"{label}: {sum(inside)}/{len(inside)} rig poses within 3 sigma; median error "
              f"{np.median(er):.4f} deg {np.median(ep):.2f} mm")  # fmt: skip


if __name__ == "__main__":
    main()
