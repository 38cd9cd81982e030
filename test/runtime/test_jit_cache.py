"""numba cache placement (rs_localizer.runtime.jit_cache) and the JIT warm-up.

The seeding is tested against numba itself: a kernel compiled into a package's __pycache__
must then load from a NUMBA_CACHE_DIR seeded from it without compiling (numba's own
``cache_hits``/``cache_misses`` counters, in fresh processes), and a fresh cache directory that
was not seeded must compile (the control). The warm-up must leave nothing for a real frame to
compile (no new kernel signature afterwards)."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rs_localizer.runtime import jit_cache

KERNEL = textwrap.dedent("""
    from rs_localizer._jit import kernel
    from rs_localizer._so3 import FMA

    @kernel(fastmath=FMA)
    def plus_one(x):
        return x + 1
""")

PROBE = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, sys.argv[1])
    from rs_localizer.runtime.jit_cache import compile_progress, seed_cache
    if len(sys.argv) > 2:
        seed_cache(sys.argv[1] + "/tinypkg", sys.argv[2])
    with compile_progress() as prog:
        import tinypkg.mod as m
        assert m.plus_one(41) == 42
    print(json.dumps({"hits": sum(m.plus_one.stats.cache_hits.values()),
                      "misses": sum(m.plus_one.stats.cache_misses.values()),
                      "nogil": m.plus_one.targetoptions.get("nogil"),
                      "compiled": [k for k, _ in prog.kernels]}))
""")


