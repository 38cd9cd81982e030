"""JIT warm-up: solve small synthetic problems so numba compiles (or loads from its cache)
every kernel a real frame needs, before the first real frame (cold and tracked frames, 3D and
planar scenes).

Used by the node at start (and on a solver change) and by ``rs-localizer compile``, the
install-time compilation step (see :mod:`rs_localizer.jit_cache` for where the kernels go).

Compiling takes one to two minutes on one core; a third of it is the fused RANSAC kernels
(:mod:`.estimation.batch`), which every frame needs first. With ``jobs`` > 1 and those kernels
not yet in numba's cache, a second Python process compiles, meanwhile, part of that batch's callees
(Lambda Twist and the MSAC scoring, while this process compiles the solver kernels), then the
kernels a frame needs later (:func:`warm_late`: the exact-model refinement, the motion prior's
MAP step, the twist filter and its smoother) while this process runs the usual warm-up, which
then loads them from the cache (or compiles whatever the second process has not finished):
the result is the same as compiling in one process.

A node need not wait for any of this (:func:`start_background_compile`): on a cold cache it
solves its frames at once without compiled kernels
(:mod:`rs_localizer.estimation.uncompiled`) while another process compiles them, and switches
to them, frame by frame, once they are cached and loaded.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable
from types import SimpleNamespace

import numpy as np

from .camera import CameraModel
from .estimation.batch import fused_kernels, prerotated_batch, ransac_batch
from .estimation.estimate import EstimateOptions, GyroMeasurement, RSPoseEstimate, estimate_rs_pose
from .estimation.frame import prepare_frame
from .estimation.prior import prior_conflict
from .estimation.refine import RefineSettings, posterior_step, refine_rs_pose
from .estimation.scoring import exact_msac_scores
from .geometry import rotvec_to_matrix
from .jit_cache import PACKAGE_DIR, cache_state, compile_progress, numba_error
from .solvers.kernels import KernelSetType, compile_kernel_set
from .solvers.lambda_twist import lambda_twist_batch
from .solvers.registry import SOLVER_NAMES, solver_info
from .tracking.tracker import RSTracker, TrackerOptions

__all__ = [
    "DEFAULT_JOBS",
    "DEFAULT_SOLVERS",
    "background_state",
    "compile_kernels",
    "fall_back_uncompiled",
    "fused_cached",
    "start_background_compile",
    "uncompiled_rate",
    "warm_late",
    "warm_up",
]

#: what ``rs-localizer compile`` compiles by default: the node's default solver
DEFAULT_SOLVERS = ("r6p_1lin",)

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
    jobs: int = 1,
    log: Callable[[str], object] | None = None,
    gyro: bool = True,
) -> tuple[float, RSPoseEstimate]:
    """Run everything a node with ``solver``, ``options`` and ``tracking`` runs on a frame, on
    small synthetic problems, so that numba compiles (or loads from its cache) every kernel
    before the first real frame: :func:`~rs_localizer.estimation.estimate_rs_pose` on a
    60-point 3D scene with and without scores (the two input paths of the node), on a small
    distant object (the motion prior's MAP step) and on a planar scene (MAP refinement and
    damped hypotheses) for solvers that take one; with ``tracking`` (the video tracker's
    options, None: every frame alone) also an
    :class:`~rs_localizer.tracking.tracker.RSTracker` over 8 frames of a moving camera in
    front of each scene (predicted RANSAC, the twist filter, its smoother, the acceleration
    sensitivity). With ``gyro`` each of these again with a gyro measurement (RANSAC's
    samples solved with the angular velocity known, the gyro-aided prior).

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
    with _parallel([solver], tracking is not None, jobs, log):
        est = _run(solver, options, tracking, gyro)
    return time.perf_counter() - tic, est


#: a gyro measurement for the warm-up (any measurement compiles the gyro path, agreeing with
#: the image or not)
_GYRO = GyroMeasurement(np.array([0.2, -0.1, 0.3]), 1e-4 * np.eye(3))


