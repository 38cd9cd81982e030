"""Residuals in pixels of the measured image on a strong fisheye:
``python -m benchmarks.bench_pixel_residuals``.

The estimator measures each point's image error in pixels of the measured (distorted) image
(its undistorted normalized error times the lens model's pixel Jacobian at the point,
:meth:`rs_localizer.camera.CameraModel.pixel_jacobian`). This compares it, frame by frame
and interleaved in one process, with the plain error (the normalized error times the mean
focal length: every frame's whitening :attr:`~rs_localizer.estimation.frame.Frame.W` dropped)
on a simulated equidistant fisheye (1280 x 1024, f = 300 px, points up to 75 degrees
off-axis, 2-6 m away; 0.5 px Gaussian noise in the measured image, 20 % outliers moved by up
to 30 px; a rolling shutter of 30 ms per frame with random motion, or ``--global-shutter``).

Prints for each: frames posed, the rotation and position error against the simulated truth
(median, 90th percentile), the points whose inlier label differs from "true pixel error <
the threshold" (2 px), the final RMS residual over its expected value ``sigma sqrt(2)``, and
the CPU time per frame; then the median per-frame time ratio. One BLAS thread.

    python -m benchmarks.bench_pixel_residuals [--frames 60] [--points 300] [--solver r6p_1lin]
        [--global-shutter]
"""

from __future__ import annotations

import argparse
import contextlib
import time

import numpy as np

import rs_localizer.estimation.estimate as estimate_module
from rs_localizer.camera import CameraModel
from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.frame import Frame
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix

THRESHOLD_PX = 2.0  # (the default inlier threshold)
NOISE_PX = 0.5


@contextlib.contextmanager
def plain_errors():
    """Inside: the estimator scores and refines the plain errors (the normalized error times
    the mean focal length), every frame's whitening dropped."""
    prepare = estimate_module.prepare_frame

    def plain(*args, **kwargs):
        fr = prepare(*args, **kwargs)
        fr.W = Frame.W
        return fr

    estimate_module.prepare_frame = plain
    try:
        yield
    finally:
        estimate_module.prepare_frame = prepare


def fisheye(rolling: bool) -> CameraModel:
    return CameraModel(
        np.array([[300.0, 0, 640], [0, 300.0, 512], [0, 0, 1]]),
        [-0.05, 0.01, -0.002, 0.0005],
        1280,
        1024,
        distortion_model="equidistant",
        line_delay=0.03 / 1024 if rolling else 0.0,
    )


def scene(cam: CameraModel, n: int, rng):
    """Truth (R, C), measured pixels (n, 2), world points (n, 3), true pixel errors (n,)."""
    R = rotvec_to_matrix(rng.normal(0, 0.3, 3))
    C = rng.normal(0, 0.2, 3)
    ang = rng.uniform(0, np.deg2rad(75), n)
    az = rng.uniform(-np.pi, np.pi, n)
    ray = np.stack([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)], 1)
    X = (ray * rng.uniform(2, 6, n)[:, None] - C) @ R
    s = cam.seconds_per_unit_r
    uv_true = cam.project_rs(X, R, C, rng.normal(0, 1.0, 3) * s, rng.normal(0, 0.5, 3) * s)
    uv = uv_true + rng.normal(0, NOISE_PX, (n, 2))
    out = rng.random(n) < 0.2
    uv[out] += rng.uniform(-30, 30, (int(out.sum()), 2))
    return R, C, uv, X, np.linalg.norm(uv - uv_true, axis=1)


def run(frames: int, points: int, solver: str, rolling: bool) -> dict:
    """``{True (pixel residuals) / False (plain): (frames, 5) rotation deg, position mm,
    mislabelled points, RMS / expected, CPU s}`` (nan rows: refused)."""
    cam = fisheye(rolling)
    rng = np.random.default_rng(0)
    res: dict = {True: [], False: []}
    warm = 4  # (the first frames compile or load the kernels: not counted)
    for k in range(frames + warm):
        R, C, uv, X, true_e = scene(cam, points, rng)
        for pixels in (True, False) if k % 2 else (False, True):
            ctx = contextlib.nullcontext() if pixels else plain_errors()
            with ctx:
                t0 = time.process_time()
                e = estimate_rs_pose(uv, X, cam, solver=solver)
                dt = time.process_time() - t0
            if k < warm:
                continue
            if not e.success:
                res[pixels].append((np.nan,) * 4 + (dt,))
                continue
            wrong = np.count_nonzero(np.asarray(e.inliers) != (true_e < THRESHOLD_PX))
            rms = e.rmse_px / (NOISE_PX * np.sqrt(2.0))
            res[pixels].append(
                (
                    rotation_angle_deg(e.model.R, R),
                    1e3 * np.linalg.norm(e.model.C - C),
                    wrong,
                    rms,
                    dt,
                )
            )
    return {k: np.array(v) for k, v in res.items()}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--points", type=int, default=300)
    ap.add_argument("--solver", default="r6p_1lin")
    ap.add_argument("--global-shutter", action="store_true")
    a = ap.parse_args(argv)
    with one_thread():
        res = run(a.frames, a.points, a.solver, not a.global_shutter)
    for pixels in (False, True):
        r = res[pixels]
        name = "pixels of the measured image" if pixels else "plain (normalized x focal)"
        print(
            f"{name:30s} posed {np.isfinite(r[:, 0]).sum()}/{len(r)}; rotation median "
            f"{np.nanmedian(r[:, 0]):.4f} p90 {np.nanpercentile(r[:, 0], 90):.4f} deg; position "
            f"median {np.nanmedian(r[:, 1]):.2f} p90 {np.nanpercentile(r[:, 1], 90):.2f} mm; "
            f"inlier labels != true error < {THRESHOLD_PX:g} px: {np.nansum(r[:, 2]):.0f} "
            f"points; RMS / expected {np.nanmedian(r[:, 3]):.3f}; "
            f"CPU {1e3 * np.median(r[:, 4]):.2f} ms/frame"
        )
    ratio = np.median(res[True][:, 4] / res[False][:, 4])
    print(f"time per frame, pixel residuals / plain (median of per-frame ratios): {ratio:.3f}")


if __name__ == "__main__":
    main()
