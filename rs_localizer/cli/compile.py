"""``rs-localizer compile``: compile the JIT kernels once after installing."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence

from ..solvers.registry import SOLVER_NAMES
from . import args as A

__all__ = ["COMPARISON_SOLVER", "compile_targets", "register", "run"]

HELP = "compile the JIT kernels now (once after installing: the node then starts in seconds)"

#: the global-shutter solver `make demo` (``rs-localizer demo``) runs next to the node's for
#: comparison: compiled by default with the node's
COMPARISON_SOLVER = "p3p"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``compile`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    c = sub.add_parser(
        "compile",
        help=HELP,
        description="Compile the JIT (numba) kernels the node needs now and cache them, once "
        "after installing while the package directory is writable: the node then starts in "
        "seconds instead of compiling on its first frames. What is compiled follows the "
        "node's parameters: its solver, the video tracker (tracking.enabled), the gyro "
        "path (imu.enabled) and, with rig.cameras set, the rig's estimator, tracking and "
        "gyro over a synthetic rig of its cameras. By default the node's defaults "
        "(config/rs_localizer.yaml) and "
        f"{COMPARISON_SOLVER}, the solver `make demo` compares with; with --params-file "
        "what the node started with those files needs.",
        formatter_class=A.HelpFormatter,
    )
    c.add_argument(
        "--params-file",
        action="append",
        default=[],
        metavar="FILE",
        help="the node's ROS 2 parameter file, e.g. your robot's (repeatable; later ones "
        "win): compile for its solver, tracking, imu and rig settings (default: the node's "
        f"defaults plus {COMPARISON_SOLVER})",
    )
    c.add_argument(
        "--solvers",
        nargs="+",
        default=None,
        choices=SOLVER_NAMES,
        help="solvers to compile for instead (default: the configured node's solver; "
        f"without --params-file also {COMPARISON_SOLVER}, the demo's global-shutter "
        "baseline)",
    )
    c.add_argument(
        "--jobs",
        type=A.positive_int,
        default=None,
        help="processes compiling at once (default: 2 on a machine with two cores or more, else 1)",
    )
    c.set_defaults(func=run)
    return c


def compile_targets(
    params_files: Sequence[str | os.PathLike] = (), solvers: Sequence[str] | None = None
) -> dict:
    """What the node started with ``params_files`` (none: its defaults) runs on a frame:
    ``{"solvers": [...], "options": EstimateOptions, "tracking": TrackerOptions or None,
    "gyro": bool}``; the solvers are ``solvers`` if given, else the node's solver (plus
    :data:`COMPARISON_SOLVER` without ``params_files``).

    Raises:
        CliError: a parameter file that cannot be read or holds an invalid value.
    """
    from ..ros.config import estimate_options, tracker_options
    from ..ros.param_files import parameter_values
    from ..ros.params import ConfigError

    try:
        values, _ = parameter_values(params_files)
        options, tracking = estimate_options(values), tracker_options(values)
    except (ConfigError, OSError, TypeError, ValueError) as e:
        raise A.CliError(f"--params-file: {e}") from None
    if values["solver"] not in SOLVER_NAMES:
        raise A.CliError(
            f"--params-file: unknown solver {values['solver']!r}; expected one of "
            f"{list(SOLVER_NAMES)}"
        )
    if solvers is None:
        solvers = [values["solver"]]
        if not params_files and COMPARISON_SOLVER not in solvers:
            solvers.append(COMPARISON_SOLVER)
    return {
        "solvers": list(solvers),
        "options": options,
        "tracking": tracking,
        "gyro": bool(values["imu.enabled"]),
        "rig": _rig_target(params_files),
    }


def _rig_target(params_files: Sequence[str | os.PathLike]) -> tuple | None:
    """``(LocalizerSettings, {camera: (line_delay, readout_time, direction)})`` of the rig mode the
    parameter files configure (``rig.cameras`` set), else None. Raises CliError on a rig
    configuration the node would refuse."""
    if not params_files:
        return None
    from ..ros.bags.bag_frames import rig_parameter_values
    from ..ros.config import build_config
    from ..ros.params import ConfigError

    try:
        values, cams = rig_parameter_values(None, params_files)
        if not values["rig.cameras"]:
            return None
        cfg = build_config(values, cams)
    except (ConfigError, OSError, TypeError, ValueError) as e:
        raise A.CliError(f"--params-file: {e}") from None
    return cfg.settings, cfg.timings


def run(args: argparse.Namespace) -> int:
    """Compile (or load from the cache) the kernels; returns 0. Raises CliError for a
    parameter file that cannot be used."""
    A.parameter_files(args.params_file)
    what = compile_targets(args.params_file, args.solvers)
    from ..runtime.jit_cache import cache_state
    from ..runtime.warmup import DEFAULT_JOBS, compile_kernels

    st = cache_state()
    print(
        f"numba cache: {st['dir']} ({st['mode']}"
        + (f", {st['seeded']} files copied from the package" if st["seeded"] else "")
        + ")",
        flush=True,
    )
    print(
        f"compiling for {', '.join(what['solvers'])}"
        + (", with the video tracker" if what["tracking"] is not None else ", frames alone")
        + (", with the gyro" if what["gyro"] else "")
        + (f", the rig of {len(what['rig'][0].mounts)} cameras" if what["rig"] is not None else ""),
        flush=True,
    )
    jobs = args.jobs or DEFAULT_JOBS
    res = compile_kernels(
        what["solvers"],
        log=lambda m: print(m, flush=True),
        tracking=what["tracking"],
        jobs=jobs,
        options=what["options"],
        gyro=what["gyro"],
        rig=what["rig"],
    )
    n = len(res["kernels"])
    print(
        f"{', '.join(res['solvers'])}: ready in {res['seconds']:.1f} s ("
        + (
            f"compiled {n} kernels, {sum(d for _, d in res['kernels']):.1f} s of compiling"
            + (f" in {jobs} processes" if jobs > 1 else "")
            if n
            else "all kernels loaded from the cache"
        )
        + ")"
    )
    return 0
