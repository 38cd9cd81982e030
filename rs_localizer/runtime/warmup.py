"""JIT warm-up: solve small synthetic problems so numba compiles (or loads from its cache)
every kernel a real frame needs, before the first real frame (cold and tracked frames, 3D and
planar scenes).

Used by the node at start (and on a solver change) and by ``rs-localizer compile``, the
install-time compilation step (see :mod:`.jit_cache` for where the kernels go).

Compiling takes one to two minutes on one core; a third of it is the fused RANSAC kernels
(:mod:`.estimation.batch`), which every frame needs first. With ``jobs`` > 1 and those kernels
not yet in numba's cache, a second Python process compiles, meanwhile, part of that batch's callees
(Lambda Twist and the MSAC scoring, while this process compiles the solver kernels), then the
kernels a frame needs later (:func:`warm_late`: the exact-model refinement, the motion prior's
MAP step, the twist filter and its smoother) while this process runs the usual warm-up, which
then loads them from the cache (or compiles whatever the second process has not finished):
the result is the same as compiling in one process.

The second process is :mod:`.second_process` (``python -m rs_localizer.runtime.second_process``).
A node need not wait for any of this (:mod:`.background`): on a cold cache it solves its frames
at once with the estimator's NumPy implementation (:mod:`rs_localizer.estimation.numpy_impl`)
while another process compiles the kernels, and uses them, frame by frame, once they are cached
and loaded.
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import replace

import numpy as np

from ..camera import CameraModel
from ..estimation.batch import fused_kernels, prerotated_batch, ransac_batch
from ..estimation.estimate import (
    EstimateOptions,
    GyroMeasurement,
    InitialModel,
    RSPoseEstimate,
    estimate_rs_pose,
)
from ..estimation.frame import prepare_frame
from ..estimation.prior import prior_conflict
from ..estimation.refine import (
    LM_REFINE_KERNEL,
    RefineSettings,
    posterior_step,
    refine_rs_pose,
    untruncated_variance,
)
from ..estimation.result import camera_model_of_rig
from ..estimation.rig import estimate_rig_pose
from ..estimation.sampling import p3p_mounted
from ..estimation.scoring import exact_msac_scores
from ..estimation.view import View
from ..geometry import rotvec_to_matrix
from ..pose import RSModel, RSPose, model_from_twist
from ..solvers.kernels import KernelSetType, compile_kernel_set
from ..solvers.registry import SOLVER_NAMES, solver_info
from ..tracking.localizer import CameraFrame
from ..tracking.sequence import reference_stamp_ns
from ..tracking.tracker import RSTracker, TrackerOptions
from ..tracking.video import Localizer, LocalizerSettings
from .jit_cache import PACKAGE_DIR, cache_state, compile_progress

__all__ = [
    "DEFAULT_JOBS",
    "DEFAULT_SOLVERS",
    "compile_kernels",
    "fused_cached",
    "package_command",
    "rig_cached",
    "split_batch",
    "synthetic_problem",
    "track_videos",
    "warm_late",
    "warm_rig",
    "warm_up",
]

#: what :func:`compile_kernels` compiles by default: the node's default solver and ``p3p``, the
#: global-shutter solver ``rs-localizer demo`` compares it with
DEFAULT_SOLVERS = ("r6p_1lin", "p3p")

#: processes that compile at once by default: two where the machine has two cores or more
DEFAULT_JOBS = min(2, os.cpu_count() or 1)


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


def synthetic_problem(n: int = 60, seed: int = 1, scene: str = "3d"):
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
    front of the points of :func:`synthetic_problem`, projected through the exact RS model (0.3 px
    noise): (camera, [(stamp_ns, pixels (m, 2), points (m, 3))])."""
    cam, _, X, _ = synthetic_problem(n, seed=2, scene="planar" if planar else "3d")
    rng = np.random.default_rng(3)
    s = cam.seconds_per_unit_r
    om, v = np.array([0.0, 0.3, 0.0]), np.array([0.5, 0.0, 0.0])  # camera frame, rad/s, m/s
    out = []
    for k in range(frames):
        R = rotvec_to_matrix(-om * k / 30.0)
        C = -v * k / 30.0
        w, t = model_from_twist(C, om, v, s)
        uv = cam.project_rs(X, R, C, w, t) + rng.normal(0.0, 0.3, (len(X), 2))
        ok = np.isfinite(uv).all(axis=1)
        out.append((k * 33_333_333, uv[ok], X[ok]))
    return cam, out


