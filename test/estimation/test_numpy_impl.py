"""The estimator's NumPy implementation (rs_localizer.estimation.numpy_impl) against the
compiled one on the same frames: poses and velocities within the frames' own accuracy,
covariances of the same size, the same failure reasons on bad input; it compiles nothing (a
fresh process with an empty numba cache); ``estimate_rs_pose``'s ``implementation`` argument
and what the estimate records; the runtime's ready implementation while the kernels compile in
the background (rs_localizer.runtime.background), whose failures keep the frames on NumPy and
are counted."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.estimate import EstimateOptions, PlausibilityOptions
from rs_localizer.estimation.gyro import GyroMeasurement
from rs_localizer.estimation.implementation import NUMPY_UNUSED
from rs_localizer.estimation.options import RefineOptions
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.runtime import background as B
from rs_localizer.sim.synthetic import make_frame, paper_camera

ROOT = Path(__file__).resolve().parents[2]

#: the protocol's scene has no physical scale (see evaluation.bench.protocol_options)
OPTS = EstimateOptions(
    plausibility=PlausibilityOptions(max_angular_velocity=np.inf, max_linear_velocity=np.inf)
)


def estimate_numpy(uv, X, cam, solver="r6p_1lin", options=None):
    return estimate_rs_pose(uv, X, cam, solver, options, implementation="numpy")


def estimate_compiled(uv, X, cam, solver="r6p_1lin", options=None):
    return estimate_rs_pose(uv, X, cam, solver, options, implementation="compiled")


def compiled_ready():
    return B.compiled_ready()


def _release():
    """The runtime's ready implementation back to the compiled kernels (after a test held
    the frames on NumPy)."""
    B._hold(False)


def _frames(n=6, points=300, rs_speed=0.5):
    return [
        make_frame(100 + k, points, rs_speed=rs_speed, noise_px=1.0, outlier_ratio=0.3)
        for k in range(n)
    ]


@pytest.mark.parametrize("solver", ["r6p_1lin", "p3p"])
def test_same_pose_as_compiled(solver):
    """Against the ground truth, the uncompiled estimate is as accurate as the compiled one
    (both fit the same exact model with a robust loss; they differ by their RANSAC samples
    and the optimizer's stopping point): each error within 1.5x the compiled one plus a
    tenth of the frame's noise-limited accuracy, and the two estimates within that of each
    other; inlier sets agree on 97 % of the points, covariance standard deviations within
    a factor 1.5."""
    cam = paper_camera()
    for f in _frames(rs_speed=0.5 if solver == "r6p_1lin" else 0.0):
        u = estimate_numpy(f.points_px, f.X, cam, solver, OPTS)
        c = estimate_compiled(f.points_px, f.X, cam, solver, OPTS)
        assert u.success and c.success
        assert (u.implementation, c.implementation) == ("numpy", "compiled")
        assert u.ignored_inputs == c.ignored_inputs == ()
        rot_u, rot_c = rotation_angle_deg(u.R, f.R), rotation_angle_deg(c.R, f.R)
        assert rot_u <= 1.5 * rot_c + 0.01
        assert rotation_angle_deg(u.R, c.R) <= 0.02 + rot_c
        pos_u = np.linalg.norm(u.position - f.position)
        pos_c = np.linalg.norm(c.position - f.position)
        assert pos_u <= 1.5 * pos_c + 1e-3
        assert np.mean(u.inliers == c.inliers) >= 0.97
        assert u.num_valid == c.num_valid
        sd_u = np.sqrt(np.diag(u.covariance))
        sd_c = np.sqrt(np.diag(c.covariance))
        n = 12 if solver == "r6p_1lin" else 6
        ratio = sd_u[:n] / sd_c[:n]
        assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), ratio
        assert u.pose_covariance.shape == (6, 6)
        if solver == "r6p_1lin":
            om = np.linalg.norm(f.angular_velocity)
            err_u = np.linalg.norm(u.angular_velocity - f.angular_velocity) / om
            err_c = np.linalg.norm(c.angular_velocity - f.angular_velocity) / om
            assert err_u <= 1.5 * err_c + 0.01
            assert u.twist_covariance.shape == (6, 6)
            np.testing.assert_allclose(u.pose_covariance, u.pose_covariance.T)
        else:
            assert u.twist_covariance is None and c.twist_covariance is None
            np.testing.assert_array_equal(u.angular_velocity, 0.0)


def _bad_inputs():
    """(name, pixels, points, camera) of frames that give no pose."""
    cam = paper_camera()
    rng = np.random.default_rng(7)
    f = make_frame(3, 100, rs_speed=0.5, noise_px=0.5)
    line = np.column_stack([np.linspace(-1, 1, 40), np.zeros(40), np.full(40, 5.0)])
    X_rand = rng.uniform(-2, 2, (80, 3)) + [0, 0, 6]
    nan_rows = f.points_px.copy()
    nan_rows[: len(nan_rows) - 8] = np.nan
    return [
        ("too_few", f.points_px[:8], f.X[:8], cam),
        ("nan_rows", nan_rows, f.X, cam),
        ("collinear_3d", cam.project_rs(line, np.eye(3), np.zeros(3)), line, cam),
        (
            "pixels_on_a_line",
            np.column_stack([np.linspace(10, 900, 80), np.full(80, 400.0)]),
            X_rand,
            cam,
        ),
        ("all_outliers", rng.uniform(0, 1000, (80, 2)), X_rand, cam),
        ("identical_points", np.tile(f.points_px[:1], (30, 1)), np.tile(f.X[:1], (30, 1)), cam),
    ]


@pytest.mark.parametrize("case", _bad_inputs(), ids=lambda c: c[0])
def test_same_failure_reasons(case):
    """Bad input gives the compiled path's failure reason and row counts, never an
    exception."""
    _, uv, X, cam = case
    u = estimate_numpy(uv, X, cam, "r6p_1lin", OPTS)
    c = estimate_compiled(uv, X, cam, "r6p_1lin", OPTS)
    assert not c.success
    assert (u.implementation, c.implementation) == ("numpy", "compiled")
    assert (u.success, u.failure) == (c.success, c.failure)
    assert (u.num_valid, u.num_dropped, len(u.inliers)) == (
        c.num_valid,
        c.num_dropped,
        len(c.inliers),
    )


def test_shapes_and_solvers_raise():
    cam = paper_camera()
    with pytest.raises(ValueError):
        estimate_numpy(np.zeros((10, 3)), np.zeros((10, 3)), cam)
    with pytest.raises(ValueError, match="compiled"):
        estimate_numpy(np.zeros((10, 2)), np.zeros((10, 3)), cam, "r9p")
    with pytest.raises(ValueError, match="implementation"):
        estimate_rs_pose(np.zeros((10, 2)), np.zeros((10, 3)), cam, implementation="gpu")


def test_default_is_compiled_and_explicit():
    """``implementation=None`` is the compiled kernels in a process that compiles them (the
    tests'), whatever the runtime says is ready: the runtime's state reaches an estimate only
    through the caller's explicit argument; the same frame twice on NumPy is bit-identical."""
    cam = paper_camera()
    f = _frames(1)[0]
    ref = estimate_numpy(f.points_px, f.X, cam, "r6p_1lin", OPTS)
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
    np.testing.assert_array_equal(est.R, ref.R)
    np.testing.assert_array_equal(est.inliers, ref.inliers)


def test_ignored_inputs_recorded():
    """The NumPy implementation lists the inputs it was given and could not use (and its
    estimate equals the one without them); the compiled one uses them all, except a gyro for
    the global-shutter P3P."""
    cam = paper_camera()
    f = _frames(1)[0]
    n = len(f.X)
    gyro = GyroMeasurement(np.array([0.1, 0.0, 0.0]), 1e-4 * np.eye(3))
    extra = {
        "scores": np.linspace(1.0, 0.0, n),
        "gyro": gyro,
        "point_sigma": np.full(n, 0.01),
    }
    plain = estimate_numpy(f.points_px, f.X, cam, "r6p_1lin", OPTS)
    opts = EstimateOptions(
        plausibility=OPTS.plausibility, refine=RefineOptions(acceleration_sensitivity=True)
    )
    u = estimate_rs_pose(f.points_px, f.X, cam, "r6p_1lin", opts, implementation="numpy", **extra)
    assert u.implementation == "numpy"
    assert u.ignored_inputs == ("scores", "gyro", "point_sigma", "refine.acceleration_sensitivity")
    assert set(u.ignored_inputs) <= set(NUMPY_UNUSED)
    np.testing.assert_array_equal(u.R, plain.R)
    np.testing.assert_array_equal(u.inliers, plain.inliers)
    c = estimate_compiled(f.points_px, f.X, cam, "r6p_1lin", OPTS)
    assert c.ignored_inputs == ()
    p = estimate_rs_pose(f.points_px, f.X, cam, "p3p", OPTS, gyro=gyro)
    assert p.implementation == "compiled" and p.ignored_inputs == ("gyro",)
    assert not p.gyro_used


_NO_COMPILE = """
import json, sys, time
t0 = time.perf_counter()
import numpy as np
from rs_localizer.runtime.jit_cache import compile_progress
from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.sim.synthetic import make_frame, paper_camera
cam = paper_camera()
out = []
with compile_progress() as prog:
    for k in range(3):
        f = make_frame(k, 200, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
        e = estimate_rs_pose(f.points_px, f.X, cam, implementation="numpy")
        out.append(bool(e.success) and e.implementation == "numpy")
used = sorted(
    f"{m}.{k}"
    for m, mod in list(sys.modules.items())
    if m.startswith("rs_localizer")
    for k, v in list(vars(mod).items())
    if hasattr(v, "overloads") and hasattr(v, "py_func") and len(v.overloads)
)
print(json.dumps({"kernels": len(prog.kernels), "used": used, "solved": out,
                  "seconds": time.perf_counter() - t0}))
"""


def test_compiles_nothing(tmp_path):
    """In a fresh process with an empty numba cache (besides what the package's own
    ``__pycache__`` seeds into it, jit_cache.seed_cache), the NumPy implementation solves frames
    and numba compiles no kernel (numba's compile events, jit_cache.compile_progress) nor
    loads one (no numba dispatcher of the package has a compiled version)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(ROOT)}
    r = subprocess.run(
        [sys.executable, "-c", _NO_COMPILE],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert res["solved"] == [True, True, True]
    assert res["kernels"] == 0
    assert res["used"] == []  # (no kernel compiled or loaded from the cache)


def test_background_compile_failure_counted(monkeypatch):
    """A background compile that crashes leaves the frames on the NumPy implementation,
    counted once with its reason."""
    import rs_localizer.runtime.warmup as W

    crash = [sys.executable, "-c", "import sys; print('boom'); sys.exit(3)"]
    monkeypatch.setattr(B, "_background_command", lambda: (crash, None))
    monkeypatch.setattr(W, "fused_cached", lambda *a, **k: False)
    before = B.background_state()["failures"]
    logs, warns = [], []
    try:
        assert B.start_background_compile("r6p_1lin", log=logs.append, warn=warns.append)
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
        assert B.start_background_compile("r6p_1lin", log=logs.append, warn=logs.append)
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
from rs_localizer.ros import params as P
from rs_localizer.ros.bags.bag_io import RosbagsMessages
from rs_localizer.ros.pipeline import FramePipeline, log_warm_up
from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

frames, _, cam, _ = generate_sequence(SequenceConfig(num_frames=3, num_points=200, seed=4))
cfg = P.build_config({**P.default_values(), "camera_info_wait": 0.0})
logs = []
log = type("L", (), {"info": lambda s, m: logs.append(m), "warning": lambda s, m: logs.append(m)})()
log_warm_up(cfg.solver, cfg.options, cfg.tracking, log, background=True)
msgs = RosbagsMessages()
pipe = FramePipeline(cfg)
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
        env={**os.environ, "PYTHONPATH": str(ROOT)},
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

    monkeypatch.setattr(B, "_background_command", lambda: ([sys.executable, "-c", "pass"], None))
    monkeypatch.setattr(W, "fused_cached", lambda *a, **k: False)
    warns = []
    try:
        B.start_background_compile("r6p_1lin", log=lambda m: None, warn=warns.append)
        deadline = time.monotonic() + 60
        while B.background_state()["state"] == "compiling" and time.monotonic() < deadline:
            time.sleep(0.05)
        st = B.background_state()
        assert st["state"] == "failed" and "not cached" in st["reason"]
        assert not compiled_ready() and len(warns) == 1
    finally:
        _release()


@pytest.mark.parametrize("scene", ["plane", "board"])
def test_planar_frames_as_accurate(scene):
    """On planar frames (a plane of points with 20 % outliers, a calibration board) both paths
    are maximum a posteriori with the motion prior; against the ground truth the NumPy
    path's median rotation, position and angular-velocity errors over five frames are within
    1.5x the compiled path's (plus 0.05 deg, 2 mm, 5 %)."""
    from rs_localizer.sim.planar import make_planar_frame

    errs = {"u": [], "c": []}
    for k in range(5):
        f = make_planar_frame(k, scene, outlier_ratio=0.2 if scene == "plane" else 0.0)
        u = estimate_numpy(f.points_px, f.X, f.camera)
        c = estimate_compiled(f.points_px, f.X, f.camera)
        for key, e in (("u", u), ("c", c)):
            assert e.success and e.motion_prior_used
            om = np.linalg.norm(f.angular_velocity)
            errs[key].append(
                (
                    rotation_angle_deg(e.R, f.R),
                    np.linalg.norm(e.position - f.position),
                    np.linalg.norm(e.angular_velocity - f.angular_velocity) / om,
                )
            )
        assert u.num_inliers == c.num_inliers
    med_u, med_c = np.median(errs["u"], axis=0), np.median(errs["c"], axis=0)
    assert np.all(med_u <= 1.5 * med_c + np.array([0.05, 0.002, 0.05])), (med_u, med_c)
