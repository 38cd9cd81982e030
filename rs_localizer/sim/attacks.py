"""Correspondences no camera can produce, and true data sets, for the estimator's fit
consistency check (``inconsistent_fit``, :func:`rs_localizer.estimation.finalize.final_estimate`):
a plane seen from behind is its own mirror image, so a mirrored image, a map reflected through
the camera or a map in a mirrored frame explains one wall of a 3D scene exactly. :func:`attack`
edits a true frame (:data:`ATTACKS`); :data:`TRUE_SETS` are the frames the check must pass;
:func:`count` runs the estimator over frames. Used by the tests and
``python -m benchmarks.bench_consistency``."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..camera import CameraModel
from ..estimation import EstimateOptions, RansacOptions, estimate_rs_pose
from ..estimation.result import INCONSISTENT_FIT
from .planar import make_planar_frame
from .synthetic import make_frame, paper_camera, protocol_options
from .trajectory import SequenceConfig, generate_sequence

__all__ = [
    "ATTACKS",
    "TRUE_SETS",
    "TestFrame",
    "attack",
    "corridor_frames",
    "count",
    "protocol_frames",
]


@dataclass(frozen=True)
class TestFrame:
    """One frame's input: ``points_px`` (N, 2) measured pixels, ``points3d`` (N, 3) world
    points (m), the ``camera``, the true camera centre ``position`` (3,) (m, world) and the
    estimator ``options``."""

    __test__ = False  # (not a test class for pytest, where tests import it)

    points_px: np.ndarray
    points3d: np.ndarray
    camera: CameraModel
    position: np.ndarray
    options: EstimateOptions


def corridor_frames(frames: int, seed: int, **config: Any) -> list[TestFrame]:
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


def protocol_frames(
    frames: int, seed: int, n_points: int = 100, noise_px: float = 1.0, rs_speed: float = 0.5
) -> Iterator[TestFrame]:
    """``frames`` frames of the paper protocol (:func:`~rs_localizer.sim.synthetic.make_frame`,
    RS speed ``rs_speed``, ``noise_px`` px noise, ``n_points`` correspondences, seeds ``seed``,
    ``seed + 1``, ...) with :func:`~rs_localizer.sim.synthetic.protocol_options`."""
    cam = paper_camera()
    for i in range(frames):
        f = make_frame(seed + i, n_points=n_points, rs_speed=rs_speed, noise_px=noise_px)
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
    "paper protocol, 1 px noise": protocol_frames,
    "plane, 30 % outliers": lambda n, s: _planar("plane", n, s),
    "board, 30 % outliers": lambda n, s: _planar("board", n, s),
}


def count(frames: Iterable[TestFrame], solver: str, unchecked: bool = False) -> dict:
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
