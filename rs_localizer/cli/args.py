"""The command line's input checks, shared by every subcommand.

Numbers are checked by argparse ``type=`` functions (finite, in range) while the command line is
parsed; paths by the ``check_*`` functions, which a command calls before any heavy step. Both
raise :class:`CliError` (or argparse's own error) with one line naming the value or path and what
was expected; :func:`rs_localizer.cli.main` prints it as ``rs-localizer CMD: error: ...`` and
exits 2, so a mistake never costs minutes of work nor shows a traceback.
"""

from __future__ import annotations

import argparse
import math
import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

if TYPE_CHECKING:  # (for the annotations only: the camera model is loaded on demand)
    from ..camera import CameraModel

__all__ = [
    "BAG_FILE_SUFFIXES",
    "CliError",
    "HelpFormatter",
    "Parser",
    "bag_dir",
    "camera_file",
    "finite_float",
    "input_dir",
    "input_file",
    "map_input",
    "marker_map_file",
    "marker_sizes",
    "node_default",
    "node_parameter_options",
    "nonneg_float",
    "nonneg_int",
    "output_dir",
    "output_file",
    "parameter_files",
    "parse_marker_sizes",
    "plain",
    "positive_float",
    "positive_int",
    "probability",
    "solver_help",
    "writable_dir",
    "yaml_file",
]

#: storage files of a ROS 2 bag directory (mcap, sqlite3)
BAG_FILE_SUFFIXES = (".mcap", ".db3")


class CliError(ValueError):
    """A mistake in the command line (a value, a path): the message names it and says what was
    expected; the CLI prints it on one line and exits 2."""


# ------------------------------------------------------------------------------ help text
_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")  # :func:`x.y` -> x.y


def plain(text: str) -> str:
    """Help text without reStructuredText markup (roles and double back-quotes)."""
    return _ROLE.sub(r"\1", text).replace("``", "")


_NODE_DEFAULT = re.compile(r"<node default of ([\w.]+)>")


def node_default(param: str) -> str:
    """A placeholder for the node parameter's default in a help text, filled in by
    :class:`HelpFormatter` when the help is shown (the parameter table is not imported while
    a command line is parsed)."""
    return f"<node default of {param}>"


def _fill_node_defaults(text: str) -> str:
    if "<node default of " not in text:
        return text
    from ..ros.params import PARAMETERS

    return _NODE_DEFAULT.sub(lambda m: str(PARAMETERS[m.group(1)][0]), text)


