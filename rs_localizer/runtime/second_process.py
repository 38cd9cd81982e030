"""The second compiling process of a parallel warm-up (:func:`.warmup.warm_up` with ``jobs``
> 1, ``rs-localizer compile``): ``python -m rs_localizer.runtime.second_process MODE SOLVER...``
(``MODE``: ``track`` or ``alone``, ``+gyro`` appended for the gyro path), started by the
warm-up (:func:`.warmup.warm_up`) through :func:`.warmup.package_command`.

Its share of the first solver's cold RANSAC batch (:func:`.warmup.split_batch`), then
:func:`.warmup.warm_late` for it, after which it prints ``warmed up SOLVER:late`` (the first
process waits for that line before its tracker's frames, and loads their twist filter); then
the warm-up of each further solver (e.g. ``p3p`` next to the node's solver), after which it
prints ``warmed up SOLVER`` (the first process, done with the first solver, waits for that
line and loads those kernels instead of compiling them a second time); then, with ``track``,
once the first process has cached the first solver's cold RANSAC batch, the tracker over the
warm-up's videos (planar first), which loads or compiles the kernels of tracked and planar
frames. Progress lines on stdout (:func:`~.jit_cache.compile_progress`).
"""

from __future__ import annotations

import sys
import time

from ..tracking.tracker import TrackerOptions
from .jit_cache import compile_progress
from .warmup import fused_cached, split_batch, track_videos, warm_late, warm_up

__all__ = ["main"]


def main(argv: list[str]) -> None:
    """Compile the second process's share for ``argv`` (the mode, then the solvers; module
    docstring)."""
    mode, solvers = argv[0], argv[1:]
    tracking = TrackerOptions() if mode.startswith("track") else None
    gyro = mode.endswith("+gyro")
    if not solvers:
        return
    first = solvers[0]
    with compile_progress(lambda m: print(m, flush=True)):
        split_batch(first, first=False)
        warm_late(first, tracking=tracking)
        print(f"warmed up {first}:late", flush=True)  # (the first process waits for this line)
        for s in solvers[1:]:
            warm_up(s, tracking=tracking, gyro=gyro)
            print(f"warmed up {s}", flush=True)  # (the first process waits for this line)
        if tracking is None:
            return
        while not fused_cached(first, anchored=False):  # (the first process stops us)
            time.sleep(0.2)
        track_videos(first, None, tracking, planar_first=True, gyro=gyro)


if __name__ == "__main__":
    main(sys.argv[1:])
