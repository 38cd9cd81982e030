"""Timing of the experiments and the benchmarks: speed claims are measured on one BLAS and one
numba thread (:func:`one_thread`); :func:`bench_solvers` times every solver (the paper's
Table 1, Exp. 6 of :mod:`rs_localizer.experiments`, and ``python -m benchmarks.bench
solvers``)."""

from __future__ import annotations

import contextlib
import time

import numpy as np

from ..sim.synthetic import make_frame

__all__ = ["bench_solvers", "one_thread"]


@contextlib.contextmanager
def one_thread():
    """Context in which BLAS (through threadpoolctl, when installed) and numba's parallel
    kernels use one thread; both are restored on exit.

    (Environment variables such as ``OMP_NUM_THREADS`` would come too late here: importing
    ``rs_localizer`` already loads NumPy and numba.)"""
    import numba

    with contextlib.ExitStack() as stack:
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:  # pragma: no cover - the bench extra is not installed
            pass
        else:
            stack.enter_context(threadpool_limits(limits=1))
        before = numba.get_num_threads()
        numba.set_num_threads(1)
        stack.callback(numba.set_num_threads, before)
        yield


def _median_us(fn, repeat: int) -> float:
    """Median CPU time of the calling thread per call (``time.thread_time``: the same as the
    wall-clock time on an idle machine, but not inflated by other processes on a shared one;
    the code timed is single-threaded), microseconds."""
    fn()  # warm-up (numba compilation, caches)
    ts = []
    for _ in range(repeat):
        t0 = time.thread_time()
        fn()
        ts.append(time.thread_time() - t0)
    return float(np.median(ts) * 1e6)


def bench_solvers(repeat: int = 200, batch: int = 1000, seed: int = 0) -> list[dict]:
    """Time every solver. Returns rows with ``us_call``, ``us_per_iteration`` (iterative
    solvers: the slope between 1 and 5 forced iterations), ``us_batched`` (per hypothesis, K =
    ``batch``) and ``us_batched_per_iteration``."""
    from .. import solvers as S

    rng = np.random.default_rng(seed)
    frames = [make_frame(rng, 9, rs_speed=0.5, angle_from_identity=0.0) for _ in range(batch)]
    x9 = np.array([f.x for f in frames])
    X9 = np.array([f.X for f in frames])
    x6, X6 = x9[:, :6].copy(), X9[:, :6].copy()
    f0 = frames[0]
    rows = []
    rows.append(
        dict(
            solver="p3p",
            us_call=_median_us(lambda: S.p3p(f0.x[:3], f0.X[:3]), repeat),
            note="Lambda Twist",
        )
    )
    rows.append(
        dict(
            solver="p3p (OpenCV)",
            us_call=_median_us(lambda: S.p3p_opencv(f0.x[:3], f0.X[:3]), repeat),
        )
    )
    rows.append(dict(solver="r6p", us_call=_median_us(lambda: S.r6p(f0.x[:6], f0.X[:6]), repeat)))
    # (every iterative solver of the registry with one batched kernel: the joined solver,
    # two kernels, is timed whole below)
    iterative = {
        k: (v.single, v.batch[0]) for k, v in S.SOLVERS.items() if v.iterative and len(v.batch) == 1
    }
    x, X = f0.x[:6], f0.X[:6]
    for name, (single, batched) in iterative.items():
        t1 = _median_us(lambda f=single: f(x, X, iterations=1), repeat)
        t5 = _median_us(lambda f=single: f(x, X, iterations=5, tol=-1.0), repeat)
        b1 = _median_us(lambda f=batched: f(x6, X6, iterations=1), 20) / batch
        b5 = _median_us(lambda f=batched: f(x6, X6, iterations=5, tol=-1.0), 20) / batch
        rows.append(
            dict(
                solver=name,
                us_call=t5,
                us_per_iteration=(t5 - t1) / 4,
                us_batched=b5,
                us_batched_per_iteration=(b5 - b1) / 4,
                us_batched_1_iteration=b1,
            )
        )
    rows.append(
        dict(
            solver="r9p",
            us_call=_median_us(lambda: S.r9p(f0.x, f0.X), repeat),
            us_batched=_median_us(lambda: S.r9p_batch(x9, X9), 20) / batch,
        )
    )
    rows.append(
        dict(
            solver="r6p_joined",
            us_call=_median_us(lambda: S.r6p_joined(f0.x[:6], f0.X[:6]), repeat),
        )
    )
    return rows
