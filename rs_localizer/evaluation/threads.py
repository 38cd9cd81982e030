"""One thread for benchmarks: speed claims are measured on one BLAS and one numba thread."""

from __future__ import annotations

import contextlib

__all__ = ["one_thread"]


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
