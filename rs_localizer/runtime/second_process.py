"""The second compiling process of a parallel warm-up (:func:`.warmup.warm_up` with ``jobs``
> 1, ``rs-localizer compile``): ``python -m rs_localizer.runtime.second_process MODE SOLVER...``
(``MODE``: ``track`` or ``alone``), started by the warm-up
(:func:`.warmup.warm_up`) through :func:`.warmup.package_command`.

Its share of each solver's cold RANSAC batch (:func:`.warmup.split_batch`), then
:func:`.warmup.warm_late` for each solver; then, with ``track``, once the first process has
cached a solver's cold RANSAC batch, the tracker over the warm-up's videos (planar first: the
first process does the 3D scenes first), which compiles the kernels of tracked and planar
frames while the first process compiles the rest of a cold frame's. Progress lines on stdout
(:func:`~.jit_cache.compile_progress`).
"""

from __future__ import annotations

import sys
import time

from ..tracking.tracker import TrackerOptions
from .jit_cache import compile_progress
from .warmup import fused_cached, split_batch, track_videos, warm_late

__all__ = ["main"]


def main(argv: list[str]) -> None:
    """Compile the second process's share for ``argv`` (``track`` or ``alone``, then the
    solvers; module docstring)."""
    tracking = TrackerOptions() if argv[0] == "track" else None
    with compile_progress(lambda m: print(m, flush=True)):
        for s in argv[1:]:
            split_batch(s, first=False)
        for s in argv[1:]:
            warm_late(s, tracking=tracking)
        if tracking is None:
            return
        for s in argv[1:]:
            while not fused_cached(s, anchored=False):  # (the first process stops us)
                time.sleep(0.2)
            track_videos(s, None, tracking, planar_first=True)


if __name__ == "__main__":
    main(sys.argv[1:])