def _run(tmp, env_extra, *args):
    import json

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(env_extra)
    out = subprocess.run(
        [sys.executable, "-c", PROBE, str(tmp), *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.fixture
def tiny_package(tmp_path):
    pkg = tmp_path / "tinypkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "mod.py").write_text(KERNEL)
    return tmp_path


def test_seeded_user_cache_loads_the_package_kernels(tiny_package, tmp_path):
    tmp = tiny_package
    first = _run(tmp, {})  # writable package: numba compiles into tinypkg/__pycache__
    assert first["misses"] == 1 and first["compiled"] == ["tinypkg.mod.plus_one"], first
    assert first["nogil"] is True  # (the package's decorator: rs_localizer._jit.kernel)
    assert list((tmp / "tinypkg" / "__pycache__").glob("mod.plus_one-*.nbi"))
    # control: a fresh user cache directory compiles again
    ctrl = _run(tmp, {"NUMBA_CACHE_DIR": str(tmp_path / "fresh")})
    assert ctrl["misses"] == 1 and ctrl["hits"] == 0, ctrl
    # seeded from the package: loaded, nothing compiled
    user = tmp_path / "user"
    seeded = _run(tmp, {"NUMBA_CACHE_DIR": str(user)}, str(user))
    assert seeded == {"hits": 1, "misses": 0, "nogil": True, "compiled": []}, seeded
    # seeding again copies nothing (the copies are not older than the package's files)
    assert jit_cache.seed_cache(str(tmp / "tinypkg"), str(user)) == 0


def test_configure_modes(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    for d in (pkg, pkg / "sub"):
        (d / "__init__.py").write_text("")
    env = {"XDG_CACHE_HOME": str(tmp_path / "xdg")}
    st = jit_cache.configure(env, package_dir=str(pkg))
    assert st["mode"] == "package" and "NUMBA_CACHE_DIR" not in env
    # a package whose __pycache__ cannot be created (a file in its way: unwritable even for
    # root, who ignores chmod)
    (pkg / "sub" / "__pycache__").rmdir()  # (made by the writability test above)
    (pkg / "sub" / "__pycache__").write_text("")
    assert not jit_cache.package_writable(str(pkg))
    (pkg / "__pycache__" / "k-1.py311.nbi").write_bytes(b"index")
    st = jit_cache.configure(env, package_dir=str(pkg))
    want = str(tmp_path / "xdg" / "rs_localizer" / "numba")
    assert st["mode"] == "user" and env["NUMBA_CACHE_DIR"] == want and st["seeded"] == 1
    assert (
        Path(want) / jit_cache._numba_subdir(str(pkg)) / "k-1.py311.nbi"
    ).read_bytes() == b"index"
    # an explicit NUMBA_CACHE_DIR wins
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "mine")}
    st = jit_cache.configure(env, package_dir=str(pkg))
    assert st["mode"] == "NUMBA_CACHE_DIR" and env["NUMBA_CACHE_DIR"] == str(tmp_path / "mine")
    assert jit_cache.user_cache_dir({}) == os.path.join(
        os.path.expanduser("~"), ".cache", "rs_localizer", "numba"
    )


def test_numba_subdir_is_numbas_name():
    from numba.core.caching import _CacheLocator

    f = os.path.join(jit_cache.PACKAGE_DIR, "solvers", "p3p.py")
    assert jit_cache._numba_subdir(os.path.dirname(f)) == _CacheLocator.get_suitable_cache_subpath(
        f
    )


def _signatures():
    """{kernel: set of signatures} of every numba dispatcher in the loaded rs_localizer
    modules (compiled or loaded from the cache)."""
    from numba.core.registry import CPUDispatcher

    out = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith("rs_localizer") or mod is None:
            continue
        for _attr, obj in vars(mod).items():
            if isinstance(obj, CPUDispatcher):
                out[f"{obj.py_func.__module__}.{obj.py_func.__qualname__}"] = set(
                    map(str, obj.signatures)
                )
    return out


@pytest.mark.parametrize("solver", ["r6p_1lin", "p3p"])
def test_warm_up_leaves_nothing_to_compile_for_real_frames(solver, sample_bag):
    """After warm_up(solver), real frames (the sample bag's clouds as the node reads them, with
    and without scores, float32 too) need no kernel signature the warm-up did not make."""
    pytest.importorskip("rosbags")
    from rs_localizer.estimation import EstimateOptions, estimate_rs_pose
    from rs_localizer.ros.bags import bag_io
    from rs_localizer.ros.conversions import camera_model_from_camera_info
    from rs_localizer.ros.pointcloud import read_correspondences
    from rs_localizer.runtime.warmup import warm_up

    _, est = warm_up(solver, EstimateOptions())
    assert est.success
    before = _signatures()
    ts = bag_io.typestore()
    info = cloud = None
    for topic, msgtype, _, raw in bag_io.iter_messages(
        sample_bag, {"/camera/correspondences", "/camera/camera_info"}
    ):
        msg = ts.deserialize_cdr(raw, msgtype)
        if topic.endswith("camera_info") and info is None:
            info = msg
        elif topic.endswith("correspondences") and cloud is None:
            cloud = msg
    cam = camera_model_from_camera_info(info, line_delay=30e-6)
    c = read_correspondences(cloud)
    scores = np.linspace(1, 0, len(c.uv))
    for uv, xyz, sc in (
        (c.uv, c.xyz, None),
        (c.uv, c.xyz, scores),
        (c.uv.astype(np.float32), c.xyz.astype(np.float32), None),
    ):
        assert estimate_rs_pose(uv, xyz, cam, solver=solver, scores=sc).success
    after = _signatures()
    new = {k: v - before.get(k, set()) for k, v in after.items() if v - before.get(k, set())}
    assert not new, f"kernels compiled after the warm-up: {new}"


def test_compile_command_reports_the_cache_and_kernels(capsys):
    """``rs-localizer compile``: where the kernels are and what was compiled or loaded."""
    from rs_localizer.cli import main

    assert main(["compile", "--solvers", "p3p"]) == 0
    out = capsys.readouterr().out
    state = jit_cache.cache_state()
    assert f"numba cache: {state['dir']} ({state['mode']}" in out
    assert "p3p: ready in" in out
    assert "all kernels loaded from the cache" in out or "compiled " in out
