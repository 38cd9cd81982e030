"""A rig of unsynchronized RS cameras through a video: the rig (Localizer) against each
camera alone (SequenceLocalizer, its pose mapped to the rig by its mounting), on the synthetic rig
walk of rs_localizer.sim.trajectory.generate_rig_video (a corridor, turning up to ~1.7 rad/s, 20 %
outliers, 0.5 px noise, cameras 4 ms apart).

    python -m benchmarks.bench_rig_video [--cameras 3] [--seconds 2] [--points 300]
        [--implementations compiled numpy] [--repeats 3]

Prints the median rotation (deg) and position (mm) error of the rig's pose, of its own and
fused twist (rad/s, m/s), for the rig and for each camera alone, and the time per rig frame
(wall clock and processor time: on a loaded machine the latter is the steadier).
``--implementations``: the rig on each of the rig estimator's implementations
(``estimate_rig_pose``'s ``implementation``: ``numpy`` is what a rig node's frames take while
its kernels compile in the background; tracked as on ``compiled``), run in turn ``--repeats``
times (interleaved), each row the median over the repeats of its time per rig frame.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.trajectory import default_rig, generate_rig_video, rig_truth
from rs_localizer.tracking import CameraFrame, SequenceLocalizer
from rs_localizer.tracking.video import Localizer, LocalizerSettings

T0 = 1_700_000_000_000_000_000


def _errors(traj, stamp_ns, Ori, p, w=None, v=None):
    R, pt, wt, vt = rig_truth(traj, (stamp_ns - T0) * 1e-9)
    out = [rotation_angle_deg(Ori, R), 1e3 * np.linalg.norm(p - pt)]
    if w is not None:
        out += [np.linalg.norm(w - wt), np.linalg.norm(v - vt)]
    return out


def _rig_run(frames, by, mounts, traj, implementation):
    """The rig video through a Localizer on ``implementation``: (own errors, fused errors,
    wall s, processor s, rig frames, rig frames posed, rig frames tracked)."""
    rig = Localizer(LocalizerSettings(mounts), implementation=lambda: implementation)
    own, fused, t0, c0 = [], [], time.perf_counter(), time.process_time()
    for f in frames:
        for o in rig.add(
            CameraFrame(f.stamp_ns, by[f.name].camera, f.uv, f.xyz, camera_name=f.name)
        ):
            if o.success:
                q = o.estimate.pose
                own.append(_errors(traj, o.stamp_ns, q.orientation, q.position,
                                   q.angular_velocity, q.linear_velocity))  # fmt: skip
            fused += o.fused
    outs = rig.close()
    fused += [f for o in outs for f in o.fused] + rig.flush()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    fz = [_errors(traj, f.pose.stamp_ns, f.pose.orientation, f.pose.position,
                  f.pose.angular_velocity, f.pose.linear_velocity) for f in fused]  # fmt: skip
    r = rig.rig_counts()
    return own, fz, seconds, cpu, r["rig_frames"], r["solved"], rig.counts["rig.path.tracked"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--points", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--implementations", nargs="+", default=["compiled"],
                    choices=["compiled", "numpy"])  # fmt: skip
    ap.add_argument("--repeats", type=int, default=1)
    a = ap.parse_args(argv)
    cams = default_rig(a.cameras)
    frames, _, traj = generate_rig_video(cams, a.seconds, a.points, seed=a.seed)
    by = {c.name: c for c in cams}
    mounts = {c.name: Mounting.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}
    # warm-up (compiled kernels; the NumPy implementation's first calls into SciPy)
    for impl in a.implementations:
        warm = Localizer(LocalizerSettings(mounts), implementation=lambda impl=impl: impl)
        for f in frames[: 3 * a.cameras]:
            warm.add(CameraFrame(f.stamp_ns, by[f.name].camera, f.uv, f.xyz, camera_name=f.name))
    runs = {impl: [] for impl in a.implementations}
    for _ in range(max(a.repeats, 1)):  # (interleaved: each implementation in turn)
        for impl in a.implementations:
            runs[impl].append(_rig_run(frames, by, mounts, traj, impl))
    n_rig = next(iter(runs.values()))[0][4]
    print(f"{a.cameras} cameras x {a.points} correspondences, {a.seconds:.1f} s, {n_rig} rig "
          f"frames, {max(a.repeats, 1)} run(s) per implementation")  # fmt: skip
    print("                    rot deg   pos mm   w rad/s  v m/s (own)  w rad/s  v m/s (fused)"
          "   ms/rig frame (processor)")  # fmt: skip
    for impl, rr in runs.items():
        own, fz, _, _, n_rig, solved, tracked = rr[0]
        wall = np.median([r[2] for r in rr]) / n_rig
        cpu = np.median([r[3] for r in rr]) / n_rig
        m = np.median(own, axis=0)
        mf = np.median(fz, axis=0) if fz else np.full(4, np.nan)
        print(f"rig ({impl:8s})    {m[0]:8.4f} {m[1]:8.2f} {m[2]:9.4f} {m[3]:7.3f}"
              f"      {mf[2]:9.4f} {mf[3]:7.3f}   {1e3 * wall:6.1f} ({1e3 * cpu:.1f})"
              f"   [{solved}/{n_rig} posed, {tracked} tracked, {len(fz)} fused]")  # fmt: skip
    for c in cams:
        seq = SequenceLocalizer()
        e, ef = [], []
        for f in frames:
            if f.name != c.name:
                continue
            out = seq.process(CameraFrame(f.stamp_ns, c.camera, f.uv, f.xyz))
            est = out.estimate
            for g in out.fused:  # (the camera's fused twist, turned into the rig frame)
                q = g.pose
                Ori = q.orientation @ c.R_rig_cam.T
                wr = c.R_rig_cam @ q.angular_velocity
                vr = c.R_rig_cam @ q.linear_velocity - np.cross(wr, c.p_rig_cam)
                ef.append(_errors(traj, q.stamp_ns, Ori, q.position - Ori @ c.p_rig_cam, wr, vr))
            if est is None or not est.success:
                continue
            Ori = est.pose.orientation @ c.R_rig_cam.T
            wr = c.R_rig_cam @ est.pose.angular_velocity
            vr = c.R_rig_cam @ est.pose.linear_velocity - np.cross(wr, c.p_rig_cam)
            e.append(
                _errors(traj, out.stamp_ns, Ori, est.pose.position - Ori @ c.p_rig_cam, wr, vr)
            )
        m = np.median(e, axis=0)
        mf = np.median(ef, axis=0) if ef else np.full(4, np.nan)
        print(f"{c.name + ' alone':17s} {m[0]:8.4f} {m[1]:8.2f} {m[2]:9.4f} {m[3]:7.3f}"
              f"      {mf[2]:9.4f} {mf[3]:7.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
