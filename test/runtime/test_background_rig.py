"""The background compile of a rig node (rs_localizer.runtime.background with RigKernels): the
rig frames' ready implementation is NumPy while it runs, the compiled kernels once they are
cached and loaded (warm_rig in this process); a failure keeps them on NumPy, said once."""

import sys
import time

from helpers.rig import mounts_of

from rs_localizer.runtime import background as B
from rs_localizer.sim.trajectory import default_rig
from rs_localizer.tracking.video import LocalizerSettings


def _rig():
    return B.RigKernels(LocalizerSettings(mounts_of(default_rig(3))))


def _wait():
    deadline = time.monotonic() + 600
    while B.background_state()["state"] in ("compiling", "loading"):
        assert time.monotonic() < deadline
        time.sleep(0.05)
    return B.background_state()


def test_a_rig_background_compile_that_crashes_keeps_the_rig_frames_on_numpy(monkeypatch):
    crash = [sys.executable, "-c", "import sys; print('boom'); sys.exit(3)"]
    monkeypatch.setattr(B, "_background_command", lambda: (crash, None, None))
    before = B.background_state()["failures"]
    logs, warns = [], []
    try:
        assert B.start_background_compile(_rig(), log=logs.append, warn=warns.append)
        assert B.ready_implementation() == "numpy"
        st = _wait()
        assert st["state"] == "failed" and st["failures"] == before + 1
        assert "exit code 3 (boom)" in st["reason"]
        assert st["uncompiled_hz"] is None  # (the camera's NumPy rate is not measured)
        assert B.ready_implementation() == "numpy"
        assert len(logs) == 1 and "rig's kernels in the background" in logs[0]
        assert len(warns) == 1 and "uncompiled" in warns[0]
    finally:
        B._hold(False)


def test_a_rig_background_compile_loads_the_rig_kernels_and_switches_over(monkeypatch):
    """The compiling process done (here one that does nothing) and the rig's kernels cached
    (as rig_cached says): warm_rig loads them in this process and the rig frames take the
    compiled implementation."""
    import rs_localizer.runtime.warmup as W

    monkeypatch.setattr(
        B, "_background_command", lambda: ([sys.executable, "-c", "pass"], None, None)
    )
    monkeypatch.setattr(W, "rig_cached", lambda: True)
    ran = []
    real = W.warm_rig
    monkeypatch.setattr(W, "warm_rig", lambda *a: ran.append(a) or real(*a))
    logs = []
    rig = _rig()
    try:
        assert B.start_background_compile(rig, log=logs.append, warn=logs.append)
        st = _wait()
        assert st["state"] == "compiled", st
        assert B.ready_implementation() == "compiled"
        assert len(ran) == 1 and ran[0][0] is rig.settings
        assert "frames use them from now on" in logs[-1]
    finally:
        B._hold(False)


def test_the_compiling_process_warms_up_what_it_is_handed(monkeypatch):
    """The compiling process's ``main`` takes the pickled ``(kernels, nice)`` and warms that
    up: a rig's kernels through warm_rig with the rig's settings and timing, a camera's
    through warm_up with its solver, options, tracking and gyro."""
    import io
    import pickle

    import rs_localizer.runtime.warmup as W
    from rs_localizer.runtime import background_process

    ran = []
    monkeypatch.setattr(W, "warm_rig", lambda *a, **k: ran.append(("rig", a, k)))
    monkeypatch.setattr(W, "warm_up", lambda *a, **k: ran.append(("camera", a, k)))
    timing = {"front": (3e-5, None, "down")}
    rig = B.RigKernels(LocalizerSettings(mounts_of(default_rig(2))), timing)
    for kernels in (rig, B.CameraKernels("r6p_1lin", gyro=True)):
        stdin = type("In", (), {"buffer": io.BytesIO(pickle.dumps((kernels, 0)))})()
        monkeypatch.setattr(sys, "stdin", stdin)
        background_process.main()
    (what, a, _), (what2, a2, k2) = ran
    assert what == "rig" and a[1] == timing and set(a[0].mounts) == {"front", "left"}
    assert what2 == "camera" and a2[0] == "r6p_1lin" and k2["gyro"] is True


def test_a_rig_background_compile_through_the_real_compiling_process(rig_kernels):
    """The real compiling process handed a rig's kernels (pickled RigKernels; the rig's
    kernels already in the cache here, so it loads rather than compiles them): it warms them
    up, they are cached, loaded here, and the rig frames switch to the compiled
    implementation."""
    logs = []
    try:
        assert B.start_background_compile(_rig(), log=logs.append, warn=logs.append)
        assert B.ready_implementation() == "numpy"
        st = _wait()
        assert st["state"] == "compiled", (st, logs)
        assert B.ready_implementation() == "compiled"
        assert "frames use them from now on" in logs[-1]
    finally:
        B._hold(False)
