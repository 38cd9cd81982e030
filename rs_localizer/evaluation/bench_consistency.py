"""Fit consistency: ``python -m rs_localizer.evaluation.bench_consistency``.

Correspondences that no camera can produce can still be fitted well on a part of the points:
a plane seen from behind is its own mirror image, so a mirrored image, a map reflected through
the camera or a map in a mirrored frame explains one wall of a 3D scene exactly, from outside
the scene, with a small reported covariance. The estimator refuses such fits
(``inconsistent_fit``: :func:`rs_localizer.estimation.finalize.final_estimate`). This
benchmark counts, per solver:

- on garbage (every row of a frame edited, :data:`ATTACKS`; and the paper protocol's frames
  with 300 points, every 3D point reflected through the camera centre): the frames that still
  give a success (must be 0), how many were refused as ``inconsistent_fit`` (the rest fail on
  earlier checks) and how many would succeed without that check
  (``PlausibilityOptions(consistent_fit=False)``);
- on true data (:data:`TRUE_SETS`: the ``make-bag`` corridor with 20 % and 70 % outliers and
  1 px noise, the paper protocol's frames at 1 px noise, a 300-point plane and a 42-corner board
  at 30 % outliers): successes, and the frames refused as ``inconsistent_fit`` (false rejects;
  must be 0).

    python -m rs_localizer.evaluation.bench_consistency [--frames 120] [--solvers r6p_1lin p3p]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from ..camera import CameraModel
from ..estimation import EstimateOptions, RansacOptions, estimate_rs_pose
from ..estimation.result import INCONSISTENT_FIT
from ..sim.planar import make_planar_frame
from ..sim.synthetic import make_frame, paper_camera
from ..sim.trajectory import SequenceConfig, generate_sequence
from .bench import protocol_options
from .threads import one_thread

__all__ = ["ATTACKS", "TRUE_SETS", "TestFrame", "attack", "corridor_frames", "count", "main"]


@dataclass(frozen=True)
class TestFrame:
    """One frame's input: ``points_px`` (N, 2) measured pixels, ``points3d`` (N, 3) world
    points (m), the ``camera``, the true camera centre ``position`` (3,) (m, world) and the
    estimator ``options``."""

    points_px: np.ndarray
    points3d: np.ndarray
    camera: CameraModel
    position: np.ndarray
    options: EstimateOptions


def corridor_frames(frames: int, seed: int, **config) -> list[TestFrame]:
    """``frames`` consecutive frames (300 correspondences) of the ``make-bag`` corridor walk
    (:func:`~rs_localizer.sim.trajectory.generate_sequence`; ``config``: more
    :class:`~rs_localizer.sim.trajectory.SequenceConfig` fields), default options."""
    cfg = SequenceConfig(num_frames=frames, num_points=300, seed=seed, **config)
    seq, _, camera, _ = generate_sequence(cfg)
    return [TestFrame(f.uv, f.xyz, camera, f.position, EstimateOptions()) for f in seq]


def attack(frame: TestFrame, kind: str) -> TestFrame:
    """``frame`` with every row edited into correspondences no camera can produce:

    - ``reflected``: each 3D point reflected through the true camera centre (``2 C - X``);
    - ``mirror_image``: the image mirrored left-right (a driver's flip option left on);
    - ``flip_image``: the image mirrored top-bottom;
    - ``mirror_world``: the map in a mirrored (left-handed) frame: world x negated about the
      camera centre.

    Raises:
        ValueError: unknown ``kind``.
    """
    px, X, cam, c = frame.points_px.copy(), frame.points3d.copy(), frame.camera, frame.position
    if kind == "reflected":
        X = 2.0 * c - X
    elif kind == "mirror_image":
        px[:, 0] = cam.width - 1 - px[:, 0]
    elif kind == "flip_image":
        px[:, 1] = cam.height - 1 - px[:, 1]
    elif kind == "mirror_world":
        X[:, 0] = 2.0 * c[0] - X[:, 0]
    else:
        raise ValueError(f"unknown attack {kind!r}; expected one of {ATTACKS}")
    return TestFrame(px, X, cam, c, frame.options)


#: the edits of :func:`attack`
ATTACKS = ("reflected", "mirror_image", "flip_image", "mirror_world")


def _protocol(frames: int, seed: int, n_points: int = 100) -> Iterator[TestFrame]:
    cam = paper_camera()
    for i in range(frames):
        f = make_frame(seed + i, n_points=n_points, rs_speed=0.5, noise_px=1.0)
        yield TestFrame(f.points_px, f.X, cam, f.position, protocol_options())


def _planar(kind: str, frames: int, seed: int) -> Iterator[TestFrame]:
    opts = EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12))
    for i in range(frames):
        f = make_planar_frame(seed + i, kind, outlier_ratio=0.3)
        yield TestFrame(f.points_px, f.X, f.camera, np.zeros(3), opts)


#: the true data sets: name -> ``f(frames, seed)`` giving :class:`TestFrame`\\ s
TRUE_SETS: dict[str, Callable[[int, int], Iterator[TestFrame]]] = {
    "corridor, 20 % outliers": lambda n, s: iter(corridor_frames(n, s)),
    "corridor, 70 % outliers": lambda n, s: iter(corridor_frames(n, s, outlier_ratio=0.7)),
    "corridor, 1 px noise": lambda n, s: iter(corridor_frames(n, s, noise_px=1.0)),
    "paper protocol, 1 px noise": _protocol,
    "plane, 30 % outliers": lambda n, s: _planar("plane", n, s),
    "board, 30 % outliers": lambda n, s: _planar("board", n, s),
}


def count(frames, solver: str, unchecked: bool = False) -> dict:
    """Run the estimator with ``solver`` on each :class:`TestFrame` of ``frames``; returns
    ``frames``, ``success`` and ``inconsistent`` (failed as ``inconsistent_fit``) counts,
    ``ms`` (median time per frame) and, with ``unchecked``, ``unchecked`` (successes of the
    same frames with the consistency check off)."""
    n = ok = bad = ok_unchecked = 0
    times = []
    for f in frames:
        t0 = time.perf_counter()
        e = estimate_rs_pose(f.points_px, f.points3d, f.camera, solver, f.options)
        times.append(time.perf_counter() - t0)
        n += 1
        ok += int(e.success)
        bad += int(e.failure == INCONSISTENT_FIT)
        if unchecked:
            off = replace(f.options.plausibility, consistent_fit=False)
            opts = replace(f.options, plausibility=off)
            ok_unchecked += int(
                estimate_rs_pose(f.points_px, f.points3d, f.camera, solver, opts).success
            )
    out = dict(frames=n, success=ok, inconsistent=bad, ms=float(np.median(times) * 1e3))
    if unchecked:
        out["unchecked"] = ok_unchecked
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m rs_localizer.evaluation.bench_consistency",
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
            r = count(
                (attack(f, "reflected") for f in _protocol(args.frames, args.seed, 300)),
                solver,
                unchecked=True,
            )
            garbage_ok += r["success"]
            name = "garbage: reflected, paper protocol"
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
