"""calibrate_mountings' time offsets on a rig that stands still: not seen (a large std), the
mountings calibrated all the same."""

from __future__ import annotations

import numpy as np
from helpers.rig import mounts_of

from rs_localizer.calibration import calibrate_mountings
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.trajectory import RigTrajectory, Trajectory, default_rig, generate_rig_video
from rs_localizer.tracking.localizer import CameraFrame


def test_a_rig_that_stands_still_shows_no_time_offset():
    cams = default_rig(3)
    z = (0.0, 0.0, 0.0)
    still = RigTrajectory(Trajectory(velocity=z, sway=z, rot_amp=z, shake_amp=z))
    frames, _, _ = generate_rig_video(cams, duration=0.6, num_points=150, seed=4,
                                      trajectory=still)  # fmt: skip
    by = {c.name: c.camera for c in cams}
    fr = [CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name) for f in frames]
    mounts = mounts_of(cams)
    est = calibrate_mountings(fr, "front", reference_mount=mounts["front"],
                              estimate_time_offsets=True)  # fmt: skip
    for n in ("left", "right"):
        e = est[n]
        # (nothing to see: an offset within its std, itself 50 times a turning rig's)
        assert e.time_offset_std > 0.002 and abs(e.time_offset) < 3 * e.time_offset_std, (
            n, e.time_offset, e.time_offset_std
        )  # fmt: skip
        deg = rotation_angle_deg(e.mount.R, mounts[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - mounts[n].position)
        assert deg < 3 * e.std_deg and mm < 3 * e.std_mm, (n, deg, mm)