def _run(solver, options, tracking, gyro: bool = True) -> RSPoseEstimate:
    """The warm-up's frames (:func:`warm_up`); returns the 3D scene's estimate."""
    gyros = (None, _GYRO) if gyro else (None,)
    cam, uv, X, scores = _problem()
    est = estimate_rs_pose(uv, X, cam, solver=solver, options=options)
    estimate_rs_pose(uv, X, cam, solver=solver, options=options, scores=scores)
    if gyro:
        estimate_rs_pose(uv, X, cam, solver=solver, options=options, gyro=_GYRO)
    for scene in ("distant", "planar") if solver_info(solver).coplanar else ("distant",):
        cam, uv, X, scores = _problem(scene=scene)
        for g in gyros:
            estimate_rs_pose(uv, X, cam, solver=solver, options=options, scores=scores, gyro=g)
    if tracking is not None:
        _track(solver, options, tracking, gyro=gyro)
    return est


def _track(solver, options, tracking, planar_first: bool = False, gyro: bool = True) -> None:
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
    cam, uv, X, _ = _problem()
    fr = prepare_frame(uv, X, cam, opts.plausibility.max_point_norm, np.random.default_rng(0))
    spr, prior = cam.seconds_per_unit_r, opts.motion_prior
    ref = refine_rs_pose(
        (np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3)),
        fr.X,
        fr.x,
        fr.r - fr.r0,
        opts.ransac.threshold_px / fr.f,
        RefineSettings(seconds_per_unit_r=spr, acceleration_block=True),
        prior=prior,
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
        est = SimpleNamespace(
            success=True,
            orientation=rotvec_to_matrix(np.array([0.0, 0.01 * k, 0.0])).T,  # (as R.T)
            position=np.array([0.01 * k, 0.0, 0.0]),
            angular_velocity=np.array([0.0, 0.3, 0.0]),
            linear_velocity=np.array([0.3, 0.0, 0.0]),
            covariance=cov,
            twist_covariance=cov[6:, 6:],
            acceleration_sensitivity=np.zeros((12, 6)),
        )
        step = filt.update(k * 33_333_333, est, prior=prior)
        _ = step.current
        filt.predict((k + 1) * 33_333_333)
    filt.flush()


def _split_batch(solver: str, first: bool) -> None:
    """Compile (or load) one share of the callees of ``solver``'s cold RANSAC batch
    (:func:`.estimation.batch.ransac_batch`, compiled first and alone on a cold frame's path)
    with the argument types the batch passes them: ``first``: the batched solver kernels (the first
    process, before its warm-up); else Lambda Twist's batch and the MSAC scoring (the second
    process, before :func:`warm_late`), which the first process's batch reaches after the
    kernels and then loads from numba's cache. Nothing for a solver without a fused batch."""
    fused = fused_kernels(solver)
    if fused is None:
        return
    if first:
        compile_kernel_set(fused[0])
        return
    lambda_twist_batch(np.zeros((1, 3, 3)), np.zeros((1, 3, 3)))
    cam, uv, X, _ = _problem()
    fr = prepare_frame(uv, X, cam, np.inf, np.random.default_rng(0))
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
    )


@contextlib.contextmanager
def _parallel(solvers: list[str], track: bool, jobs: int, log: Callable[[str], object] | None):
    """While the body compiles: with ``jobs`` > 1 and some solver's fused RANSAC kernels not
    cached, a second compiling process (:class:`_SecondProcess`, with the tracker's frames if
    ``track``), and this process's share of each solver's cold batch compiled first
    (:func:`_split_batch`); the second process is stopped when the body is done. Yields the
    :class:`_SecondProcess` (its :attr:`~_SecondProcess.kernels` complete after the block) or
    None."""
    helper = None
    if jobs > 1 and not all(fused_cached(s) for s in solvers):
        helper = _SecondProcess(solvers, track, log)
    try:
        if helper is not None:
            for s in solvers:
                _split_batch(s, first=True)
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