class HelpFormatter(argparse.HelpFormatter):
    """Shows an option's default once: appended as ``(default: X)`` unless the help already
    says ``default`` or there is no default to show (None, False, suppressed); help and
    descriptions lose their reST markup; node parameters' defaults are filled in; description
    paragraphs are wrapped to the terminal (indented lines kept as written)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = _fill_node_defaults(action.help or "").replace("%", "%%")
        if (
            "default" not in text
            and action.default not in (None, False, argparse.SUPPRESS)
            and (action.option_strings or action.nargs in ("?", "*"))
            and not isinstance(action, argparse._StoreTrueAction)
        ):
            text += " (default: %(default)s)"
        return text

    def _format_text(self, text: str) -> str:
        return super()._format_text(plain(text))

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        # paragraphs (blank-line separated) are wrapped; indented lines are kept as written
        out = []
        for para in text.split("\n\n"):
            if any(line.startswith(" ") for line in para.splitlines()):
                out.append("\n".join(indent + line for line in para.splitlines()))
            else:
                out.append(super()._fill_text(para, width, indent))
        return "\n\n".join(out)

    def _expand_help(self, action: argparse.Action) -> str:
        return plain(super()._expand_help(action))


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, ``PROG: error: MESSAGE`` (exit 2), without
    the usage block: ``PROG -h`` shows it."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} -h)\n")


# ------------------------------------------------------------------------------ numbers
def _number(kind, text: str, name: str) -> float:
    try:
        v = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {name}, got {text!r}") from None
    if isinstance(v, float) and not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected {name}, got {text!r}")
    return v


def finite_float(text: str) -> float:
    """A finite number (not nan or inf)."""
    return _number(float, text, "a finite number")


def positive_float(text: str) -> float:
    """A finite number > 0."""
    v = _number(float, text, "a finite number > 0")
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v


def nonneg_float(text: str) -> float:
    """A finite number >= 0."""
    v = _number(float, text, "a finite number >= 0")
    if not v >= 0:
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return v


def probability(text: str) -> float:
    """A number in [0, 1]."""
    v = _number(float, text, "a number in [0, 1]")
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return v


def positive_int(text: str) -> int:
    """An integer >= 1."""
    v = _number(int, text, "an integer >= 1")
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return v


def nonneg_int(text: str) -> int:
    """An integer >= 0."""
    v = _number(int, text, "an integer >= 0")
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v


# ------------------------------------------------------------------------------ marker sizes
#: the most ids one ``--marker-sizes`` range may span (the largest AprilTag family has 48714)
MAX_SIZE_RANGE = 100_000


def _size_entries(text: str, where: str) -> list:
    """``(key, size)`` pairs of ``--marker-sizes``: its text, or the entries of the YAML file it
    names (a mapping ``ID or FIRST-LAST: SIZE``, or lines of ``ID:SIZE``)."""
    path = Path(text.strip())
    if text.strip().lower().endswith((".yaml", ".yml", ".txt")) or (
        "," not in text and ":" not in text and text.strip() and path.is_file()
    ):
        import yaml

        if not path.is_file():
            raise ValueError(f"{where}: no such file {str(path)!r}")
        try:
            data = yaml.safe_load(path.read_text())
        except (yaml.YAMLError, UnicodeDecodeError):
            raise ValueError(f"{where}: {path} is not YAML") from None
        if isinstance(data, dict):
            return [(str(k), str(v)) for k, v in data.items()]
        if isinstance(data, str):  # ("ID:SIZE,..." or lines of it)
            text = data.replace("\n", ",")
        elif data is None:
            return []
        else:
            raise ValueError(f"{where}: {path}: expected 'ID: SIZE' or 'FIRST-LAST: SIZE' lines")
        where = f"{where} ({path})"
    out = []
    for part in filter(None, (q.strip() for q in text.replace("\n", ",").split(","))):
        key, sep, size = part.partition(":")
        if not sep:
            raise ValueError(f"{where}: expected ID:SIZE or FIRST-LAST:SIZE (m), got {part!r}")
        out.append((key.strip(), size.strip()))
    return out


def parse_marker_sizes(text: str, where: str = "--marker-sizes") -> dict[int, float]:
    """Marker sides by id: ``"12:0.30,14:0.1"``, id ranges ``"0-9:0.165,10-52:0.1"`` (both
    ends included), or a YAML file of them (``{0-9: 0.165, 12: 0.3}`` or lines ``ID:SIZE``).
    Returns {id: side (m)}.

    Raises:
        ValueError (one line naming ``where`` and the entry): a malformed entry, a range whose
        end is below its start, an id given twice (also through overlapping ranges), a size
        that is not a finite number > 0, a file that cannot be read.
    """
    out: dict[int, float] = {}
    for key, value in _size_entries(text or "", where):
        entry = f"{key}:{value}"
        first, dash, last = key.partition("-")
        try:
            lo, hi = int(first), int(last if dash else first)
            size = float(value)
        except ValueError:
            raise ValueError(
                f"{where}: expected ID:SIZE or FIRST-LAST:SIZE (m, > 0), got {entry!r}"
            ) from None
        if lo < 0 or hi < lo or hi - lo >= MAX_SIZE_RANGE:
            raise ValueError(
                f"{where}: bad id range {key!r} (FIRST-LAST, 0 <= FIRST <= LAST, at most "
                f"{MAX_SIZE_RANGE} ids)"
            )
        if not (math.isfinite(size) and size > 0):
            raise ValueError(f"{where}: expected a size (m) > 0, got {entry!r}")
        for mid in range(lo, hi + 1):
            if mid in out:
                raise ValueError(f"{where}: marker {mid} is given twice")
            out[mid] = size
    return out


def marker_sizes(text: str) -> dict[int, float]:
    """``--marker-sizes`` as an argparse type (:func:`parse_marker_sizes`)."""
    try:
        return parse_marker_sizes(text)
    except (ValueError, OSError) as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("--marker-sizes: ")) from None


# ------------------------------------------------------------------------------ paths
def _writable_parent(path: Path, what: str) -> None:
    """The nearest existing ancestor of ``path`` is a directory we may write into."""
    parent = path.parent if str(path.parent) else Path(".")
    anc = parent
    while not anc.exists():
        if anc == anc.parent:
            break
        anc = anc.parent
    if not anc.is_dir():
        raise CliError(f"{path}: cannot write the {what} ({anc} is a file, not a directory)")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise CliError(f"{path}: cannot write the {what} (directory {anc} is not writable)")


def output_file(path: str | Path, overwrite: bool = True, what: str = "output file") -> Path:
    """Check that the file ``path`` can be written before any work: not a directory, not an
    existing file without ``overwrite``, its directory (or the nearest existing ancestor)
    writable. Returns it as a Path. Raises CliError."""
    path = Path(path)
    if path.is_dir():
        raise CliError(f"{path}: is a directory (expected the name of the {what} to write)")
    if path.exists():
        if not overwrite:
            raise CliError(f"{path}: exists (use --overwrite to replace it)")
        if not os.access(path, os.W_OK):
            raise CliError(f"{path}: exists and is not writable")
    _writable_parent(path, what)
    return path


def output_dir(path: str | Path, overwrite: bool = True, what: str = "output directory") -> Path:
    """Check that the directory ``path`` can be created (or replaced with ``overwrite``) before
    any work. Raises CliError."""
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise CliError(f"{path}: is a file (expected the {what})")
        if not overwrite:
            raise CliError(f"{path}: exists (use --overwrite to replace it)")
    _writable_parent(path, what)
    return path


def writable_dir(path: str | Path, what: str = "directory") -> Path:
    """A directory that exists or can be created, and is writable. Raises CliError."""
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise CliError(f"{path}: is a file (expected the {what})")
        if not os.access(path, os.W_OK | os.X_OK):
            raise CliError(f"{path}: the {what} is not writable")
        return path
    _writable_parent(path, what)
    return path


def input_file(path: str | Path, what: str = "file") -> Path:
    """An existing, readable regular file. Raises CliError."""
    path = Path(path)
    if not path.exists():
        raise CliError(f"{path}: no such file (expected the {what})")
    if path.is_dir():
        raise CliError(f"{path}: is a directory (expected the {what})")
    if not os.access(path, os.R_OK):
        raise CliError(f"{path}: not readable (the {what})")
    return path


def input_dir(path: str | Path, what: str = "directory") -> Path:
    """An existing directory. Raises CliError."""
    path = Path(path)
    if not path.exists():
        raise CliError(f"{path}: no such directory (expected the {what})")
    if not path.is_dir():
        raise CliError(f"{path}: is a file (expected the {what})")
    return path


def yaml_file(path: str | Path, what: str = "YAML file") -> Any:
    """Load a YAML file now (missing, a directory, unreadable or not YAML: CliError); returns
    its content."""
    import yaml

    path = input_file(path, what)
    try:
        return yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CliError(f"{path}: not a valid {what} ({first})") from None


def _bag_error(path: Path, text: str) -> CliError:
    return CliError(
        f"{path}: {text} (expected a ROS 2 bag directory with metadata.yaml, or its "
        f"{'/'.join(BAG_FILE_SUFFIXES)} file)"
    )


def bag_dir(path: str | Path, require_messages: bool = False) -> Path:
    """Check a bag argument and return the bag directory to read.

    Accepts a bag directory (with ``metadata.yaml``) or one of its storage files
    (``BAG/BAG.mcap``: the directory is returned, so that its ``metadata.yaml`` and the
    ``sequence.json`` of make-bag and render-bag apply). The bag is opened (its metadata and
    the storage file's index) but no message is read. ``require_messages``: a bag without any
    message is refused.

    Raises:
        CliError: missing path, a directory that is no bag, a file that is no bag storage file,
            a corrupt ``metadata.yaml``, a truncated or unreadable storage file, an empty bag.
    """
    path = Path(path)
    if not path.exists():
        raise _bag_error(path, "no such bag")
    if path.is_file():
        if path.suffix not in BAG_FILE_SUFFIXES:
            raise _bag_error(path, "not a bag")
        if not (path.parent / "metadata.yaml").is_file():
            raise _bag_error(
                path, "a bag file outside a bag directory (no metadata.yaml beside it)"
            )
        path = path.parent
    elif not (path / "metadata.yaml").is_file():
        raise _bag_error(path, "not a bag directory (no metadata.yaml)")
    try:
        from rosbags.rosbag2 import Reader
    except ModuleNotFoundError:  # (the command then says what to install)
        return path
    try:
        with Reader(path) as r:
            count = r.message_count
    except Exception as e:  # rosbags' ReaderError and what its storage plugins raise
        reason = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise _bag_error(path, f"cannot read the bag: {reason}") from None
    if require_messages and count == 0:
        raise CliError(f"{path}: the bag has no messages")
    return path


def node_parameter_options(
    parser: argparse.ArgumentParser, files_help: str, param_help: str, default: Any = None
) -> None:
    """Add the node's parameters to a command's ``parser``: ``--params-file FILE`` (the node's
    ROS 2 parameter files) and ``-p``/``--param NAME:=VALUE`` (one parameter, its value in YAML
    as ``ros2 run ... -p``; :func:`param_overrides` reads them), both repeatable, with their
    help. Not given: ``default`` (None: an empty list; ``argparse.SUPPRESS``: no attribute)."""
    fresh = default is None
    parser.add_argument("--params-file", action="append", default=[] if fresh else default,
                        metavar="FILE", help=files_help)  # fmt: skip
    parser.add_argument("-p", "--param", action="append", default=[] if fresh else default,
                        metavar="NAME:=VALUE", help=param_help)  # fmt: skip


def parameter_files(paths: Iterable[str | Path]) -> None:
    """Load the node's parameter files (``--params-file``) now, before any work: one that is
    missing, a directory, unreadable, not YAML or not a mapping raises CliError naming it (the
    node's reading checks the rest)."""
    for f in paths:
        if not isinstance(yaml_file(f, "parameter file"), dict):
            raise CliError(f"{f}: not a ROS 2 parameter file (expected a YAML mapping)")


def param_overrides(items: Iterable[str] | None) -> dict:
    """``NAME:=VALUE`` (the value in YAML, as ``ros2 run ... -p``) -> {NAME: value}.

    Raises:
        CliError: an item without ``:=`` or a name, or a value that is not YAML.
    """
    import yaml

    out = {}
    for it in items or ():
        name, sep, text = it.partition(":=")
        if not sep or not name.strip():
            raise CliError(f"--param expects NAME:=VALUE, got {it!r}")
        try:
            out[name.strip()] = yaml.safe_load(text)
        except yaml.YAMLError:
            raise CliError(f"--param {name.strip()}: not a YAML value: {text!r}") from None
    return out


def solver_help(prefix: str) -> str:
    """Help text listing the solver registry's names with their paper names."""
    from ..solvers.registry import SOLVER_NAMES, solver_info

    def entry(n: str) -> str:
        info = solver_info(n)
        return f"{n} ({info.paper_name}{'' if info.rolling else ', global shutter'})"

    return prefix + ": " + ", ".join(entry(n) for n in SOLVER_NAMES)


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def camera_file(path: str | Path) -> CameraModel:
    """Load a camera YAML (ROS camera_info / calibration) now; returns the camera model.
    Raises CliError when it is missing or not a camera file."""
    from ..mapping.outputs import camera_from_yaml

    path = input_file(path, "camera YAML (ROS camera_info)")
    try:
        return camera_from_yaml(path)
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise CliError(f"{path}: not a camera YAML ({_first_line(e)})") from None


def map_input(path: str | Path, camera: str | Path | None) -> Path:
    """The input of a mapping command: a bag (directory or its storage file; returns the
    directory) or a folder of images, which needs a camera YAML (loaded now). Raises CliError."""
    path = Path(path)
    if (path / "metadata.yaml").exists() or (path.is_file() and path.suffix in BAG_FILE_SUFFIXES):
        return bag_dir(path, require_messages=True)
    if not path.exists():
        raise CliError(f"{path}: no such bag or folder of images")
    if not path.is_dir():
        raise CliError(f"{path}: not a bag or a folder of images")
    if camera is None:
        raise CliError(f"{path}: a folder of images needs --camera CAMERA.yaml (ROS camera_info)")
    camera_file(camera)
    return path


def marker_map_file(path: str | Path) -> None:
    """Load a marker map YAML (or a scene YAML / built-in scene name) now. Raises CliError when
    it is missing, a directory or not a marker map."""
    from ..maps import load_marker_map, scene_names

    if str(path) not in scene_names():
        yaml_file(path, "marker map YAML")
    try:
        load_marker_map(path)
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise CliError(f"{path}: not a marker map ({_first_line(e)})") from None
