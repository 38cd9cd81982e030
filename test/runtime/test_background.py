"""The runtime's ready implementation of the estimator (rs_localizer.runtime.background): the
compiled kernels unless a background compile holds the frames on the NumPy implementation;
the background compile switches over once the kernels are cached and loaded, its failures
(a crash, nothing cached, a warm-up that cannot load the cache, numba missing) keep the frames
on NumPy, said once and counted."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.estimate import EstimateOptions, PlausibilityOptions
from rs_localizer.runtime import background as B
from rs_localizer.sim.synthetic import make_frame, paper_camera

ROOT = Path(__file__).resolve().parents[2]

#: the protocol's scene has no physical scale (see sim.synthetic.protocol_options)
OPTS = EstimateOptions(
    plausibility=PlausibilityOptions(max_angular_velocity=np.inf, max_linear_velocity=np.inf)
)


def compiled_ready():
    return B.compiled_ready()


def _release():
    """The runtime's ready implementation back to the compiled kernels (after a test held
    the frames on NumPy)."""
    B._hold(False)


def test_default_is_compiled_and_explicit():
    """``implementation=None`` is the compiled kernels in a process that compiles them (the
    tests'), whatever the runtime says is ready: the runtime's state reaches an estimate only
    through the caller's explicit argument; the same frame twice on NumPy is bit-identical."""
    cam = paper_camera()
    f = make_frame(100, 300, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.3)
    ref = estimate_rs_pose(f.points_px, f.X, cam, "r6p_1lin", OPTS, implementation="numpy")
    assert compiled_ready()
    assert B.ready_implementation("r6p_1lin") == "compiled"
    B._hold(True)
    try:
        assert not compiled_ready()
        assert B.ready_implementation("r6p_1lin") == "numpy"
        assert B.ready_implementation("r9p") == "compiled"  # (no NumPy implementation)
        default = estimate_rs_pose(f.points_px, f.X, cam, options=OPTS)
        est = estimate_rs_pose(
            f.points_px, f.X, cam, options=OPTS, implementation=B.ready_implementation("r6p_1lin")
        )
    finally:
        _release()
    assert default.implementation == "compiled"
    assert est.implementation == "numpy"
    np.testing.assert_array_equal(est.model.R, ref.model.R)
    np.testing.assert_array_equal(est.inliers, ref.inliers)


def test_background_compile_failure_counted(monkeypatch):
    """A background compile that crashes leaves the frames on the NumPy implementation,
    counted once with its reason."""
    import rs_localizer.runtime.warmup as W

    crash = [sys.executable, "-c", "import sys; print('boom'); sys.exit(3)"]
    monkeypatch.setattr(B, "_background_command", lambda: (crash, None, None))
    monkeypatch.setattr(W, "fused_cached", lambda *a, **k: False)
    before = B.background_state()["failures"]
    logs, warns = [], []
    try:
        assert B.start_background_compile(
            B.CameraKernels("r6p_1lin"), log=logs.append, warn=warns.append
        )
        assert not compiled_ready()
        import time

        deadline = time.monotonic() + 60
        while B.background_state()["state"] == "compiling" and time.monotonic() < deadline:
            time.sleep(0.05)
        st = B.background_state()
        assert st["state"] == "failed"
        assert st["failures"] == before + 1
        assert "ended with exit code 3 (boom)" in st["reason"]
        assert not compiled_ready()
        assert len(warns) == 1 and "uncompiled" in warns[0]
        assert len(logs) == 1 and "compiling kernels in the background" in logs[0]
        assert st["uncompiled_hz"] > 0
    finally:
        _release()


def test_background_compile_switches_over():
    """With the kernels cached, the background compile's process finishes, the kernels are
    loaded in a background thread and the frames switch to the compiled path; meanwhile the
    runtime's ready implementation is NumPy."""
    import time

    logs = []
    try:
        assert B.start_background_compile(
            B.CameraKernels("r6p_1lin"), log=logs.append, warn=logs.append
        )
        assert B.ready_implementation("r6p_1lin") == "numpy"
        deadline = time.monotonic() + 300
        while B.background_state()["state"] in ("compiling", "loading"):
            assert time.monotonic() < deadline, logs
            time.sleep(0.1)
        st = B.background_state()
        assert st["state"] == "compiled", st
        assert B.ready_implementation("r6p_1lin") == "compiled"
        assert st["seconds"] > 0
        assert "frames use them from now on" in logs[-1]
    finally:
        _release()


_NO_NUMBA = """
import importlib.abc, json, sys


class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("numba", "llvmlite"):
            raise ImportError(f"No module named {name!r} (blocked)")


sys.meta_path.insert(0, Block())
from rs_localizer.runtime.jit_cache import numba_error
from rs_localizer.runtime.background import background_state, compiled_ready
from rs_localizer.ros import config as C
from rs_localizer.ros import params as P
from rs_localizer.ros.bags.bag_io import RosbagsMessages
from rs_localizer.ros.pipeline import log_warm_up
from helpers.camera_node import CameraNode
from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

frames, _, cam, _ = generate_sequence(SequenceConfig(num_frames=3, num_points=200, seed=4))
cfg = C.build_config({**P.default_values(), "camera_info_wait": 0.0})
logs = []
log = type("L", (), {"info": lambda s, m: logs.append(m), "warning": lambda s, m: logs.append(m)})()
log_warm_up(cfg.solver, cfg.options, cfg.tracking, log, background=True)
msgs = RosbagsMessages()
pipe = CameraNode(cfg)
pipe.add_camera_info(msgs.camera_info(cam, frames[0].stamp_ns, "cam"))
solved = [pipe.process(msgs.cloud(f.uv, f.xyz, f.ids, f.stamp_ns, "cam"), "correspondences").solved
          for f in frames]
print(json.dumps({"error": numba_error(), "compiled": compiled_ready(),
                  "solved": solved, "state": background_state(), "logs": logs}))
"""


def test_runs_without_numba():
    """With numba missing (its import blocked), the package imports, the node's warm-up says
    once why the kernels are not compiled and counts it, and the pipeline solves frames on the
    uncompiled path."""
    r = subprocess.run(
        [sys.executable, "-c", _NO_NUMBA],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join((str(ROOT), str(ROOT / "test")))},
        timeout=180,
    )
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert "blocked" in res["error"]
    assert res["compiled"] is False
    assert res["solved"] == [True, True, True]
    assert res["state"]["state"] == "failed" and res["state"]["failures"] == 1
    assert "numba is not available" in res["state"]["reason"]
    assert sum("frames stay on the uncompiled path" in m for m in res["logs"]) == 1


