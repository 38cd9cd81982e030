"""The parameters' defaults where users read them, kept equal to :data:`.params.PARAMETERS`
(the one place a parameter is written): the default column of every one-parameter row of the
parameter tables in ``docs/node.md`` and ``README.md``, and the values of
``config/rs_localizer.yaml``.

``python -m rs_localizer.ros.param_docs`` lists what differs (exit code 1 if anything does);
``--write`` rewrites it in place (``make params``). A parameter missing from a page or the YAML
is reported, not added: its row and comment are prose. ``test/test_docs_sync.py`` runs the
check.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .params import PARAMETERS

__all__ = ["DOC_PAGES", "YAML_FILE", "check", "main", "render_default", "sync_table", "sync_yaml"]

#: pages whose ``| parameter | default | ... |`` tables show defaults (repository-relative)
DOC_PAGES = ("docs/node.md", "README.md")
#: the parameter file listing every parameter at its default (repository-relative)
YAML_FILE = "config/rs_localizer.yaml"

_ROW = re.compile(r"^\|\s*`([^`]+)`\s*\|\s*`([^`]*)`\s*\|")
_YAML_LINE = re.compile(r"^(\s*)([A-Za-z_][\w]*):(\s*)([^#\n]*?)(\s*#.*)?$")


def render_default(value: Any, yaml: bool = False) -> str:
    """``value`` as the docs (``yaml=False``: ``true``, ``""`` for an empty string) or a
    parameter file (``yaml=True``: doubles keep their decimal point) write it."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return value if value else '""'
    if isinstance(value, list):
        return "[" + ", ".join(render_default(v, yaml) for v in value) + "]"
    return repr(value)


def _same(text: str, default: Any) -> bool:
    """Whether the written ``text`` means ``default`` (numbers compared as numbers)."""
    import yaml

    try:
        value = yaml.safe_load(text) if text not in ("", '""') else ""
    except yaml.YAMLError:
        return False
    if isinstance(default, bool) or isinstance(value, bool):
        return value is default
    if isinstance(default, (int, float)):
        return isinstance(value, (int, float)) and float(value) == default
    if isinstance(default, list):
        return isinstance(value, list) and [float(v) for v in value] == default
    return value == default


def sync_table(text: str, parameters: Mapping[str, tuple] = PARAMETERS) -> tuple[str, list]:
    """``text`` (a Markdown page) with the default cell of every one-parameter table row
    (``| `name` | `default` | ... |``) of a parameter in ``parameters`` set to its default
    where it differs. Returns ``(new text, [(name, written, default), ...] changed)``."""
    out, changed = [], []
    for line in text.splitlines(keepends=True):
        m = _ROW.match(line)
        if m and m.group(1) in parameters:
            name, written = m.group(1), m.group(2)
            default = parameters[name][0]
            if not _same(written, default):
                changed.append((name, written, default))
                a, b = m.span(2)
                line = line[:a] + render_default(default) + line[b:]
        out.append(line)
    return "".join(out), changed


def sync_yaml(text: str, parameters: Mapping[str, tuple] = PARAMETERS) -> tuple[str, list, list]:
    """``text`` (a ROS 2 parameter file with one ``ros__parameters`` section, nested keys
    by indentation) with the value of every parameter in ``parameters`` set to its default
    where it differs. Returns ``(new text, changed, missing)``: ``changed`` as
    :func:`sync_table`, ``missing`` the parameters the file does not set."""
    out, changed, seen = [], [], set()
    stack: list[tuple[int, str]] = []  # (indent, key) of the open mappings
    inside = False
    for line in text.splitlines(keepends=True):
        m = _YAML_LINE.match(line.rstrip("\n"))
        if not m:
            out.append(line)
            continue
        indent, key, value = len(m.group(1)), m.group(2), m.group(4)
        while stack and stack[-1][0] >= indent:
            stack.pop()
        if key == "ros__parameters":
            inside, stack = True, []
            out.append(line)
            stack.append((indent, None))
            continue
        path = [k for _, k in stack if k is not None]
        name = ".".join([*path, key])
        if not value:
            stack.append((indent, key))
        elif inside and name in parameters:
            seen.add(name)
            default = parameters[name][0]
            if not _same(value, default):
                changed.append((name, value, default))
                a, b = m.span(4)
                line = line[:a] + render_default(default, yaml=True) + line[b:]
        out.append(line)
    missing = [p for p in parameters if p not in seen]
    return "".join(out), changed, missing


def check(root: str | Path, write: bool = False) -> list[str]:
    """Compare (``write``: and rewrite) the defaults of :data:`DOC_PAGES` and
    :data:`YAML_FILE` under the repository ``root`` with :data:`.params.PARAMETERS`. Returns
    one line per difference or missing parameter (empty: all in step).

    Raises:
        OSError: a file cannot be read or written.
    """
    root = Path(root)
    problems = []
    for page in DOC_PAGES:
        text = (root / page).read_text()
        new, changed = sync_table(text)
        problems += [f"{page}: {n} shows {w!r}, default {d!r}" for n, w, d in changed]
        if write and new != text:
            (root / page).write_text(new)
    text = (root / YAML_FILE).read_text()
    new, changed, missing = sync_yaml(text)
    problems += [f"{YAML_FILE}: {n}: {w!r}, default {d!r}" for n, w, d in changed]
    problems += [f"{YAML_FILE}: {n} missing" for n in missing]
    if write and new != text:
        (root / YAML_FILE).write_text(new)
    return problems


def main(argv: list[str] | None = None) -> int:
    """Command line: ``[--root DIR] [--write]``; exit code 1 when something differs (after
    ``--write``: when something is still missing)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", default=".", help="repository root (default: .)")
    ap.add_argument("--write", action="store_true", help="rewrite the defaults that differ")
    args = ap.parse_args(argv)
    problems = check(args.root, args.write)
    for p in problems:
        print(p)
    if args.write:
        problems = check(args.root)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