def warm_up(
    solver: str = "r6p_1lin",
    options: EstimateOptions | None = None,
    tracking: TrackerOptions | None = None,
    jobs: int = 1,
    log: Callable[[str], object] | None = None,
    gyro: bool = True,
    implementation: str | None = None,
) -> tuple[float, RSPoseEstimate]:
    """Run everything a node with ``solver``, ``options`` and ``tracking`` runs on a frame, on
    small synthetic problems, so that numba compiles (or loads from its cache) every kernel
    before the first real frame: :func:`~rs_localizer.estimation.estimate_rs_pose` on a
    60-point 3D scene with and without scores (the two input paths of the node) and with its
    points in groups of four (a marker front end's corners: their shared shift's
    covariance), on a small distant object (the motion prior's MAP step) and on a planar
    scene (MAP refinement and damped hypotheses) for solvers that take one, and on one tag's
    four corners (the few-points path, with and without distortion, and with a prediction's
    velocities held); with ``tracking`` (the video tracker's options, None: every frame
    alone) also an
    :class:`~rs_localizer.tracking.tracker.RSTracker` over 8 frames of a moving camera in
    front of each scene (predicted RANSAC, the twist filter, its smoother, the acceleration
    sensitivity). With ``gyro`` each of these again with a gyro measurement (RANSAC's
    samples solved with the angular velocity known, the gyro-aided prior).
    ``implementation``: the estimator's (``estimate_rs_pose``'s argument; ``"compiled"``
    loads or compiles the kernels whatever the process's default).

    With ``jobs`` > 1, when the solver's fused RANSAC kernels are not in numba's cache
    (:func:`fused_cached`), another process compiles part of them and the kernels a frame
    needs later (:func:`warm_late`) meanwhile (module docstring); ``log`` receives its
    progress lines.

    Returns:
        (seconds, the estimate of the 3D scene without scores).
    Raises:
        ValueError: unknown solver.
    """
    if solver not in SOLVER_NAMES:
        raise ValueError(f"unknown solver {solver!r}; expected one of {list(SOLVER_NAMES)}")
    tic = time.perf_counter()
    with _parallel([solver], tracking is not None, jobs, log, gyro):
        est = _run(solver, options, tracking, gyro, implementation)
    return time.perf_counter() - tic, est


#: a gyro measurement for the warm-up (any measurement compiles the gyro path, agreeing with
#: the image or not)
_GYRO = GyroMeasurement(np.array([0.2, -0.1, 0.3]), 1e-4 * np.eye(3))


