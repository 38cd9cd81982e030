"""tools/architecture_report.py: its figures against independent counts, its circle finder on
graphs with and without a circle, and the package itself free of import circles."""

from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location(
        "architecture_report", ROOT / "tools" / "architecture_report.py"
    )
    mod = importlib.util.module_from_spec(spec)
    sys.modules["architecture_report"] = mod  # (its dataclasses look their module up)
    spec.loader.exec_module(mod)
    return mod


def test_circles_found_only_where_the_imports_loop():
    ar = _tool()
    assert ar.circles({"a": {"b"}, "b": {"c"}, "c": set(), "d": {"a"}}) == []
    loop = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e", "a"}}
    assert ar.circles(loop) == [["a", "b", "c"]]


def test_imports_resolve_relative_deferred_and_type_checking():
    ar = _tool()
    known = {
        "rs_localizer",
        "rs_localizer.ros",
        "rs_localizer.ros.x",
        "rs_localizer.solvers",
        "rs_localizer.solvers.registry",
        "rs_localizer.camera",
    }
    src = (
        "from typing import TYPE_CHECKING\n"
        "from ..solvers.registry import SOLVERS\n"
        "from .. import camera\n"
        "import numpy\n"
        "if TYPE_CHECKING:\n"
        "    from ..solvers import registry\n"
        "def f():\n"
        "    from ..camera import CameraModel\n"
    )
    tree = ast.parse(src)
    top = ar.imports("ros/x.py", tree, deferred=False, known=known)
    assert top == {"rs_localizer.solvers.registry", "rs_localizer.camera"}
    assert ar.imports("ros/x.py", tree, deferred=True, known=known) == top


def test_report_figures_against_independent_counts():
    ar = _tool()
    r = ar.report(top=5)
    assert r["not_found"] == [] and r["rig_only"]["missing"] == []
    pkg = ROOT / "rs_localizer"
    wc = {p: p.read_bytes().count(b"\n") for p in pkg.rglob("*.py")}
    assert r["total_lines"] == sum(wc.values())
    assert r["rig_only"]["lines"] == sum(wc[pkg / m] for m in ar.RIG_ONLY)
    assert r["packages"]["solvers"]["lines"] == sum(
        n for p, n in wc.items() if p.parent == pkg / "solvers"
    )
    lengths = [f["lines"] for f in r["longest_functions"]]
    assert len(lengths) == 5 and lengths == sorted(lengths, reverse=True)
    # the longest one read again from its own module
    mod, name = r["longest_functions"][0]["function"].split(":")
    tree = ast.parse((pkg / mod).read_text())
    node = next(
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.FunctionDef) and n.name == name.split(".")[-1]
    )
    assert node.end_lineno - node.lineno + 1 == lengths[0]
    # the package's own claim (docs/architecture.md): no import circle
    assert r["import_circles"] == {"module level": [], "with deferred": []}
    assert r["imports"]["module level"] > 300