#: a progress line of :func:`~rs_localizer.jit_cache.compile_progress`: kernel, seconds
_COMPILED = re.compile(r"compiled (\S+) in ([0-9.]+) s")

#: the helper process: the package's parent directory first on sys.path (not the working
#: directory's copy of the package, if any), then :func:`_second_main`
_HELPER = (
    "import sys; sys.path.insert(0, sys.argv[1]); "
    "from rs_localizer.warmup import _second_main; _second_main(sys.argv[2:])"
)


def _second_main(argv: list[str]) -> None:
    """The helper process of :class:`_SecondProcess` (``argv``: ``track`` or ``alone``, then
    the solvers): its share of each solver's cold RANSAC batch (:func:`_split_batch`), then
    :func:`warm_late` for each solver; then, with ``track``, once the first
    process has cached a solver's cold RANSAC batch, the tracker over the warm-up's videos
    (planar first: the first process does the 3D scenes first), which compiles the kernels of
    tracked and planar frames while the first process compiles the rest of a cold frame's.
    Progress lines on stdout."""
    tracking = TrackerOptions() if argv[0] == "track" else None
    with compile_progress(lambda m: print(m, flush=True)):
        for s in argv[1:]:
            _split_batch(s, first=False)
        for s in argv[1:]:
            warm_late(s, tracking=tracking)
        if tracking is None:
            return
        for s in argv[1:]:
            while not fused_cached(s, anchored=False):  # (the first process stops us)
                time.sleep(0.2)
            _track(s, None, tracking, planar_first=True)


