"""The package's shape in figures, read from the source (nothing is imported or run): lines
per package, the lines only a rig of cameras uses, the estimators and the pose carriers (the
lists below, each entry with why it is one, checked against the code), the longest functions
and the import circles among the package's modules.

    .venv/bin/python tools/architecture_report.py [--json] [--top N]

Lines are physical lines (``wc -l``); "code" leaves out blank lines and comment lines.
Import circles are the strongly connected components of the graph of ``import`` statements
between the package's modules: module-level imports (what Python runs at import time; those
under ``if TYPE_CHECKING:`` left out), again with the imports inside functions too, and again
with those under ``TYPE_CHECKING`` too (a type named across modules ties them as an import
does).
``from .pkg import name`` is an edge to ``pkg/name.py`` when that module exists, else to
``pkg/__init__.py``.

The rig's lines are the modules of ``RIG_ONLY`` and, in the other (shared) modules, the
top-level functions and classes (their decorators included) that only those modules use
(:func:`rig_only_definitions`): a definition is used where its name is loaded (imported by
name, ``module.name`` through an imported module, or in its own module), a use counted for
the top-level definition it is in, or for its module outside any; an import whose name is
never loaded (a re-export) is a use by its module. Names in strings (``__all__``, registries,
``importlib``) are not uses; the tests and benchmarks are not read.

Exit status 1 when a listed estimator or pose carrier is not found where the list says (the
list is out of date).
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "rs_localizer"

#: the modules of what only a rig of several cameras needs (path under rs_localizer/ -> why),
#: counted whole: a single camera runs none of them but tracking/rig.py's grouping, through
#: which the localizer takes a camera's frames as a rig of one's
RIG_ONLY = {
    "estimation/rig.py": "estimate_rig_pose: one pose for a rig frame of several cameras",
    "estimation/rig_batch.py": "the rig's compiled RANSAC batch and scoring kernels",
    "tracking/rig.py": (
        "RigGrouping, CameraAgreement, refusal: the cameras' frames grouped into rig "
        "frames, their disagreement, the refusal of a rig frame one camera poses"
    ),
    "ros/rig_node.py": (
        "the node's rig-only parts (rig.cameras set): its cameras' parameters, the "
        "grouping of queued frames into rig frames"
    ),
    "calibration/mountings.py": "calibrate_mountings: the cameras' mountings on the rig",
    "calibration/corners.py": "RigCorners: a rig video's corners as one least-squares problem",
    "cli/calibrate_rig.py": "rs-localizer calibrate-rig",
    "solvers/gr6p_1lin.py": "gR6P: the linear RS solver for points seen by several cameras",
}

#: what computes a pose from observations: (module, name) -> why it is one
ESTIMATORS = {
    ("estimation/driver.py", "staged_estimate"): (
        "one view or many: a camera's frame (estimate_rs_pose) or a rig frame's"
        " (estimate_rig_pose), each its Stages"
    ),
    (
        "estimation/single_tag.py",
        "few_points_estimate",
    ): "too few points: one marker (IPPE) or a few (SQPnP)",
    ("tracking/tracker.py", "RSTracker"): "a camera's video: predicted RANSAC, relocalization",
    ("tracking/sequence.py", "SequenceLocalizer"): "a camera's video, the library entry point",
    ("tracking/video.py", "Localizer"): "a camera's or a rig's video (a camera: a rig of one)",
    ("tracking/fusion.py", "TwistFilter"): "the fixed-lag smoother of a camera's or rig's twist",
    ("calibration/mountings.py", "calibrate_mountings"): "mountings from a video: poses jointly",
    ("mapping/marker_map.py", "map_markers"): "marker maps: the camera's poses with the map",
}

#: the types that hold a pose (or the solvers' model of one): (module, class) -> why
POSE_CARRIERS = {
    ("pose.py", "RSModel"): "the solvers' (R, C, w, t), the kernels' model",
    ("pose.py", "RSPose"): "the domain pose: orientation, position, twist, stamp",
    ("pose.py", "PoseWithCovariance"): "an RSPose with its 6x6 covariances: what is published",
    ("estimation/result.py", "RSPoseEstimate"): (
        "a camera's or a rig's frame's estimate (a PoseWithCovariance)"
    ),
    ("tracking/localizer.py", "FusedPose"): "a frame with its fused twist (a PoseWithCovariance)",
    ("tracking/fusion.py", "FusedState"): "the twist filter's state of a frame (an RSPose)",
    ("estimation/options.py", "InitialModel"): "a model to start RANSAC from (an RSModel)",
    ("estimation/finalize.py", "FinalModel"): "the refined model before the last checks",
    ("solvers/_common.py", "RSSolution"): "one solver solution (v, C, w, t)",
    ("frames.py", "Mounting"): "a camera's pose on a body (a rig, base_link): its mounting",
    ("calibration/mountings.py", "MountingEstimate"): "a camera's mounting on the rig",
}


@dataclass(frozen=True)
class Function:
    module: str  # path under rs_localizer/
    name: str  # Class.method or function
    line: int
    lines: int


def modules() -> list[Path]:
    """The package's Python modules, sorted."""
    return sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts)


