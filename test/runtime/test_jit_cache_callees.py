"""A cached kernel is compiled again when a kernel it calls changes in another file
(rs_localizer._jit.kernel stamps the callees' files into the cache index), and only then.

numba compiles a kernel's callees into its machine code but checks only the kernel's own
source file before loading it from the cache; without the callees' stamp a caller would keep
running the old callee after an update that changed only the callee's file. Each run is a fresh
process on one temporary NUMBA_CACHE_DIR; what it compiled is read from numba's own counters
(``stats.cache_hits`` / ``cache_misses``) and rs_localizer's ``compile_progress``."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

CALLEE = textwrap.dedent("""
    from rs_localizer._jit import kernel

    @kernel
    def offset():
        return {value}

    @kernel
    def shifted(x):
        return x + offset()
""")

CALLER = textwrap.dedent("""
    from rs_localizer._jit import kernel
    import callee_mod
    from callee_mod import shifted

    @kernel
    def _twice(x):
        return 2 * shifted(x)

    @kernel
    def caller(x):
        return _twice(x) + callee_mod.offset()
""")

PROBE = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, sys.argv[1])
    from rs_localizer.runtime.jit_cache import compile_progress
    with compile_progress() as prog:
        import caller_mod
        value = caller_mod.caller(1)
    s = caller_mod.caller.stats
    print(json.dumps({"value": value, "hits": sum(s.cache_hits.values()),
                      "misses": sum(s.cache_misses.values()),
                      "compiled": [k for k, _ in prog.kernels]}))
""")


def _run(src: Path, cache: Path) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    out = subprocess.run(
        [sys.executable, "-c", PROBE, str(src)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_changed_callee_file_recompiles_the_cached_caller(tmp_path):
    src, cache = tmp_path / "src", tmp_path / "numba"
    src.mkdir()
    (src / "callee_mod.py").write_text(CALLEE.format(value=10))
    (src / "caller_mod.py").write_text(CALLER)

    first = _run(src, cache)
    assert first["value"] == 2 * (1 + 10) + 10
    assert first["misses"] == 1 and first["compiled"] == ["caller_mod.caller"]

    # an update that changes only the callee's file (same size: numba's own stamp of the
    # caller's file is unchanged)
    (src / "callee_mod.py").write_text(CALLEE.format(value=20))
    second = _run(src, cache)
    assert second["value"] == 2 * (1 + 20) + 20, "the cached caller ran the old callee"
    assert second["misses"] == 1 and second["hits"] == 0

    third = _run(src, cache)  # nothing changed: loaded, nothing compiled
    assert third == {"value": 62, "hits": 1, "misses": 0, "compiled": []}


def test_an_unrelated_file_keeps_the_cache(tmp_path):
    src, cache = tmp_path / "src", tmp_path / "numba"
    src.mkdir()
    (src / "callee_mod.py").write_text(CALLEE.format(value=10))
    (src / "caller_mod.py").write_text(CALLER)
    (src / "other_mod.py").write_text("VALUE = 1\n")
    assert _run(src, cache)["misses"] == 1
    (src / "other_mod.py").write_text("VALUE = 2\n")
    again = _run(src, cache)
    assert again["value"] == 32 and again["hits"] == 1 and again["compiled"] == []


REAL = textwrap.dedent("""
    import json
    from rs_localizer.runtime.jit_cache import compile_progress
    from rs_localizer.solvers.kernels import _KERNELS, compile_kernel_set, kernel_set
    from rs_localizer._jit import callee_files
    with compile_progress() as prog:
        compile_kernel_set(kernel_set((0,)))
    k = _KERNELS[0]
    print(json.dumps({"hits": sum(k.stats.cache_hits.values()),
                      "compiled": [n for n, _ in prog.kernels],
                      "files": sorted(callee_files(k.py_func))}))
""")


def test_the_package_kernels_load_warm_in_a_second_process(tmp_path):
    """The R6P kernel (its callees in solvers/_linear.py and _linalg.py): compiled once, then
    loaded by the next process, nothing compiled."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONPATH=str(ROOT))
    runs = [
        json.loads(
            subprocess.run(
                [sys.executable, "-c", REAL],
                env=env,
                capture_output=True,
                text=True,
                timeout=600,
                check=True,
            ).stdout.splitlines()[-1]
        )
        for _ in range(2)
    ]
    assert runs[0]["compiled"] and runs[0]["hits"] == 0
    assert "rs_localizer.solvers._linear:_linear.py" in runs[0]["files"]
    assert runs[1]["compiled"] == [] and runs[1]["hits"] == 1