def _run(solver, options, tracking, gyro: bool = True, impl: str | None = None) -> RSPoseEstimate:
    """The warm-up's frames (:func:`warm_up`); returns the 3D scene's estimate."""
    gyros = (None, _GYRO) if gyro else (None,)
    kw = {"solver": solver, "options": options, "implementation": impl}
    cam, uv, X, scores = synthetic_problem()
    est = estimate_rs_pose(uv, X, cam, **kw)
    estimate_rs_pose(uv, X, cam, scores=scores, **kw)
    # (points in groups of four, a marker front end's corners: the covariance of their shared
    # shift, :mod:`~rs_localizer.estimation.noise_model`)
    estimate_rs_pose(uv, X, cam, groups=np.arange(len(uv)) // 4, **kw)
    # (a camera without distortion refines the plain errors: the refinement's other version)
    estimate_rs_pose(uv, X, replace(cam, D=np.zeros(0)), **kw)
    if gyro:
        estimate_rs_pose(uv, X, cam, gyro=_GYRO, **kw)
    for scene in ("distant", "planar") if solver_info(solver).coplanar else ("distant",):
        cam, uv, X, scores = synthetic_problem(scene=scene)
        for g in gyros:
            estimate_rs_pose(uv, X, cam, scores=scores, gyro=g, **kw)
    # (four coplanar points, one tag's corners: the few-points path's fits, of the errors
    # whitened by the lens and of the plain ones, and with the velocities held at a
    # prediction's)
    cam, uv, X, _ = synthetic_problem(4, scene="planar")
    for c in (cam, replace(cam, D=np.zeros(0))):
        tag = estimate_rs_pose(uv, X, c, **kw)
    if tag.success:
        R, C, w, t = tag.model
        held = InitialModel(RSModel(R, C, w + 1e-4, t + 1e-4), gate_px=1e6)
        estimate_rs_pose(uv, X, cam, initial_model=held, **kw)
    if tracking is not None:
        track_videos(solver, options, tracking, gyro=gyro)
    return est


def track_videos(solver, options, tracking, planar_first: bool = False, gyro: bool = True) -> None:
    """The warm-up's videos through an :class:`RSTracker` (with ``gyro`` also with a gyro
    measurement): a 3D scene, then a planar one for solvers that take one (the other way round
    with ``planar_first``)."""
    scenes = (False, True) if solver_info(solver).coplanar else (False,)
    for planar in reversed(scenes) if planar_first else scenes:
        cam, frames = _video(planar)
        for g in (None, _GYRO) if gyro else (None,):
            tracker = RSTracker(solver, options, tracking)
            for stamp, uv, X in frames:
                tracker.process(stamp, uv, X, cam, gyro=g)
            tracker.flush()


def warm_late(
    solver: str, options: EstimateOptions | None = None, tracking: TrackerOptions | None = None
) -> None:
    """Compile (or load), without running RANSAC, the kernels a frame of ``solver`` needs
    after it, with the argument types the estimator passes them: the exact-model refinement
    (:func:`~.estimation.refine.refine_rs_pose`; its functions normalize their inputs, so the
    types do not depend on the values), the motion prior's MAP step
    (:func:`~.estimation.prior.prior_conflict`, :func:`~.estimation.refine.posterior_step`)
    and, with ``tracking``, the twist filter and its smoother
    (:class:`~.tracking.fusion.TwistFilter` over synthetic per-frame estimates). The second
    process of a parallel warm-up runs it (:func:`warm_up`).

    Raises:
        ValueError: unknown solver.
    """
    if solver not in SOLVER_NAMES:
        raise ValueError(f"unknown solver {solver!r}; expected one of {list(SOLVER_NAMES)}")
    if not solver_info(solver).rolling:
        return
    opts = options or EstimateOptions()
    cam, uv, X, _ = synthetic_problem()
    fr = prepare_frame(uv, X, cam, opts.plausibility.max_point_norm, np.random.default_rng(0))
    spr, prior = cam.seconds_per_unit_r, opts.motion_prior
    # (both versions: the plain errors of a camera without distortion, then the pixel errors of
    # the measured image of this distorted one)
    for mountings in (None, fr.mountings()):
        ref = refine_rs_pose(
            (np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3)),
            fr.X,
            fr.x,
            fr.r - fr.r0,
            opts.ransac.threshold_px / fr.f,
            RefineSettings(seconds_per_unit_r=spr, acceleration_block=True),
            prior=prior,
            mountings=mountings,
        )
    # (the twist filter before the MAP step: the first process reaches the MAP step first, on
    # its cold frame, and the tracker's filter last)
    if tracking is not None:
        _warm_filter(solver, opts, tracking)
    if prior is not None and ref.covariance is not None:
        prior_conflict(prior, ref.covariance, ref.C, ref.w, ref.t, spr)
        posterior_step(ref, prior, spr)