def _rel(p: Path) -> str:
    return p.relative_to(PKG).as_posix()


def package_of(rel: str) -> str:
    """``estimation/rig.py`` -> ``estimation``; a module at the package root -> ``(root)``."""
    return rel.split("/")[0] if "/" in rel else "(root)"


def line_counts(path: Path) -> tuple[int, int]:
    """(physical lines, code lines: neither blank nor a comment) of a file."""
    text = path.read_text(encoding="utf-8").splitlines()
    code = sum(1 for s in text if s.strip() and not s.lstrip().startswith("#"))
    return len(text), code


def functions(path: Path, tree: ast.AST | None = None) -> list[Function]:
    """Every function and method of a module with its length in lines (decorators left out;
    a nested function counted inside its parent and again on its own)."""
    tree = tree or ast.parse(path.read_text(encoding="utf-8"))
    out: list[Function] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                name = prefix + child.name
                out.append(
                    Function(_rel(path), name, child.lineno, child.end_lineno - child.lineno + 1)
                )
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")

    visit(tree, "")
    return out


def top_level_names(tree: ast.AST) -> set[str]:
    return {
        n.name
        for n in tree.body
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef)
    }


def _module_name(rel: str) -> str:
    parts = rel[: -len(".py")].split("/")
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(["rs_localizer", *parts])


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _known() -> set[str]:
    return {_module_name(_rel(p)) for p in modules()}


def _from_base(pkg: str, node: ast.ImportFrom) -> str:
    """The absolute module name ``from ... import`` statement ``node`` imports from, in the
    package ``pkg`` of the importing module (a relative import resolved)."""
    if not node.level:
        return node.module or ""
    base = pkg
    for _ in range(node.level - 1):
        base = base.rpartition(".")[0]
    return f"{base}.{node.module}" if node.module else base


def imports(
    rel: str, tree: ast.AST, deferred: bool, known: set[str] | None = None, typing: bool = False
) -> set[str]:
    """The package modules (names as in :func:`_module_name`) that module ``rel`` imports: at
    module level, with ``deferred`` also inside functions, with ``typing`` also under
    ``if TYPE_CHECKING:``. ``known``: the package's module names (default: read from the
    tree)."""
    me = _module_name(rel)
    pkg = me if rel.endswith("__init__.py") else me.rpartition(".")[0]
    known = _known() if known is None else known
    found: set[str] = set()

    def target(base: str, names: list[str]) -> None:
        for n in names:
            sub = f"{base}.{n}" if base else n
            if sub in known:
                found.add(sub)
            elif base in known:
                found.add(base)

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child) and not typing:
                for other in child.orelse:
                    visit(ast.Module(body=[other], type_ignores=[]), in_function)
                continue
            fn = isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
            if isinstance(child, ast.Import) and (deferred or not in_function):
                for a in child.names:
                    name = a.name
                    while name and name not in known:
                        name = name.rpartition(".")[0]
                    if name:
                        found.add(name)
            elif isinstance(child, ast.ImportFrom) and (deferred or not in_function):
                base = _from_base(pkg, child)
                if base.split(".")[0] == "rs_localizer":
                    target(base, [a.name for a in child.names])
            visit(child, in_function or fn)

    visit(tree, False)
    found.discard(me)
    return found


@dataclass(frozen=True)
class Definition:
    module: str  # path under rs_localizer/
    name: str  # a top-level function or class
    line: int  # its first line, decorators included
    lines: int


def _bindings(
    rel: str, tree: ast.AST, known: set[str]
) -> tuple[dict[str, tuple[str, str | None]], list[str]]:
    """The names module ``rel`` binds by importing from the package, anywhere in it (under
    TYPE_CHECKING and in functions too): local name -> (module name, imported name), the name
    None for a module itself; and the modules it star-imports."""
    me = _module_name(rel)
    pkg = me if rel.endswith("__init__.py") else me.rpartition(".")[0]
    bound: dict[str, tuple[str, str | None]] = {}
    star: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.asname and a.name in known:
                    bound[a.asname] = (a.name, None)
                elif not a.asname and a.name.split(".")[0] in known:
                    head = a.name.split(".")[0]
                    bound[head] = (head, None)
        elif isinstance(node, ast.ImportFrom):
            base = _from_base(pkg, node)
            for a in node.names:
                if a.name == "*":
                    if base in known:
                        star.append(base)
                elif f"{base}.{a.name}" in known:
                    bound[a.asname or a.name] = (f"{base}.{a.name}", None)
                elif base in known:
                    bound[a.asname or a.name] = (base, a.name)
    return bound, star


