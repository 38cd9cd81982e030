"""The background compiling process of a node's start on a cold cache
(:func:`.background.start_background_compile`): ``python -m
rs_localizer.runtime.background_process``, the pickled ``(kernels, nice)`` on stdin.

It warms ``kernels`` up (a camera's :class:`.background.CameraKernels`:
:func:`.warmup.warm_up`; a rig's :class:`.background.RigKernels`: :func:`.warmup.warm_rig`;
one process: the node's process keeps the other cores) at niceness ``nice``, so that numba
compiles and caches every kernel the node's frames need, one such process at a time per numba
cache (:func:`compile_lock`); progress lines on stdout. Exit code 0 when done.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import sys
from collections.abc import Iterator

from .jit_cache import cache_state, compile_progress

__all__ = ["compile_lock", "main"]


@contextlib.contextmanager
def compile_lock() -> Iterator[None]:
    """One background compile at a time per numba cache (several nodes starting at once on
    a cold cache: the first compiles, the others then load most kernels from the cache): an
    exclusive ``flock`` on a file in the temporary directory named after the cache. Without
    ``fcntl`` (not POSIX) no lock."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    import hashlib
    import tempfile

    key = hashlib.sha1(str(cache_state()["dir"]).encode()).hexdigest()[:16]
    path = os.path.join(tempfile.gettempdir(), f"rs_localizer_compile_{key}.lock")
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def main() -> None:
    """Compile what the pickled arguments on stdin name (module docstring)."""
    kernels, nice = pickle.loads(sys.stdin.buffer.read())
    if nice and hasattr(os, "nice"):  # (the frames of the node's process come first)
        os.nice(nice)
    with compile_lock(), compile_progress(lambda m: print(m, flush=True)):
        kernels.warm()


if __name__ == "__main__":
    main()