def _warm_filter(solver: str, opts: EstimateOptions, tracking: TrackerOptions) -> None:
    """The tracker's twist filter and smoother over synthetic per-frame estimates
    (:func:`warm_late`)."""
    prior = opts.motion_prior
    filt = RSTracker(solver, opts, tracking).filter  # (the tracker's own filter)
    cov = np.diag(np.full(12, 1e-4))
    for k in range(4):
        est = RSPoseEstimate(
            success=True,
            pose=RSPose(
                rotvec_to_matrix(np.array([0.0, 0.01 * k, 0.0])).T,  # (as R.T)
                np.array([0.01 * k, 0.0, 0.0]),
                np.array([0.0, 0.3, 0.0]),
                np.array([0.3, 0.0, 0.0]),
            ),
            covariance=cov,
            twist_covariance=cov[6:, 6:],
            acceleration_sensitivity=np.zeros((12, 6)),
        )
        step = filt.update(k * 33_333_333, est, prior=prior)
        _ = step.current
        filt.predict((k + 1) * 33_333_333)
    filt.flush()


def split_batch(solver: str, first: bool) -> None:
    """Compile (or load) one share of the callees of ``solver``'s cold RANSAC batch
    (:func:`.estimation.batch.ransac_batch`, compiled first and alone on a cold frame's path)
    with the argument types the batch passes them: ``first``: the batched solver kernels (the first
    process, before its warm-up); else the P3P poses of a camera's samples
    (:func:`~.estimation.sampling.p3p_mounted` on unit bearings) and the MSAC scoring (the second
    process, before :func:`warm_late`), which the first process's batch reaches after the
    kernels and then loads from numba's cache. Nothing for a solver without a fused batch."""
    fused = fused_kernels(solver)
    if fused is None:
        return
    if first:
        compile_kernel_set(fused[0])
        return
    cam, uv, X, _ = synthetic_problem()
    fr = prepare_frame(uv, X, cam, np.inf, np.random.default_rng(0))
    p3p_mounted(fr.x, fr.X, np.zeros((1, 3), dtype=np.int64), None, None, None)
    H = 2
    exact_msac_scores(
        fr.x,
        fr.X,
        fr.r0e,
        fr.d,
        np.zeros((H, 3, 3)),
        np.zeros((H, 3)),
        np.zeros((H, 3)),
        np.zeros((H, 3)),
        1e-6,
        np.zeros(H, dtype=np.bool_),
        np.inf,
        10,
        0,
        0.5,
        False,
        fr.W,
    )


@contextlib.contextmanager
def _parallel(
    solvers: list[str],
    track: bool,
    jobs: int,
    log: Callable[[str], object] | None,
    gyro: bool = True,
):
    """While the body compiles: with ``jobs`` > 1 and some solver's fused RANSAC kernels not
    cached, a second compiling process (:class:`_SecondProcess`, with the tracker's frames if
    ``track``, the gyro path if ``gyro``), and this process's share of the first solver's cold
    batch compiled first (:func:`split_batch`; the second process warms the other solvers
    up); the second process is stopped when the body is done. Yields the
    :class:`_SecondProcess` (its :attr:`~_SecondProcess.kernels` complete after the block) or
    None."""
    helper = None
    if jobs > 1 and not all(fused_cached(s) for s in solvers):
        helper = _SecondProcess(solvers, track, log, gyro)
    try:
        if helper is not None:
            split_batch(solvers[0], first=True)
        yield helper
    finally:
        if helper is not None:
            helper.stop()


def fused_cached(solver: str, anchored: bool = True) -> bool:
    """True when numba's cache holds ``solver``'s fused RANSAC kernels (the cold batch and,
    with ``anchored``, the anchored one) for this source, or the solver has none: then
    compiling in another process gains nothing. Reads numba's cache index (numba internals);
    any surprise there counts as not cached."""
    fused = fused_kernels(solver)
    if fused is None:
        return True
    kernels = [ransac_batch] + ([prerotated_batch] if anchored and len(fused[0]) else [])
    try:
        for disp in kernels:
            index = disp._cache._cache_file._load_index()
            if not any(
                isinstance(t, KernelSetType) and t.ids == fused[0].ids
                for key in index
                for t in key[0]
            ):
                return False
    except Exception:
        return False
    return True