def rig_only_definitions(
    trees: dict[str, ast.AST], rig_only: Iterable[str], known: set[str] | None = None
) -> list[Definition]:
    """The top-level functions and classes of the modules not in ``rig_only`` that only the
    ``rig_only`` modules use: every use of one is in a ``rig_only`` module, in itself, or in
    another such definition, and at least one is in a ``rig_only`` module.

    ``trees``: every module of the package (path under rs_localizer/ -> its parsed source);
    ``known``: the package's module names (default: those of ``trees``). Uses are read as the
    module docstring says. Sorted by module, then line."""
    known = {_module_name(m) for m in trees} if known is None else known
    rel_of = {_module_name(m): m for m in trees}
    rig = set(rig_only)
    defs = {
        (m, n.name): n
        for m, t in trees.items()
        for n in t.body
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef)
    }
    bindings = {m: _bindings(m, t, known) for m, t in trees.items()}

    def resolve(module: str, name: str, seen: frozenset = frozenset()) -> tuple[str, str] | None:
        """The definition ``name`` of ``module`` is, following re-exports."""
        m = rel_of.get(module)
        if m is None or (m, name) in seen:
            return None
        if (m, name) in defs:
            return m, name
        b = bindings[m][0].get(name)
        return resolve(b[0], b[1], seen | {(m, name)}) if b and b[1] else None

    def target_of(m: str, node: ast.AST) -> tuple[str, str] | None:
        """The definition a loaded name or ``module.name`` in module ``m`` is, if any."""
        if isinstance(node, ast.Name):
            b = bindings[m][0].get(node.id)
            if b is None:
                return (m, node.id) if (m, node.id) in defs else None
            return resolve(*b) if b[1] else None
        parts = []
        while isinstance(node, ast.Attribute):
            parts.append(node.attr)
            node = node.value
        b = bindings[m][0].get(node.id) if isinstance(node, ast.Name) else None
        if b is None or b[1] is not None:
            return None
        module = b[0]
        for attr in reversed(parts[1:]):
            module = f"{module}.{attr}"
        return resolve(module, parts[0]) if module in known else None

    users: dict[tuple[str, str], set[tuple[str, str | None]]] = {d: set() for d in defs}
    for m, tree in trees.items():
        loaded: set[str] = set()
        for stmt in tree.body:
            owner = stmt.name if (m, getattr(stmt, "name", None)) in defs else None
            for node in ast.walk(stmt):
                if isinstance(node, ast.Name | ast.Attribute) and isinstance(node.ctx, ast.Load):
                    d = target_of(m, node)
                    if d is not None:
                        users[d].add((m, owner))
                    if isinstance(node, ast.Name):
                        loaded.add(node.id)
        bound, star = bindings[m]
        for local, (module, name) in bound.items():  # imported, never loaded: a re-export
            d = resolve(module, name) if name and local not in loaded else None
            if d is not None:
                users[d].add((m, None))
        for module in star:
            for mm, name in defs:
                if mm == rel_of[module] and not name.startswith("_"):
                    users[(mm, name)].add((m, None))

    def serves_rig(d: tuple[str, str], keep: set) -> bool:
        return all(u[0] in rig or u == d or u in keep for u in users[d])

    # the largest set whose every use is in a rig-only module, in itself or in the set ...
    keep = {d for d, u in users.items() if d[0] not in rig and u}
    while drop := {d for d in keep if not serves_rig(d, keep)}:
        keep -= drop
    # ... of those a rig-only module reaches (not a loop nothing outside it uses)
    reached = {d for d in keep if any(u[0] in rig for u in users[d])}
    while more := {d for d in keep - reached if users[d] & reached}:
        reached |= more
    out = []
    for m, name in reached:
        n = defs[(m, name)]
        first = min([n.lineno] + [x.lineno for x in n.decorator_list])
        out.append(Definition(m, name, first, n.end_lineno - first + 1))
    return sorted(out, key=lambda d: (d.module, d.line))


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in graph:
                    continue
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def _check_listed(listed: dict, trees: dict[str, ast.AST]) -> list[str]:
    """The entries of ``listed`` whose name is not a top-level definition of their module."""
    return [f"{m}:{n}" for (m, n) in listed if m not in trees or n not in top_level_names(trees[m])]


