"""The one decorator of the package's numba kernels, :func:`kernel`, and the options every
kernel shares.

- ``cache=True``: the machine code is kept on disk (where: :mod:`rs_localizer.runtime.jit_cache`),
  so that a process loads it instead of compiling it again.
- ``nogil=True``: a kernel called from Python releases the GIL while it runs. The kernels
  compile in nopython mode and take and return NumPy arrays, numbers and tuples only (no
  Python object, no callback into Python), so nothing inside needs the GIL; meanwhile the
  node's executor thread keeps taking frame messages while its worker thread is inside a
  kernel (``test/runtime/test_kernels_release_the_gil.py``).
"""

from __future__ import annotations

from numba import njit

__all__ = ["kernel"]


def kernel(fn=None, /, **options):
    """numba's ``njit`` with ``cache=True, nogil=True`` and ``options`` (``inline``,
    ``fastmath``, ``parallel``): ``@kernel`` or ``@kernel(fastmath=FMA)``; ``kernel(fn)``
    compiles an existing function."""
    decorate = njit(cache=True, nogil=True, **options)
    return decorate if fn is None else decorate(fn)