def rig_cached() -> bool:
    """True when numba's cache holds the rig's refinement kernel for this source: the
    Levenberg-Marquardt kernel's specialization with mountings
    (:func:`~rs_localizer.estimation.refine.refine_rs_pose` with ``mountings``, the longest
    of the rig's kernels to compile; :func:`warm_rig` then loads rather than compiles). Reads
    numba's cache index (numba internals) as :func:`fused_cached`; any surprise there counts
    as not cached."""
    from numba.core import types

    try:
        index = LM_REFINE_KERNEL._cache._cache_file._load_index()
        return any(isinstance(key[0][-1], types.BaseTuple) for key in index)
    except Exception:
        return False


#: a progress line of :func:`~.jit_cache.compile_progress`: kernel, seconds
_COMPILED = re.compile(r"compiled (\S+) in ([0-9.]+) s")
#: the second process's line when it has warmed a further solver up: solver
_WARMED = re.compile(r"warmed up (\S+)$")


def package_command(module: str, *args: str) -> tuple[list[str], dict[str, str], str | None]:
    """The command, environment and working directory (None: this process's) of ``python -m
    module args`` in another process of this interpreter that imports this very package: the
    package's parent directory first on ``PYTHONPATH`` and ``-P`` (the working directory,
    which may hold another copy of the package, not on ``sys.path``); Python 3.10 has no
    ``-P``: there the process runs in the package's parent directory (a relative
    ``NUMBA_CACHE_DIR`` made absolute). The rest of the environment is this process's (numba
    caches where this process does)."""
    env = dict(os.environ)
    parent = os.path.dirname(PACKAGE_DIR)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (parent, env.get("PYTHONPATH")) if p)
    if sys.version_info >= (3, 11):
        return [sys.executable, "-P", "-m", module, *args], env, None
    if env.get("NUMBA_CACHE_DIR"):
        env["NUMBA_CACHE_DIR"] = os.path.abspath(env["NUMBA_CACHE_DIR"])
    return [sys.executable, "-m", module, *args], env, parent