class _Log:
    def __init__(self):
        self.lines = []

    def info(self, m):
        self.lines.append(m)

    def warning(self, m):
        self.lines.append(m)


def test_warm_up_failure_falls_back(monkeypatch):
    """A cached warm-up that fails (numba cannot load a corrupt or foreign cache entry: it
    raises) leaves the node's frames on the uncompiled path, said once and counted."""
    import rs_localizer.runtime.warmup as W
    from rs_localizer.ros.pipeline import log_warm_up

    def broken(*a, **k):
        raise ValueError("invalid literal for int() with base 10: 'arbage'")

    monkeypatch.setattr(W, "fused_cached", lambda *a, **k: True)
    monkeypatch.setattr(W, "warm_up", broken)
    before = B.background_state()["failures"]
    log = _Log()
    try:
        log_warm_up("r6p_1lin", None, None, log, background=True)
        assert not compiled_ready()
        st = B.background_state()
        assert st["state"] == "failed" and st["failures"] == before + 1
        assert "ValueError" in st["reason"]
        assert sum("frames stay on the uncompiled path" in m for m in log.lines) == 1
    finally:
        _release()


def test_compiled_but_not_cached(monkeypatch):
    """A background compile that ends well but leaves nothing in the cache (a read-only
    cache directory: numba then only warns) keeps the frames uncompiled, with the reason."""
    import time

    import rs_localizer.runtime.warmup as W

    monkeypatch.setattr(
        B, "_background_command", lambda: ([sys.executable, "-c", "pass"], None, None)
    )
    monkeypatch.setattr(W, "fused_cached", lambda *a, **k: False)
    warns = []
    try:
        B.start_background_compile(
            B.CameraKernels("r6p_1lin"), log=lambda m: None, warn=warns.append
        )
        deadline = time.monotonic() + 60
        while B.background_state()["state"] == "compiling" and time.monotonic() < deadline:
            time.sleep(0.05)
        st = B.background_state()
        assert st["state"] == "failed" and "not cached" in st["reason"]
        assert not compiled_ready() and len(warns) == 1
    finally:
        _release()
