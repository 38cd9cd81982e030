"""Solve at once, compile meanwhile: the background compile of a node's start on a cold numba
cache, and which implementation of the estimator is ready in this process.

The estimator has two implementations (:mod:`rs_localizer.estimation.implementation`):
the compiled kernels and NumPy. Which one is *ready* is this process's state, kept here:
:func:`ready_implementation` says it, and the callers that solve frames (the video's
:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`, the node through it) pass it to
``estimate_rs_pose(..., implementation=...)``. The compiled kernels are ready unless the
process cannot or must not compile them
(:func:`~rs_localizer.estimation.implementation.compiled_by_default`) or they are being
compiled in the background, or that failed.

:func:`start_background_compile` makes the NumPy implementation the ready one, compiles the
kernels in another Python process (:mod:`.background_process`, ``python -m
rs_localizer.runtime.background_process``), and once they are cached, loads them in a thread
of this process and makes them the ready one: the next frame uses them; what it compiles is
a camera's :class:`CameraKernels` or a rig's :class:`RigKernels` (a rig's frames take
``ready_implementation()``, :func:`~rs_localizer.estimation.rig.estimate_rig_pose`'s).
:func:`fall_back_uncompiled` keeps the frames on the NumPy implementation when the kernels
cannot be used (a corrupt cache). :func:`background_state` reports it all (the node's
diagnostics).
"""

from __future__ import annotations

import atexit
import contextlib
import pickle
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TextIO

import numpy as np

from ..estimation.estimate import EstimateOptions, RansacOptions, estimate_rs_pose
from ..estimation.implementation import COMPILED, NUMPY, NUMPY_SOLVERS, compiled_by_default
from ..tracking.tracker import TrackerOptions
from ..tracking.video import SINGLE_CAMERA_SOLVER, LocalizerSettings
from . import warmup
from .jit_cache import cache_state, compile_progress, numba_error

__all__ = [
    "CameraKernels",
    "RigKernels",
    "background_state",
    "cold_compile_note",
    "compiled_ready",
    "fall_back_uncompiled",
    "frames_alone_options",
    "ready_implementation",
    "start_background_compile",
    "uncompiled_rate",
]

#: the background compile's state (:func:`background_state`)
_BACKGROUND = {
    "state": "off",
    "reason": None,
    "seconds": None,
    "failures": 0,
    "uncompiled_hz": None,
}
_BACKGROUND_LOCK = threading.Lock()
#: the frames are held on the NumPy implementation (a background compile running, or one
#: that failed)
_HELD = {"numpy": False}


def compiled_ready() -> bool:
    """True when the compiled kernels are this process's ready implementation: the process
    compiles them (:func:`~rs_localizer.estimation.implementation.compiled_by_default`) and
    no background compile holds the frames on the NumPy implementation."""
    return not _HELD["numpy"] and compiled_by_default()


def ready_implementation(solver: str | None = None) -> str:
    """The implementation the frames of a camera's ``solver`` (``estimate_rs_pose``'s
    ``implementation``), or with None a rig's frames
    (:func:`~rs_localizer.estimation.rig.estimate_rig_pose`'s), take now: ``"compiled"``
    when :func:`compiled_ready` or the solver has no NumPy implementation
    (:data:`~rs_localizer.estimation.implementation.NUMPY_SOLVERS`), else ``"numpy"``."""
    numpy = solver is None or solver in NUMPY_SOLVERS
    return NUMPY if numpy and not compiled_ready() else COMPILED


def _hold(numpy: bool) -> None:
    _HELD["numpy"] = bool(numpy)


def background_state() -> dict:
    """The background compilation of this process (:func:`start_background_compile`):
    ``{"state": "off" | "compiling" | "loading" | "compiled" | "failed", "reason": why it
    failed or None, "seconds": compile-and-load time once compiled, "failures": background
    compiles that failed, "uncompiled_hz": the NumPy implementation's rate measured at
    start}``."""
    with _BACKGROUND_LOCK:
        return dict(_BACKGROUND)


