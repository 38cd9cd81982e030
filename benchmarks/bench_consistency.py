"""Fit consistency: ``python -m benchmarks.bench_consistency``.

Correspondences that no camera can produce can still be fitted well on a part of the points:
a plane seen from behind is its own mirror image, so a mirrored image, a map reflected through
the camera or a map in a mirrored frame explains one wall of a 3D scene exactly, from outside
the scene, with a small reported covariance. The estimator refuses such fits
(``inconsistent_fit``: :func:`rs_localizer.estimation.finalize.final_estimate`). This
benchmark (data from :mod:`rs_localizer.sim.attacks`) counts, per solver:

- on garbage (every row of a frame edited, :data:`ATTACKS`; and the paper protocol's frames
  with 300 points, every 3D point reflected through the camera centre: at 1 px noise, without
  noise, and of a still camera at 0.2 px noise): the frames that still
  give a success (must be 0), how many were refused as ``inconsistent_fit`` (the rest fail on
  earlier checks) and how many would succeed without that check
  (``PlausibilityOptions(consistent_fit=False)``);
- on true data (:data:`TRUE_SETS`: the ``make-bag`` corridor with 20 % and 70 % outliers and
  1 px noise, the paper protocol's frames at 1 px noise, a 300-point plane and a 42-corner board
  at 30 % outliers): successes, and the frames refused as ``inconsistent_fit`` (false rejects;
  must be 0).

    python -m benchmarks.bench_consistency [--frames 120] [--solvers r6p_1lin p3p]
"""

from __future__ import annotations

import argparse

from rs_localizer.experiments.timing import one_thread
from rs_localizer.sim.attacks import (
    ATTACKS,
    TRUE_SETS,
    attack,
    corridor_frames,
    count,
    protocol_frames,
)

__all__ = ["main"]

#: the reflected paper-protocol rows: (name, pixel noise (px), RS speed)
REFLECTED_PROTOCOL = (
    ("garbage: reflected, paper protocol", 1.0, 0.5),
    ("garbage: reflected, protocol, exact", 0.0, 0.5),
    ("garbage: reflected, still, 0.2 px", 0.2, 0.0),
)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_consistency",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--frames", type=int, default=120, help="frames per set")
    p.add_argument("--solvers", nargs="+", default=["r6p_1lin", "p3p"])
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.frames < 1:
        p.error("--frames must be >= 1")
    garbage_ok = true_bad = 0
    with one_thread():
        corridor = corridor_frames(args.frames, args.seed + 101)
        print(
            f"{'solver':9s} {'data':34s} {'frames':>6s} {'success':>7s} "
            f"{'inconsistent_fit':>16s} {'success without the check':>25s}"
        )
        for solver in args.solvers:
            for kind in ATTACKS:
                r = count((attack(f, kind) for f in corridor), solver, unchecked=True)
                garbage_ok += r["success"]
                name = f"garbage: {kind}"
                print(
                    f"{solver:9s} {name:34s} {r['frames']:6d} {r['success']:7d} "
                    f"{r['inconsistent']:16d} {r['unchecked']:25d}"
                )
            for name, noise, speed in REFLECTED_PROTOCOL:
                frames = protocol_frames(args.frames, args.seed, 300, noise, speed)
                r = count((attack(f, "reflected") for f in frames), solver, unchecked=True)
                garbage_ok += r["success"]
                print(
                    f"{solver:9s} {name:34s} {r['frames']:6d} {r['success']:7d} "
                    f"{r['inconsistent']:16d} {r['unchecked']:25d}"
                )
            for name, make in TRUE_SETS.items():
                r = count(make(args.frames, args.seed), solver)
                true_bad += r["inconsistent"]
                print(
                    f"{solver:9s} {name:34s} {r['frames']:6d} {r['success']:7d} "
                    f"{r['inconsistent']:16d}"
                )
    print(
        f"garbage frames solved: {garbage_ok} (target 0); true frames refused as "
        f"inconsistent_fit: {true_bad} (target 0)"
    )
    return 0 if garbage_ok == 0 and true_bad == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
