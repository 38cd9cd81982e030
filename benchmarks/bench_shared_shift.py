"""What a marker's corners given as a group cost and give (from the repository root):
``python -m benchmarks.bench_shared_shift``.

Still frames of square tags (0.16 m, 1.5-3.5 m away, every corner 20 px inside a 640 x 480 image
with OpenCV's sample barrel distortion), each tag's 4 corners shifted together by ``--shift`` px
per axis plus ``--noise`` px of their own noise: a camera alone, global shutter (P3P's model)
and rolling shutter (R6P's), with 4, 9 and 75 tags, and a rig of three global-shutter cameras of
3 tags each. Each frame is estimated with its corners grouped by tag
(:attr:`~rs_localizer.estimation.view.View.groups`, ``estimate_rs_pose(..., groups=)``: the
covariance under the groups' shared shift) and without (every corner's error independent), in
turns (A B B A, 5 rounds), one BLAS and numba thread. Prints per case the ratio of the grouped
time to the plain one (CPU time of the one thread, ``time.thread_time``), the plain time per
frame, the median rotation (deg) and position (mm) error of the estimates against the truth,
grouped and plain, and the true pose within 3 sigma (rotation and position, 6 degrees of
freedom, 99.73 %) in either covariance. The groups change only the covariance: the estimates,
and so their errors, are the same grouped and plain (the error columns are there to show what an
estimator that uses the groups would gain).
"""

from __future__ import annotations

import argparse
import os
import time

if __name__ == "__main__":  # (the command runs on one thread; importing it changes nothing)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
from scipy.stats import chi2

from rs_localizer.camera import CameraModel
from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.estimation.rig import RIG_OPTIONS, estimate_rig_pose
from rs_localizer.estimation.view import View
from rs_localizer.frames import Mounting
from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.noise import shifted_tag_frame

K = np.array([[535.9157, 0.0, 342.2832], [0.0, 535.9157, 235.5708], [0.0, 0.0, 1.0]])
D = np.array([-0.26637, -0.038589, 0.0017832, -0.00028122, 0.23839])
Q6 = chi2.ppf(0.9973, 6)


def pose_errors(est, R, C) -> tuple[float, float]:
    """(rotation deg, position mm) of an estimate's pose from the truth ``x = R X + C``."""
    rot = np.degrees(np.linalg.norm(matrix_to_rotvec(est.model.R @ R.T)))
    return rot, 1e3 * float(np.linalg.norm(est.model.R.T @ est.model.C - R.T @ C))


def within_3_sigma(est, R, C) -> bool:
    d = np.r_[matrix_to_rotvec(est.model.R @ R.T), est.model.C - C]
    return bool(d @ np.linalg.solve(np.asarray(est.covariance)[:6, :6], d) <= Q6)


def _camera_case(camera, frames):
    def run(grouped):
        return [estimate_rs_pose(uv, X, camera, groups=g if grouped else None)
                for uv, X, g, _, _ in frames]  # fmt: skip

    return run


def _rig_case(frames):
    def run(grouped):
        out = []
        for views, _, _ in frames:
            vs = views if grouped else [View(v.uv, v.X, v.camera, v.mounting) for v in views]
            out.append(estimate_rig_pose(vs, RIG_OPTIONS))
        return out

    return run


def rig_frames(rng, camera, n, shift, noise):
    """Rig frames of three cameras (turned 0, 120 and 240 deg about y, 10 cm apart), 3 tags
    each: ``(views, R, C)`` of the rig pose ``x_rig = R X + C``."""
    mounts = [Mounting(rotvec_to_matrix(np.r_[0.0, a, 0.0]), np.r_[0.1 * k, 0.0, 0.0])
              for k, a in enumerate((0.0, 2.1, 4.2))]  # fmt: skip
    out = []
    for _ in range(n):
        R, C = rotvec_to_matrix(rng.normal(scale=0.2, size=3)), rng.normal(scale=0.2, size=3)
        views = []
        for m in mounts:
            uv, Xa, g, Ra, Ca = shifted_tag_frame(rng, camera, 3, shift, noise)
            X = ((Xa @ Ra.T + Ca - m.c) @ m.R - C) @ R  # (the camera's points on the rig)
            views.append(View(uv, X, camera, m, groups=g))
        out.append((views, R, C))
    return out


def timed(run, rounds=5):
    """CPU seconds of the grouped and the plain run, in turns (A B B A per round)."""
    t = {True: 0.0, False: 0.0}
    for _ in range(rounds):
        for grouped in (True, False, False, True):
            t0 = time.thread_time()
            run(grouped)
            t[grouped] += time.thread_time() - t0
    return t


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--frames", type=int, default=100, help="frames per case (default 100)")
    ap.add_argument("--shift", type=float, default=0.3, help="px per axis each tag's corners share")
    ap.add_argument("--noise", type=float, default=0.2, help="px per axis of each corner's own")
    a = ap.parse_args(argv)
    rng = np.random.default_rng(1)
    cases = []
    for line_delay, model in ((0.0, "global shutter"), (30e-6, "rolling shutter")):
        camera = CameraModel(K=K, D=D, width=640, height=480, line_delay=line_delay)
        for tags in (4, 9, 75):
            frames = [
                shifted_tag_frame(rng, camera, tags, a.shift, a.noise) for _ in range(a.frames)
            ]
            truth = [(R, C) for *_, R, C in frames]
            cases.append((f"camera, {model}, {tags} tags", _camera_case(camera, frames), truth))
    camera = CameraModel(K=K, D=D, width=640, height=480, line_delay=0.0)
    frames = rig_frames(rng, camera, a.frames, a.shift, a.noise)
    cases.append(("rig of 3 global-shutter cameras, 3 tags each", _rig_case(frames),
                  [(R, C) for _, R, C in frames]))  # fmt: skip
    print(f"{a.frames} frames per case, each tag shifted {a.shift} px, {a.noise} px own noise")
    for name, run, truth in cases:
        grouped, plain = run(True), run(False)
        for e, p in zip(grouped, plain, strict=True):  # (groups change only the covariance)
            assert e.success == p.success and (
                not e.success or np.array_equal(e.model.R, p.model.R)
            )
        both = [
            (e, p, R, C)
            for e, p, (R, C) in zip(grouped, plain, truth, strict=True)
            if e.success and p.success
        ]
        err = [np.median([pose_errors(b[k], R, C) for *b, R, C in both], axis=0) for k in (0, 1)]
        inside = [
            np.mean(
                [
                    within_3_sigma(e, R, C)
                    for e, (R, C) in zip(ests, truth, strict=True)
                    if e.success and e.covariance is not None
                ]
            )
            for ests in (grouped, plain)
        ]
        t = timed(run)
        print(
            f"  {name}: grouped / plain time {t[True] / t[False]:.2f} (plain "
            f"{1e3 * t[False] / (10 * a.frames):.2f} ms per frame); median error rotation "
            f"{err[0][0]:.4f} / {err[1][0]:.4f} deg ({err[0][0] / err[1][0]:.3f}x), position "
            f"{err[0][1]:.2f} / {err[1][1]:.2f} mm ({err[0][1] / err[1][1]:.3f}x) grouped / "
            f"plain ({len(both)} frames both posed); the truth within 3 sigma "
            f"{100 * inside[0]:.0f} % grouped, {100 * inside[1]:.0f} % plain"
        )


if __name__ == "__main__":
    main()