def uncompiled_rate(n: int = 500, frames: int = 2) -> float:
    """Frames per second of the NumPy implementation on :func:`.warmup.synthetic_problem`'s
    3D scene with ``n`` correspondences (a fifth of them outliers): the last of ``frames``
    runs (the first one also warms the path up: first calls into SciPy and OpenCV)."""
    cam, uv, X, _ = warmup.synthetic_problem(n)
    rng = np.random.default_rng(5)
    bad = rng.random(n) < 0.2
    uv = uv.copy()
    uv[bad] = rng.uniform([0, 0], [639, 479], (int(bad.sum()), 2))
    dt = np.inf
    for _ in range(max(frames, 1)):
        tic = time.perf_counter()
        estimate_rs_pose(uv, X, cam, implementation=NUMPY)
        dt = time.perf_counter() - tic
    return 1.0 / dt


@dataclass(frozen=True)
class CameraKernels:
    """What a camera's frames compile (:func:`.warmup.warm_up`'s arguments): ``solver``'s
    kernels with ``options``, ``tracking`` (None: every frame alone), ``gyro`` (its path too)."""

    solver: str
    options: EstimateOptions | None = None
    tracking: TrackerOptions | None = None
    gyro: bool = False
    what, command = "kernels", "compile"

    @property
    def numpy(self) -> bool:
        return self.solver in NUMPY_SOLVERS

    def cached(self) -> bool:
        return warmup.fused_cached(self.solver, anchored=False)

    def warm(self) -> None:
        warmup.warm_up(self.solver, self.options, self.tracking, jobs=1, gyro=self.gyro,
                       implementation=COMPILED)  # fmt: skip

    def uncompiled_hz(self) -> float:
        return uncompiled_rate()


@dataclass(frozen=True)
class RigKernels:
    """What a rig's frames compile (:func:`.warmup.warm_rig`'s arguments): the rig's kernels
    for its ``settings`` and its cameras' RS ``timing`` (a rig of one camera,
    :attr:`~rs_localizer.tracking.video.LocalizerSettings.single_camera`: its camera's); its frames
    wait on NumPy."""

    settings: LocalizerSettings
    timing: dict | None = None
    what, command, numpy = "the rig's kernels", "compile --params-file", True

    def cached(self) -> bool:
        if self.settings.single_camera:  # (solved as the camera: the camera's kernels)
            return warmup.fused_cached(SINGLE_CAMERA_SOLVER, anchored=False)
        return warmup.rig_cached()

    def warm(self) -> None:
        warmup.warm_rig(self.settings, self.timing)

    def uncompiled_hz(self) -> None:
        return None  # (the rig's NumPy rate is not measured)


def cold_compile_note(kernels: CameraKernels | RigKernels, stream: TextIO | None = None) -> bool:
    """For the offline commands that solve frames on the compiled kernels and compile them
    on the first frame (``replay``, ``calibrate-rig``, ``calibrate-readout``; the node
    compiles in the background instead, :func:`start_background_compile`): say once on
    ``stream`` (None: ``sys.stderr``), before the first frame, that ``kernels``
    (:class:`CameraKernels`, :class:`RigKernels`) compile now, once, into numba's cache,
    roughly how long it takes (``rs-localizer compile`` took 35-110 s on an empty cache,
    docs/install.md "Start-up") and that ``rs-localizer compile`` does it ahead. Says
    nothing when they are cached (``kernels.cached()``, the node's check) or this process
    does not compile them (:func:`compiled_ready` false for frames that have a NumPy
    implementation).

    Returns:
        True when it said so.
    """
    if (kernels.numpy and not compiled_ready()) or kernels.cached():
        return False
    print(
        f"compiling {kernels.what} before the first frame: numba compiles them once and caches "
        f"them in {cache_state()['dir']} (about half a minute to two minutes, longer on a busy "
        "machine); `rs-localizer compile [--params-file FILE]` after installing does it ahead",
        file=stream or sys.stderr,
        flush=True,
    )
    return True


def frames_alone_options(
    threshold_px: float, solver: str = SINGLE_CAMERA_SOLVER, stream: TextIO | None = None
) -> EstimateOptions:
    """The single-camera estimator's options of an offline command that poses each frame
    alone with ``solver`` on the compiled kernels (``calibrate-rig``, ``calibrate-readout``):
    the defaults with the RANSAC threshold ``threshold_px`` (px). Their
    :class:`CameraKernels` are told on ``stream`` first when they compile now
    (:func:`cold_compile_note`)."""
    options = EstimateOptions(ransac=RansacOptions(threshold_px=threshold_px))
    cold_compile_note(CameraKernels(solver, options), stream)
    return options


