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

    python -m benchmarks.bench_global_shutter [--frames 60] [--points 100]
        [--line-delays 0 1e-9 1e-7 1e-6 2e-6 3e-5] [--turn 10]
"""

from __future__ import annotations

import argparse

import numpy as np

from rs_localizer.estimation import EstimateOptions, RansacOptions, estimate_rs_pose
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.synthetic import FRAME_SPAN, IMAGE_SIZE, make_frame, paper_camera

__all__ = ["main", "run"]

SOLVERS = ("p3p", "r6p_1lin")


def run(line_delay: float, frames: list, solvers=SOLVERS) -> dict:
    """Each solver's rotation errors (deg, None for a refused frame) and motion models on
    ``frames`` seen by the protocol's camera with ``line_delay`` (s per line)."""
    camera = paper_camera(line_delay * IMAGE_SIZE)
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
    ratio = med[1] / med[0]
    print(
        f"{name:24s} {med[0]:9.4f} {med[1]:12.4f} {ratio:6.3f} {e_gs.count(None):8d} "
        f"{e_rs.count(None):12d} {lost:9d} {counts['global_shutter']:6d} "
        f"{counts['rolling_shutter']:7d}"
    )
    return ratio, lost


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
    args = p.parse_args(argv)
    if args.frames < 1 or args.points < 7:
        p.error("need --frames >= 1 and --points >= 7")
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
    print(f"targets at rest (ratio <= 1.05, no P3P-solved frame lost): {'met' if ok else 'MISSED'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
