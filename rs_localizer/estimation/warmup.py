"""JIT warm-up: solve small synthetic problems so numba compiles (or loads from its cache)
every kernel a real frame needs, before the first real frame (cold and tracked frames, 3D and
planar scenes).

Used by the node at start (and on a solver change) and by ``rs-localizer compile``, the
install-time compilation step (see :mod:`rs_localizer.jit_cache` for where the kernels go).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import numpy as np

from ..camera import CameraModel
from ..geometry import rotvec_to_matrix
from ..jit_cache import cache_state, compile_progress
from ..solvers.registry import SOLVER_NAMES, solver_info
from .estimate import EstimateOptions, GyroMeasurement, RSPoseEstimate, estimate_rs_pose
from .tracker import RSTracker, TrackerOptions

__all__ = ["DEFAULT_SOLVERS", "compile_kernels", "warm_up"]

#: what ``rs-localizer compile`` compiles by default: the node's default solver and the
#: global-shutter baseline of ``rs-localizer demo``
DEFAULT_SOLVERS = ("r6p_1lin", "p3p")


def _camera() -> CameraModel:
    """A 640x480 distorted RS camera (50 us per line)."""
    return CameraModel(
        K=np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]]),
        D=np.array([0.05, -0.05, 0.0, 0.0, 0.0]),
        width=640,
        height=480,
        line_delay=5e-5,
        distortion_model="plumb_bob",
    )


def _problem(n: int = 60, seed: int = 1, scene: str = "3d"):
    """The camera and ``n`` correspondences with 0.3 px image noise and scores: camera, pixels
    (n, 2), world points (n, 3), scores (n,). ``scene``: ``3d`` (3-8 m deep over the whole
    image), ``planar`` (a plane 5 m ahead) or ``distant`` (a small object 20-30 m away, whose
    velocities lean on the motion prior: its MAP step runs)."""
    rng = np.random.default_rng(seed)
    cam = _camera()
    lo, hi = ([200, 150], [440, 330]) if scene == "distant" else ([0, 0], [639, 479])
    uv = rng.uniform(lo, hi, (n, 2))
    depth = {"3d": (3.0, 8.0), "planar": (5.0, 5.0), "distant": (20.0, 30.0)}[scene]
    xn = cam.undistort(uv)
    X = np.concatenate([xn, np.ones((n, 1))], axis=1) * rng.uniform(*depth, n)[:, None]
    return cam, uv + rng.normal(0.0, 0.3, uv.shape), X, rng.uniform(0, 1, n)


def _video(planar: bool, frames: int = 8, n: int = 60):
    """``frames`` frames at 30 Hz of a camera turning (0.3 rad/s) and moving (0.5 m/s) in
    front of the points of :func:`_problem`, projected through the exact RS model (0.3 px
    noise): (camera, [(stamp_ns, pixels (m, 2), points (m, 3))])."""
    cam, _, X, _ = _problem(n, seed=2, scene="planar" if planar else "3d")
    rng = np.random.default_rng(3)
    s = cam.seconds_per_unit_r
    om, v = np.array([0.0, 0.3, 0.0]), np.array([0.5, 0.0, 0.0])  # camera frame, rad/s, m/s
    out = []
    for k in range(frames):
        R = rotvec_to_matrix(-om * k / 30.0)
        C = -v * k / 30.0
        w = -om * s
        t = np.cross(w, C) - v * s
        uv = cam.project_rs(X, R, C, w, t) + rng.normal(0.0, 0.3, (len(X), 2))
        ok = np.isfinite(uv).all(axis=1)
        out.append((k * 33_333_333, uv[ok], X[ok]))
    return cam, out


def warm_up(
    solver: str = "r6p_1lin",
    options: EstimateOptions | None = None,
    tracking: TrackerOptions | None = None,
    gyro: bool = True,
) -> tuple[float, RSPoseEstimate]:
    """Run everything a node with ``solver``, ``options`` and ``tracking`` runs on a frame, on
    small synthetic problems, so that numba compiles (or loads from its cache) every kernel
    before the first real frame: :func:`~rs_localizer.estimation.estimate_rs_pose` on a
    60-point 3D scene with and without scores (the two input paths of the node), on a small
    distant object (the motion prior's MAP step) and on a planar scene (MAP refinement and
    damped hypotheses) for solvers that take one; with ``tracking`` (the video tracker's
    options, None: every frame alone) also an
    :class:`~rs_localizer.estimation.tracker.RSTracker` over 8 frames of a moving camera in
    front of each scene (predicted RANSAC, the twist filter, its smoother, the acceleration
    sensitivity). With ``gyro`` each of these again with a gyro measurement (RANSAC's
    samples solved with the angular velocity known, the gyro-aided prior).

    Returns:
        (seconds, the estimate of the 3D scene without scores).
    Raises:
        ValueError: unknown solver.
    """
    if solver not in SOLVER_NAMES:
        raise ValueError(f"unknown solver {solver!r}; expected one of {list(SOLVER_NAMES)}")
    tic = time.perf_counter()
    cam, uv, X, scores = _problem()
    est = estimate_rs_pose(uv, X, cam, solver=solver, options=options)
    estimate_rs_pose(uv, X, cam, solver=solver, options=options, scores=scores)
    # (any measurement compiles the gyro path; agreeing with the image or not)
    gyros = (
        (None, GyroMeasurement(np.array([0.2, -0.1, 0.3]), 1e-4 * np.eye(3))) if gyro else (None,)
    )
    if gyro:
        estimate_rs_pose(uv, X, cam, solver=solver, options=options, gyro=gyros[1])
    scenes = (False, True) if solver_info(solver).coplanar else (False,)
    for scene in ("distant", "planar") if True in scenes else ("distant",):
        cam, uv, X, scores = _problem(scene=scene)
        for g in gyros:
            estimate_rs_pose(uv, X, cam, solver=solver, options=options, scores=scores, gyro=g)
    if tracking is not None:
        for planar in scenes:
            cam, frames = _video(planar)
            for g in gyros:
                tracker = RSTracker(solver, options, tracking)
                for stamp, uv, X in frames:
                    tracker.process(stamp, uv, X, cam, gyro=g)
                tracker.flush()
    return time.perf_counter() - tic, est


def compile_kernels(
    solvers: Iterable[str] = DEFAULT_SOLVERS,
    log: Callable[[str], object] = print,
    tracking: TrackerOptions | None = TrackerOptions(),
) -> dict:
    """Compile (or load) every kernel the estimator needs for ``solvers`` (with the video
    tracker's, for ``tracking``: the node's default), reporting each kernel numba compiles
    through ``log`` (see :func:`rs_localizer.jit_cache.compile_progress`).

    Returns:
        ``{"seconds": total, "kernels": [(name, seconds)], "cache": cache_state(),
        "solvers": {solver: seconds}}``.
    Raises:
        ValueError: an unknown solver name.
    """
    solvers = list(solvers)
    for s in solvers:
        if s not in SOLVER_NAMES:
            raise ValueError(f"unknown solver {s!r}; expected one of {list(SOLVER_NAMES)}")
    tic = time.perf_counter()
    per = {}
    with compile_progress(log) as prog:
        for s in solvers:
            per[s], _ = warm_up(s, tracking=tracking)
    return {
        "seconds": time.perf_counter() - tic,
        "kernels": prog.kernels,
        "cache": cache_state(),
        "solvers": per,
    }