def start_background_compile(
    kernels: CameraKernels | RigKernels,
    log: Callable[[str], object] = print,
    warn: Callable[[str], object] | None = None,
    nice: int = 10,
) -> bool:
    """Solve at once, compile meanwhile: make the NumPy implementation this process's ready
    one (:func:`ready_implementation`), compile ``kernels`` (:class:`CameraKernels`,
    :class:`RigKernels`: ``warm()``) in another Python process (at ``nice``), and once they
    are cached (``cached()``), load them here in a background thread (the frames go on with
    NumPy meanwhile) and make them the ready implementation again: the next frame uses them.
    Logs what it does through ``log`` (once), a failure through ``warn`` (once: numba is not
    available, the compiling process cannot start, crashes or is killed, the kernels were not
    cached, or loading them fails); the frames then stay on the NumPy implementation and
    :func:`background_state` counts it.

    Returns:
        False (nothing started) when the frames have no NumPy implementation to take
        meanwhile (a camera's solver not in
        :data:`~rs_localizer.estimation.implementation.NUMPY_SOLVERS`), else True.
    """
    if not kernels.numpy:
        return False
    with _BACKGROUND_LOCK:  # (several cameras in one process: one background compile)
        if _BACKGROUND["state"] in ("compiling", "loading"):
            return True
    warn = warn or log
    _hold(True)
    hz = kernels.uncompiled_hz()
    with _BACKGROUND_LOCK:
        _BACKGROUND.update(state="compiling", reason=None, seconds=None, uncompiled_hz=hz)
    rate = "" if hz is None else f", ~{hz:.0f} Hz with 500 correspondences,"
    log(
        f"compiling {kernels.what} in the background: frames are solved on the uncompiled "
        f"path{rate} until they are ready (`rs-localizer {kernels.command}` after installing "
        "avoids this)"
    )
    if numba_error() is not None:
        _background_failed(f"numba is not available: {numba_error()}", warn)
        return True
    threading.Thread(
        target=_background_run, args=(kernels, log, warn, nice), daemon=True, name="compile"
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
    the warm-up could not load): make the NumPy implementation this process's ready one, say
    why once through ``warn`` and count it (:func:`background_state`). False (nothing
    changed) for a solver without a NumPy implementation."""
    if solver not in NUMPY_SOLVERS:
        return False
    _hold(True)
    _background_failed(reason, warn)
    return True


def _background_command() -> tuple[list[str], dict[str, str] | None, str | None]:
    """The compiling process's command, environment, directory (:func:`.warmup.package_command`)."""
    return warmup.package_command("rs_localizer.runtime.background_process")


def _stop(proc: subprocess.Popen) -> None:
    """End a background compiling process still running (at this process's exit)."""
    _BACKGROUND["exiting"] = True
    if proc.poll() is None:
        proc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=5.0)


def _background_run(kernels, log, warn, nice: int) -> None:
    """The thread of :func:`start_background_compile`."""
    tic = time.perf_counter()
    fail = lambda reason: _background_failed(reason, warn)  # noqa: E731
    try:
        cmd, env, cwd = _background_command()
        proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)  # fmt: skip
        atexit.register(_stop, proc)  # (not left compiling after this process ends)
        out, _ = proc.communicate(pickle.dumps((kernels, nice)))
    except (OSError, pickle.PicklingError) as e:
        return fail(f"the compiling process could not start: {e}")
    if (rc := proc.returncode) != 0:
        if _BACKGROUND.get("exiting"):  # (stopped at this process's exit: not a failure)
            return
        lines = out.decode(errors="replace").strip().splitlines()
        how = f"was killed by signal {-rc}" if rc < 0 else f"ended with exit code {rc}"
        return fail(f"the compiling process {how}" + (f" ({lines[-1]})" if lines else ""))
    if not kernels.cached():
        return fail(f"compiled but not cached: is the numba cache {cache_state()['dir']} writable?")
    with _BACKGROUND_LOCK:
        _BACKGROUND["state"] = "loading"
    try:
        with compile_progress() as prog:
            kernels.warm()
    except Exception as e:  # (a corrupt cache entry numba cannot load, ...)
        return fail(f"loading the compiled kernels failed: {type(e).__name__}: {e}")
    _hold(False)
    dt = time.perf_counter() - tic
    with _BACKGROUND_LOCK:
        _BACKGROUND.update(state="compiled", seconds=dt)
    extra = f" ({len(prog.kernels)} compiled in this process)" if prog.kernels else ""
    log(f"kernels compiled and loaded in {dt:.1f} s{extra}: frames use them from now on")