class _SecondProcess:
    """:func:`_second_main` for ``solvers`` (with the default tracker if ``track``) in another
    Python process (the same interpreter and package, the same environment: numba caches where
    this process does), started at once. ``log`` receives its progress lines; :attr:`kernels`
    the (name, seconds) of what it compiled. A helper that cannot start or fails only costs
    time: this process compiles what is missing."""

    def __init__(self, solvers: list[str], track: bool, log: Callable[[str], object] | None):
        self.kernels: list[tuple[str, float]] = []
        self._log = log
        try:
            self._proc = subprocess.Popen(
                [
                    sys.executable,
                    "-c",
                    _HELPER,
                    os.path.dirname(PACKAGE_DIR),
                    "track" if track else "alone",
                    *solvers,
                ],
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
            if line and self._log is not None:
                self._log(f"[second process] {line}")

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


def compile_kernels(
    solvers: Iterable[str] = DEFAULT_SOLVERS,
    log: Callable[[str], object] = print,
    tracking: TrackerOptions | None = TrackerOptions(),
    jobs: int = DEFAULT_JOBS,
) -> dict:
    """Compile (or load) every kernel the estimator needs for ``solvers`` (with the video
    tracker's, for ``tracking``: the node's default), reporting each kernel numba compiles
    through ``log`` (see :func:`rs_localizer.jit_cache.compile_progress`); with ``jobs`` > 1
    a second process compiles part of the RANSAC batch and the kernels a frame needs later
    meanwhile (module docstring).

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
        _parallel(solvers, tracking is not None, jobs, log) as helper,
    ):
        for s in solvers:
            per[s], _ = warm_up(s, tracking=tracking)
    return {
        "seconds": time.perf_counter() - tic,
        "kernels": prog.kernels + (helper.kernels if helper is not None else []),
        "cache": cache_state(),
        "solvers": per,
    }


#: the background compile's state (:func:`background_state`)
_BACKGROUND = {
    "state": "off",
    "reason": None,
    "seconds": None,
    "failures": 0,
    "uncompiled_hz": None,
}
_BACKGROUND_LOCK = threading.Lock()

#: the background compiling process: the package's parent directory first on sys.path, then
#: :func:`_background_main` with the pickled (solver, options, tracking, gyro) on stdin
_BACKGROUND_HELPER = (
    "import sys; sys.path.insert(0, sys.argv[1]); "
    "from rs_localizer.warmup import _background_main; _background_main()"
)


def background_state() -> dict:
    """The background compilation of this process (:func:`start_background_compile`):
    ``{"state": "off" | "compiling" | "loading" | "compiled" | "failed", "reason": why it
    failed or None, "seconds": compile-and-load time once compiled, "failures": background
    compiles that failed, "uncompiled_hz": the uncompiled path's rate measured at start}``."""
    with _BACKGROUND_LOCK:
        return dict(_BACKGROUND)


def _background_main() -> None:
    """The background compiling process: :func:`warm_up` (one process: the node's process
    keeps the other cores) for the pickled (solver, options, tracking, gyro) read from stdin,
    so numba compiles and caches every kernel the node's frames need. Exit code 0 when
    done."""
    import pickle

    solver, options, tracking, gyro, nice = pickle.loads(sys.stdin.buffer.read())
    if nice and hasattr(os, "nice"):  # (the frames of the node's process come first)
        os.nice(nice)
    with _compile_lock(), compile_progress(lambda m: print(m, flush=True)):
        warm_up(solver, options, tracking, jobs=1, gyro=gyro)


@contextlib.contextmanager
def _compile_lock():
    """One background compile at a time per numba cache (several nodes starting at once on
    a cold cache: the first compiles, the others then load most kernels from the cache): an
    exclusive ``flock`` on a file in the temporary directory named after the cache. Without
    ``fcntl`` (not POSIX) no lock."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    import hashlib
    import tempfile

    key = hashlib.sha1(str(cache_state()["dir"]).encode()).hexdigest()[:16]
    path = os.path.join(tempfile.gettempdir(), f"rs_localizer_compile_{key}.lock")
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def uncompiled_rate(n: int = 500, frames: int = 2) -> float:
    """Frames per second of the uncompiled path on :func:`_problem`'s 3D scene with ``n``
    correspondences (a fifth of them outliers): the last of ``frames`` runs (the first one
    also warms the path up: first calls into SciPy and OpenCV)."""
    from .estimation.uncompiled import estimate_uncompiled

    cam, uv, X, _ = _problem(n)
    rng = np.random.default_rng(5)
    bad = rng.random(n) < 0.2
    uv = uv.copy()
    uv[bad] = rng.uniform([0, 0], [639, 479], (int(bad.sum()), 2))
    dt = np.inf
    for _ in range(max(frames, 1)):
        tic = time.perf_counter()
        estimate_uncompiled(uv, X, cam)
        dt = time.perf_counter() - tic
    return 1.0 / dt


def start_background_compile(
    solver: str,
    options: EstimateOptions | None = None,
    tracking: TrackerOptions | None = None,
    gyro: bool = False,
    log: Callable[[str], object] = print,
    warn: Callable[[str], object] | None = None,
    nice: int = 10,
) -> bool:
    """Solve at once, compile meanwhile: switch this process's estimator to the uncompiled
    path (:func:`~rs_localizer.estimation.uncompiled.use_compiled_kernels`), compile the
    kernels ``solver`` (with ``options``, ``tracking``, ``gyro``) needs in another Python
    process (at ``nice``), and once it has cached them, load them here in a background thread
    (the frames go on uncompiled meanwhile) and switch back to the compiled path: the next
    frame uses them. Logs what it does through ``log`` (once), a failure through ``warn``
    (once: numba is not available, the compiling process cannot start, crashes or is killed,
    the kernels were not cached, or loading them fails); the frames then stay on the
    uncompiled path and :func:`background_state` counts it.

    Returns:
        False (nothing started) when the solver has no uncompiled path
        (:data:`~rs_localizer.estimation.uncompiled.UNCOMPILED_SOLVERS`), else True.
    """
    from .estimation.uncompiled import UNCOMPILED_SOLVERS, use_compiled_kernels

    if solver not in UNCOMPILED_SOLVERS:
        return False
    with _BACKGROUND_LOCK:  # (several cameras in one process: one background compile)
        if _BACKGROUND["state"] in ("compiling", "loading"):
            return True
    warn = warn or log
    use_compiled_kernels(False)
    hz = uncompiled_rate()
    with _BACKGROUND_LOCK:
        _BACKGROUND.update(state="compiling", reason=None, seconds=None, uncompiled_hz=hz)
    log(
        f"compiling kernels in the background: frames are solved on the uncompiled path, "
        f"~{hz:.0f} Hz with 500 correspondences, until they are ready (`rs-localizer "
        "compile` after installing avoids this)"
    )
    if numba_error() is not None:
        _background_failed(f"numba is not available: {numba_error()}", warn)
        return True
    args = (solver, options, tracking, gyro)
    threading.Thread(
        target=_background_run, args=(args, log, warn, nice), daemon=True, name="compile"
    ).start()
    return True


def _background_failed(reason: str, warn) -> None:
    """Record and say once that the background compile failed (:func:`background_state`)."""
    with _BACKGROUND_LOCK:
        _BACKGROUND.update(state="failed", reason=reason)
        _BACKGROUND["failures"] += 1
    warn(f"kernels not compiled ({reason}): frames stay on the uncompiled path")


def fall_back_uncompiled(solver: str, reason: str, warn: Callable[[str], object]) -> bool:
    """The compiled kernels cannot be used (``reason``: e.g. a corrupt or foreign numba cache
    the warm-up could not load): switch this process to the uncompiled path, say why once
    through ``warn`` and count it (:func:`background_state`). False (nothing changed) for a
    solver without an uncompiled path."""
    from .estimation.uncompiled import UNCOMPILED_SOLVERS, use_compiled_kernels

    if solver not in UNCOMPILED_SOLVERS:
        return False
    use_compiled_kernels(False)
    _background_failed(reason, warn)
    return True


def _stop(proc: subprocess.Popen) -> None:
    """End a background compiling process still running (at this process's exit)."""
    _BACKGROUND["exiting"] = True
    if proc.poll() is None:
        proc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=5.0)


def _background_run(args: tuple, log, warn, nice: int) -> None:
    """The thread of :func:`start_background_compile`."""
    solver, options, tracking, gyro = args
    import pickle

    from .estimation.uncompiled import compiled_path, use_compiled_kernels

    tic = time.perf_counter()

    def fail(reason: str) -> None:
        _background_failed(reason, warn)

    try:
        proc = subprocess.Popen(
            [sys.executable, "-c", _BACKGROUND_HELPER, os.path.dirname(PACKAGE_DIR)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        atexit.register(_stop, proc)  # (not left compiling after this process ends)
        out, _ = proc.communicate(pickle.dumps((*args, nice)))
    except (OSError, pickle.PicklingError) as e:
        fail(f"the compiling process could not start: {e}")
        return
    if proc.returncode != 0:
        if _BACKGROUND.get("exiting"):  # (stopped at this process's exit: not a failure)
            return
        lines = out.decode(errors="replace").strip().splitlines()
        how = (
            f"was killed by signal {-proc.returncode}"
            if proc.returncode < 0
            else f"ended with exit code {proc.returncode}"
        )
        fail(f"the compiling process {how}" + (f" ({lines[-1]})" if lines else ""))
        return
    if not fused_cached(solver, anchored=False):
        fail(f"compiled but not cached: is the numba cache {cache_state()['dir']} writable?")
        return
    with _BACKGROUND_LOCK:
        _BACKGROUND["state"] = "loading"
    try:
        with compiled_path(), compile_progress() as prog:
            warm_up(solver, options, tracking, jobs=1, gyro=gyro)
    except Exception as e:  # (a corrupt cache entry numba cannot load, ...)
        fail(f"loading the compiled kernels failed: {type(e).__name__}: {e}")
        return
    use_compiled_kernels(True)
    dt = time.perf_counter() - tic
    with _BACKGROUND_LOCK:
        _BACKGROUND.update(state="compiled", seconds=dt)
    extra = f" ({len(prog.kernels)} compiled in this process)" if prog.kernels else ""
    log(f"kernels compiled and loaded in {dt:.1f} s{extra}: frames use them from now on")
