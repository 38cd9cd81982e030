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
    # (a module imported only under TYPE_CHECKING counts with typing alone)
    only = ast.parse(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .. import camera\n"
    )
    assert ar.imports("ros/x.py", only, deferred=True, known=known) == set()
    assert ar.imports("ros/x.py", only, deferred=True, known=known, typing=True) == {
        "rs_localizer.camera"
    }


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
    assert r["import_circles"] == {
        "module level": [], "with deferred": [], "with TYPE_CHECKING": []
    }  # fmt: skip
    assert r["imports"]["module level"] > 300


#: a package of five modules: r.py the only rig-only one, c.py a camera's
SYNTHETIC = {
    "__init__.py": "",
    "shared/__init__.py": "from .a import Reexported\n",
    "shared/a.py": (
        "def dec(f):\n"  # 1
        "    return f\n"
        "@dec\n"  # 3: only_rig's first line
        "def only_rig():\n"
        "    return _inner()\n"
        "def _inner():\n"  # 6
        "    return _recursive(2)\n"
        "def _recursive(n):\n"  # 8
        "    return _recursive(n - 1) if n else 0\n"
        "def both():\n"  # 10
        "    return 2\n"
        "class Reexported:\n"  # 12
        "    pass\n"
        "def loop_a():\n"  # 14
        "    return loop_b()\n"
        "def loop_b():\n"  # 16
        "    return loop_a()\n"
        "def via_module():\n"  # 18
        "    return 3\n"
        "def unused():\n"  # 20
        "    return 4\n"
        "def level():\n"  # 22
        "    return 5\n"
        "LEVEL = level()\n"  # 24
        "def in_doc():\n"  # 25
        "    return 6\n"
        "def deep():\n"  # 27
        "    return 7\n"
        "def camera_too():\n"  # 29
        "    return 8\n"
    ),
    "b.py": (
        "from .shared.a import deep, camera_too\n"
        "def helper():\n"
        "    return deep()\n"
        "def helper2():\n"
        "    return camera_too()\n"
    ),
    "r.py": (
        "from .shared.a import only_rig, both, level, in_doc, via_module, camera_too\n"
        "from .shared import Reexported\n"
        "from .b import helper, helper2\n"
        "def run():\n"
        "    return only_rig(), both(), level(), in_doc(), via_module(), Reexported()\n"
        "X = helper(), helper2(), camera_too\n"
    ),
    "c.py": (
        '"""Never in_doc, nor camera_too."""\n'
        "from rs_localizer.shared.a import both\n"
        "from .shared import a\n"
        "from .b import helper2\n"
        '__all__ = ["in_doc", "only_rig"]\n'
        "def f():\n"
        "    return both(), a.via_module(), helper2()\n"
    ),
}


def test_rig_only_definitions_on_a_synthetic_package():
    ar = _tool()
    trees = {m: ast.parse(src) for m, src in SYNTHETIC.items()}
    found = {
        f"{d.module}:{d.name}": (d.line, d.lines) for d in ar.rig_only_definitions(trees, {"r.py"})
    }
    # only_rig with its decorator line; dec, _inner and _recursive used only through it (a
    # function's use of itself not a use); deep only through b.helper, used only by r.py;
    # in_doc named by c.py only in its docstring and __all__. Not: both, via_module (c.py's
    # a.via_module), Reexported (shared/__init__.py's re-export), level (used at a.py's
    # module level), loop_a/loop_b (a loop no rig-only module enters), unused, camera_too
    # (b.helper2's too, which c.py uses), run and helper2.
    assert found == {
        "shared/a.py:dec": (1, 2),
        "shared/a.py:only_rig": (3, 3),
        "shared/a.py:_inner": (6, 2),
        "shared/a.py:_recursive": (8, 2),
        "shared/a.py:in_doc": (25, 2),
        "shared/a.py:deep": (27, 2),
        "b.py:helper": (2, 2),
    }


def test_rig_only_code_in_shared_modules_of_the_package():
    ar = _tool()
    rig = ar.report(top=1)["rig_only"]
    shared = {d["definition"]: d for d in rig["shared_definitions"]}
    # StackedViews: estimation/view.py's, imported only by estimation/rig.py; View: a
    # camera's too (tracking/video.py, estimation/estimate.py)
    assert "estimation/view.py:StackedViews" in shared
    assert "estimation/view.py:View" not in shared
    tree = ast.parse((ROOT / "rs_localizer" / "estimation" / "view.py").read_text())
    node = next(n for n in tree.body if getattr(n, "name", None) == "StackedViews")
    first = min([node.lineno] + [d.lineno for d in node.decorator_list])
    assert shared["estimation/view.py:StackedViews"]["lines"] == node.end_lineno - first + 1
    assert rig["shared_lines"] == sum(d["lines"] for d in shared.values())
    assert rig["total_lines"] == rig["lines"] + rig["shared_lines"]
    assert not any(d.split(":")[0] in ar.RIG_ONLY for d in shared)
