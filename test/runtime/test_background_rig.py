"""The background compile of a rig node (rs_localizer.runtime.background with ``rig=``): the
rig frames' ready implementation is NumPy while it runs, the compiled kernels once they are
cached and loaded (warm_rig in this process); a failure keeps them on NumPy, said once."""

import sys
import time

from helpers.rig import mounts_of

from rs_localizer.runtime import background as B
from rs_localizer.sim.rig_video import default_rig
from rs_localizer.tracking.rig import RigSettings


def _rig():
    return RigSettings(mounts_of(default_rig(3))), None


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
        assert B.start_background_compile("rig", log=logs.append, warn=warns.append, rig=_rig())
        assert B.ready_rig_implementation() == "numpy"
        st = _wait()
        assert st["state"] == "failed" and st["failures"] == before + 1
        assert "exit code 3 (boom)" in st["reason"]
        assert st["uncompiled_hz"] is None  # (the camera's NumPy rate is not measured)
        assert B.ready_rig_implementation() == "numpy"
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
        assert B.start_background_compile("rig", log=logs.append, warn=logs.append, rig=rig)
        st = _wait()
        assert st["state"] == "compiled", st
        assert B.ready_rig_implementation() == "compiled"
        assert len(ran) == 1 and ran[0][0] is rig[0]
        assert "frames use them from now on" in logs[-1]
    finally:
        B._hold(False)