class _SecondProcess:
    """:func:`.second_process.main` for ``solvers`` (with the default tracker if ``track``,
    the gyro path if ``gyro``)
    in another Python process (:func:`package_command`: the same interpreter and package, the
    same environment: numba caches where this process does), started at once. ``log``
    receives its progress lines; :attr:`kernels` the (name, seconds) of what it compiled. A
    helper that cannot start or fails only costs time: this process compiles what is
    missing."""

    def __init__(
        self,
        solvers: list[str],
        track: bool,
        log: Callable[[str], object] | None,
        gyro: bool = True,
    ):
        self.kernels: list[tuple[str, float]] = []
        self.warmed: set[str] = set()
        self._log = log
        mode = ("track" if track else "alone") + ("+gyro" if gyro else "")
        cmd, env, cwd = package_command("rs_localizer.runtime.second_process", mode, *solvers)
        try:
            self._proc = subprocess.Popen(
                cmd,
                env=env,
                cwd=cwd,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
        except OSError as e:
            self._proc = None
            if log is not None:
                log(f"could not start a second compiling process ({e}); compiling in this one")
            return
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self._proc.stdout:
            line = line.rstrip("\n")
            m = _COMPILED.match(line)
            if m:
                with contextlib.suppress(ValueError):
                    self.kernels.append((m.group(1), float(m.group(2))))
            m = _WARMED.match(line)
            if m:
                self.warmed.add(m.group(1))
            if line and self._log is not None:
                self._log(f"[second process] {line}")

    def wait_warmed(self, solver: str) -> None:
        """Wait until the helper has warmed ``solver`` up (one of the further solvers it
        compiles; ``SOLVER:late``: :func:`warm_late` for the first solver;
        :mod:`.second_process`) or has ended: this process then loads those kernels from the
        cache instead of compiling them a second time."""
        if self._proc is None:
            return
        while solver not in self.warmed and self._proc.poll() is None:
            time.sleep(0.1)

    def stop(self) -> None:
        """End the helper: this process has then compiled or loaded every kernel it needs,
        so what the helper still does is of no use (numba writes each cached kernel
        atomically: stopping it mid-way leaves no broken entry). Returns when it is gone."""
        if self._proc is None:
            return
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._reader.join(timeout=5.0)


def warm_rig(
    settings: LocalizerSettings,
    timing: dict[str, tuple[float, float, str]] | None = None,
    frames: int = 8,
) -> int:
    """Run a :class:`~rs_localizer.tracking.video.Localizer` with ``settings`` (the rig node's:
    its mountings, estimator options, tracking, gyro) over ``frames`` rig frames at 30 Hz of a
    rig turning (0.3 rad/s) and moving (0.5 m/s) among points in front of every camera,
    projected through each camera's exact RS model (0.3 px noise), with gyro samples at 200 Hz
    when ``settings.imu`` is set: numba compiles (or loads) every kernel the rig's estimator
    (:func:`~rs_localizer.estimation.rig.estimate_rig_pose`: gR6P, P3P, its residuals, the
    shared shift's covariance of points in groups), its tracking and twist filter and the
    per-camera checks run. ``timing``: camera name ->
    ``(line_delay s, readout_time s, direction)`` (default: 30 us per line, top to bottom; the
    kernels' types do not depend on the values).
    Returns the rig frames posed (all of them on this scene)."""
    rng = np.random.default_rng(4)
    om, v = np.array([0.0, 0.3, 0.1]), np.array([0.5, 0.0, 0.1])  # rig frame, rad/s, m/s
    w, t = -om, -v  # (the rig's model per second, C = 0 at T = 0: its twist is (om, v))
    loc = Localizer(settings)
    cams, points = {}, {}
    for name, m in settings.mounts.items():
        ld, rt, d = (timing or {}).get(name, (3e-5, 0.0, "top_to_bottom"))
        cams[name] = CameraModel(
            K=np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]]),
            D=np.array([0.05, -0.05, 0.0, 0.0, 0.0]),
            width=640,
            height=480,
            line_delay=ld if ld > 0 else (rt / 480 if rt > 0 else 0.0),
            readout=d,
            distortion_model="plumb_bob",
        )
        cam_pts = _camera().undistort(rng.uniform([0, 0], [639, 479], (60, 2)))
        Xc = np.concatenate([cam_pts, np.ones((60, 1))], 1) * rng.uniform(3, 8, 60)[:, None]
        points[name] = (Xc - m.c) @ m.R  # camera -> rig (= world at T = 0)
    if settings.imu is not None:
        R_rig_imu = np.asarray(settings.imu.R_cam_imu, dtype=float)
        for j in range(int(frames / 30 * 200) + 40):  # (200 Hz, the IMU frame's rate)
            loc.add_imu(j * 5_000_000, R_rig_imu.T @ om)
    posed = 0
    for f in range(frames):
        for k, (name, m) in enumerate(settings.mounts.items()):
            cam = cams[name]
            stamp = f * 33_333_333 + 2_000_000 * k
            T = reference_stamp_ns(stamp, cam, settings.stamp_row) / 1e9
            rig = (rotvec_to_matrix(T * w), T * t, w, t)  # (the rig's model at time T)
            model = camera_model_of_rig(rig, m, 0.0, cam.seconds_per_unit_r)
            uv = cam.project_rs(points[name], *model) + rng.normal(0, 0.3, (60, 2))
            ok = np.isfinite(uv).all(1)
            outs = loc.add(CameraFrame(stamp, cam, uv[ok], points[name][ok], camera_name=name))
            posed += sum(o.success for o in outs)
    posed += sum(o.success for o in loc.close())
    loc.flush()
    # (rig frames alone, with outliers, that these tracked frames are not: a global-shutter
    # one (the search's compiled batch of those, with the correction of a sample's pose on its
    # other cameras) and, with a gyro, a rolling-shutter one searched with P3P and the gyro)
    views: dict = {True: [], False: []}
    for name, m in settings.mounts.items():
        for still in (True, False):
            cam = replace(cams[name], line_delay=0.0) if still else cams[name]
            rig = (np.eye(3), np.zeros(3), w, t)
            model = camera_model_of_rig(rig, m, 0.0, cam.seconds_per_unit_r)
            uv = cam.project_rs(points[name], *model) + rng.normal(0, 0.3, (60, 2))
            uv[:6] += 40.0
            ok = np.isfinite(uv).all(1)
            views[still].append(View(uv[ok], points[name][ok], cam, m))
    estimate_rig_pose(views[True], settings.options)
    # (each camera's points in groups of four, a marker front end's corners: the covariance
    # of their shared shift)
    grouped = [replace(v, groups=np.arange(len(v.uv)) // 4) for v in views[False]]
    estimate_rig_pose(grouped, settings.options)
    # (one camera's four corners alone: a rig frame posed by that camera's few-points path,
    # its frame taken from the rig's undistorted points)
    cam, uv, X, _ = synthetic_problem(4, scene="planar")
    estimate_rig_pose([View(uv, X, cam)], settings.options)
    if settings.imu is not None:
        gyro = GyroMeasurement(om, 1e-4 * np.eye(3))
        estimate_rig_pose(views[False], settings.options, gyro=gyro)
    # (the image variance by which the rig's final refinement judges the inliers' own fit,
    # tried only on points between one and two thresholds of its model: none here)
    untruncated_variance(1.0, 2.0)
    return posed


def compile_kernels(
    solvers: Iterable[str] = DEFAULT_SOLVERS,
    log: Callable[[str], object] = print,
    tracking: TrackerOptions | None = TrackerOptions(),
    jobs: int = DEFAULT_JOBS,
    options: EstimateOptions | None = None,
    gyro: bool = False,
    rig: tuple | None = None,
) -> dict:
    """Compile (or load) every kernel the estimator needs for ``solvers`` with ``options``
    (with the video tracker's, for ``tracking``: the node's default; the gyro path with
    ``gyro``, the node's ``imu.enabled``), as :func:`warm_up` runs them, reporting each kernel
    numba compiles through ``log`` (see :func:`.jit_cache.compile_progress`); with ``jobs`` >
    1 a second process compiles part of the first solver's RANSAC batch, the kernels a frame
    needs later and the other solvers' meanwhile (module docstring). ``rig``: ``(LocalizerSettings,
    timing)`` of a rig node (:func:`warm_rig`'s arguments): its kernels too, after the solvers'
    (``solvers`` then maps ``"rig"`` to its seconds).

    Returns:
        ``{"seconds": total, "kernels": [(name, seconds)] (both processes'), "cache":
        cache_state(), "solvers": {solver: seconds}}``.
    Raises:
        ValueError: an unknown solver name.
    """
    solvers = list(solvers)
    for s in solvers:
        if s not in SOLVER_NAMES:
            raise ValueError(f"unknown solver {s!r}; expected one of {list(SOLVER_NAMES)}")
    tic = time.perf_counter()
    per = {}
    with (
        compile_progress(log) as prog,
        _parallel(solvers, tracking is not None, jobs, log, gyro) as helper,
    ):
        for k, s in enumerate(solvers):
            if helper is None:
                per[s], _ = warm_up(s, options, tracking, gyro=gyro)
            elif k:  # (the second process warms it up: then it loads)
                helper.wait_warmed(s)
                per[s], _ = warm_up(s, options, tracking, gyro=gyro)
            else:  # warm_up's frames, the tracker's once the second process's twist filter
                # (warm_late) is cached: then it loads
                t0 = time.perf_counter()
                _run(s, options, None, gyro)
                if tracking is not None:
                    helper.wait_warmed(f"{s}:late")
                    track_videos(s, options, tracking, gyro=gyro)
                per[s] = time.perf_counter() - t0
        if rig is not None:
            t0 = time.perf_counter()
            warm_rig(*rig)
            per["rig"] = time.perf_counter() - t0
    return {
        "seconds": time.perf_counter() - tic,
        "kernels": prog.kernels + (helper.kernels if helper is not None else []),
        "cache": cache_state(),
        "solvers": per,
    }