def report(top: int = 10) -> dict:
    """Every figure of the report as a dict (what ``--json`` prints)."""
    trees = {_rel(p): ast.parse(p.read_text(encoding="utf-8")) for p in modules()}
    per_package: dict[str, dict[str, int]] = {}
    per_module: dict[str, int] = {}
    for p in modules():
        n, code = line_counts(p)
        per_module[_rel(p)] = n
        d = per_package.setdefault(package_of(_rel(p)), {"modules": 0, "lines": 0, "code": 0})
        d["modules"] += 1
        d["lines"] += n
        d["code"] += code
    total = sum(d["lines"] for d in per_package.values())
    missing_rig = [m for m in RIG_ONLY if m not in per_module]
    rig_lines = {m: per_module[m] for m in RIG_ONLY if m in per_module}
    funcs = sorted(
        (f for p in modules() for f in functions(p, trees[_rel(p)])),
        key=lambda f: (-f.lines, f.module, f.line),
    )
    known = _known()
    shared = rig_only_definitions(trees, RIG_ONLY, known)
    shared_lines = sum(d.lines for d in shared)
    graphs = {
        kind: {
            _module_name(m): imports(
                m,
                t,
                deferred=(kind != "module level"),
                known=known,
                typing=(kind == "with TYPE_CHECKING"),
            )
            for m, t in trees.items()
        }
        for kind in ("module level", "with deferred", "with TYPE_CHECKING")
    }
    return {
        "total_lines": total,
        "packages": dict(sorted(per_package.items(), key=lambda kv: -kv[1]["lines"])),
        "rig_only": {
            "modules": rig_lines,
            "lines": sum(rig_lines.values()),
            "missing": missing_rig,
            "shared_definitions": [
                {"definition": f"{d.module}:{d.name}", "line": d.line, "lines": d.lines}
                for d in shared
            ],
            "shared_lines": shared_lines,
            "total_lines": sum(rig_lines.values()) + shared_lines,
        },
        "estimators": [f"{m}:{n}" for (m, n) in ESTIMATORS],
        "pose_carriers": [f"{m}:{n}" for (m, n) in POSE_CARRIERS],
        "not_found": _check_listed(ESTIMATORS, trees) + _check_listed(POSE_CARRIERS, trees),
        "longest_functions": [
            {"function": f"{f.module}:{f.name}", "line": f.line, "lines": f.lines}
            for f in funcs[:top]
        ],
        "import_circles": {kind: circles(g) for kind, g in graphs.items()},
        "imports": {kind: sum(len(v) for v in g.values()) for kind, g in graphs.items()},
    }


def _print(r: dict) -> None:
    total = r["total_lines"]
    print(
        f"rs_localizer: {total} lines in {sum(d['modules'] for d in r['packages'].values())} "
        "modules"
    )
    print("\nlines per package (physical, code):")
    for name, d in r["packages"].items():
        print(f"  {name:<14} {d['lines']:>6} {d['code']:>6}  {d['modules']:>3} modules")
    rig = r["rig_only"]
    print(
        f"\nrig-only modules: {rig['lines']} lines ({100 * rig['lines'] / total:.1f} % of the "
        "package)"
    )
    for m, n in rig["modules"].items():
        print(f"  {m:<26} {n:>5}  {RIG_ONLY[m]}")
    for m in rig["missing"]:
        print(f"  {m:<26}     -  listed but not in the package")
    shared = rig["shared_definitions"]
    print(
        f"rig-only code in shared modules: {rig['shared_lines']} lines in {len(shared)} "
        "definitions (used only by the modules above, or through one another)"
    )
    for d in shared:
        print(f"  {d['definition']:<58} {d['lines']:>5}")
    print(
        f"rig-only lines, modules and shared definitions: {rig['total_lines']} "
        f"({100 * rig['total_lines'] / total:.1f} % of the package)"
    )
    print(f"\nestimators: {len(ESTIMATORS)}")
    for (m, n), why in ESTIMATORS.items():
        print(f"  {m}:{n}  {why}")
    print(f"\npose carriers: {len(POSE_CARRIERS)}")
    for (m, n), why in POSE_CARRIERS.items():
        print(f"  {m}:{n}  {why}")
    for x in r["not_found"]:
        print(f"  NOT FOUND: {x} (the list above is out of date)")
    print(f"\nthe {len(r['longest_functions'])} longest functions (lines):")
    for f in r["longest_functions"]:
        print(f"  {f['lines']:>4}  {f['function']} (line {f['line']})")
    print("\nimport circles among the package's modules:")
    for kind, cs in r["import_circles"].items():
        print(f"  {kind} ({r['imports'][kind]} imports): {len(cs)}")
        for c in cs:
            print("    " + " <-> ".join(c))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    ap.add_argument("--top", type=int, default=10, help="longest functions shown (default 10)")
    a = ap.parse_args(argv)
    r = report(a.top)
    if a.json:
        print(json.dumps(r, indent=1))
    else:
        _print(r)
    return 1 if r["not_found"] or r["rig_only"]["missing"] else 0


if __name__ == "__main__":
    sys.exit(main())
