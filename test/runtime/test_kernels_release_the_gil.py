"""The compiled kernels release the GIL while they run (``rs_localizer._jit.kernel``:
``nogil=True``), so that another Python thread runs meanwhile: the node's executor thread
keeps taking frame messages while its worker thread is inside a kernel.

Measured against the clock, not the flag: a thread of pure Python stamps
``time.perf_counter()`` in a loop while another thread is inside one long kernel call
(R6P_{v,C,w,t}^{[v]x}'s batched kernel on many problems, as RANSAC calls it). A kernel that
holds the GIL stops the stamping thread for the whole call (its largest gap equals the call);
one that releases it leaves gaps of an OS time slice. Every kernel of the package is also
checked to be compiled with ``nogil`` and cached (that a kernel declared with the decorator
loads from the cache in the next process: ``test_jit_cache.py``)."""

import importlib
import threading
import time
from pathlib import Path

import numpy as np
from numba.core.registry import CPUDispatcher

PKG = Path(__file__).resolve().parents[2] / "rs_localizer"
#: R6P_{v,C,w,t}^{[v]x}'s batched kernel (K problems), as the fused RANSAC batch runs it
_kernel = importlib.import_module("rs_localizer.solvers.r6p_1lin")._kernel


def _problems(k: int):
    """``k`` problems of 12 random correspondences for the batched R6P_{v,C,w,t}^{[v]x}
    kernel (noise: each runs its iterations without converging), its arguments."""
    from rs_localizer.solvers.kernels import MAX_PARAMS

    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 0.3, (k, 12, 2))
    X = rng.normal(0.0, 1.0, (k, 12, 3)) + [0.0, 0.0, 5.0]
    r = x[:, :, 1].copy()
    out = (np.zeros((k, MAX_PARAMS)), np.zeros(k, bool), np.zeros(k, np.int64), np.zeros(k))
    return (x, X, r, 0.0, 30, -1.0, np.zeros((k, 3)), *out)


def _largest_gap_inside_a_kernel_call(k: int):
    """(seconds the kernel call on ``k`` problems took, the largest gap between two stamps
    of a pure-Python thread during it)."""
    args = _problems(k)
    stamps, span = [], []
    started, done = threading.Event(), threading.Event()

    def stamp():
        started.set()
        while not done.is_set():
            stamps.append(time.perf_counter())

    def solve():
        t0 = time.perf_counter()
        _kernel(*args)
        span.extend((t0, time.perf_counter()))
        done.set()

    b = threading.Thread(target=stamp)
    b.start()
    started.wait()
    a = threading.Thread(target=solve)
    a.start()
    a.join()
    b.join()
    t0, t1 = span
    inside = [t0] + [s for s in stamps if t0 < s < t1] + [t1]
    return t1 - t0, float(np.max(np.diff(inside)))


def test_another_python_thread_runs_while_a_kernel_runs():
    """A kernel call of 0.3 s or more leaves a thread of pure Python gaps below half of it
    (with the GIL held the gap is the whole call)."""
    _kernel(*_problems(4))  # (compiled, or loaded from numba's cache, before the clock)
    k = 200
    for _ in range(6):  # (scaled until one call takes 0.6 s or more on this machine, so
        # that the call measured next, on a busy machine a little shorter, is still 0.3 s)
        t = time.perf_counter()
        _kernel(*_problems(k))
        dt = time.perf_counter() - t
        if dt >= 0.6:
            break
        k = int(min(k * max(2.0, 0.6 / max(dt, 1e-4)), 400_000))
    duration, gap = _largest_gap_inside_a_kernel_call(k)
    assert duration >= 0.3, (k, duration)
    assert gap < 0.5 * duration, (k, duration, gap)


def _kernel_modules():
    """The package's modules that compile numba kernels (those that mention numba or the
    kernel decorator), imported (``ros``, ``cli`` and ``experiments`` compile none)."""
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG.parent).with_suffix("")
        if rel.parts[1] in ("ros", "cli", "experiments") or path.name == "_jit.py":
            continue
        text = path.read_text()
        if "numba" in text or "_jit import kernel" in text:
            yield importlib.import_module(".".join(rel.parts))


def test_every_kernel_of_the_package_releases_the_gil():
    kernels = {
        f"{m.__name__}.{name}": obj
        for m in _kernel_modules()
        for name, obj in vars(m).items()
        if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == m.__name__
    }
    assert len(kernels) > 150, len(kernels)
    held = sorted(n for n, k in kernels.items() if not k.targetoptions.get("nogil"))
    assert held == []
    uncached = sorted(n for n, k in kernels.items() if k._cache.__class__.__name__ == "NullCache")
    assert uncached == []
