"""The package's layers: imports point down only, ``ros`` is the only rclpy importer, nothing in
the library imports ``sim``, nothing in the package (and no test but the benchmarks' own) imports
the benchmarks outside it, and one solver registry (docs/architecture.md "Layers")."""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "rs_localizer"

#: layer of each top-level module / subpackage, lowest first; a module may import only its own
#: layer or lower ones (``sim`` produces data: it may use the model and the front ends' map
#: formats; ``experiments`` and ``cli`` compose everything)
LAYER = {
    "geometry": 0,
    "camera": 0,
    "_so3": 0,
    "_linalg": 0,
    "_jit": 0,  # (the kernels' decorator)
    "maps": 0,
    "accuracy": 0,
    "frames": 0,
    "pose": 0,
    "correspondences": 0,
    "cv_compat": 0,  # (OpenCV's API across versions: the board models', detectors', renderer's)
    "solvers": 1,
    "estimation": 2,
    "calibration": 2.4,  # (mountings, line delay: posed by the estimator)
    "tracking": 2.5,
    "runtime": 2.7,  # (warms the tracker up too)
    "frontends": 3,
    "viz": 3,
    "sim": 4,
    "mapping": 4,
    "ros": 5,
    "experiments": 6,
    "cli": 7,
}
#: the package's own top level (re-exports the public API) and ``python -m rs_localizer``
TOP = {"__init__", "__main__"}
ROS_PACKAGES = {
    "rclpy",
    "geometry_msgs",
    "sensor_msgs",
    "nav_msgs",
    "diagnostic_msgs",
    "std_msgs",
    "tf2_msgs",
    "visualization_msgs",
    "rcl_interfaces",
    "builtin_interfaces",
    "lifecycle_msgs",
}
#: the benchmarks (``python -m benchmarks.X`` from a checkout): outside the package, not installed
BENCHMARKS = PKG.parent / "benchmarks"


def _unit(path: Path) -> str:
    rel = path.relative_to(PKG).with_suffix("")
    return rel.parts[0]


def _imports(path: Path):
    """(absolute module name, line) of every import in a file (relative ones resolved)."""
    tree = ast.parse(path.read_text())
    rel = path.relative_to(PKG.parent).with_suffix("")
    pkg = list(rel.parts[:-1])
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
                if node.module is None:  # from . import x
                    for a in node.names:
                        yield f"{mod}.{a.name}", node.lineno
                    continue
            else:
                mod = node.module
            yield mod, node.lineno


FILES = sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts)


def test_every_unit_has_a_layer():
    units = {_unit(p) for p in FILES} - TOP
    assert units <= set(LAYER), f"modules without a layer: {units - set(LAYER)}"


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(PKG)))
def test_imports_point_down(path):
    unit = _unit(path)
    if unit in TOP:
        return
    bad = []
    for mod, line in _imports(path):
        parts = mod.split(".")
        if parts[0] in ROS_PACKAGES and unit != "ros":
            bad.append(f"line {line}: {mod} (only rs_localizer.ros imports ROS)")
        if parts[0] == BENCHMARKS.name:
            bad.append(f"line {line}: {mod} (the package never imports the benchmarks)")
        if parts[0] != "rs_localizer" or len(parts) < 2:
            continue
        target = parts[1]
        if target in TOP:
            bad.append(f"line {line}: {mod} (import the module, not the package top)")
        elif LAYER[target] > LAYER[unit]:
            bad.append(f"line {line}: {mod} ({unit} -> {target} points up)")
    assert not bad, f"{path.relative_to(PKG)}:\n" + "\n".join(bad)


def test_benchmarks_are_outside_the_package():
    """The benchmarks are a top-level package of the checkout, not of ``rs_localizer``; only
    ``test/benchmarks/`` (the benchmarks' own logic) imports them among the tests."""
    assert (BENCHMARKS / "__init__.py").is_file()
    assert not (PKG / "evaluation").exists() and not (PKG / "benchmarks").exists()
    tests = PKG.parent / "test"
    found = []
    for path in sorted(tests.rglob("*.py")):
        if path.is_relative_to(tests / "benchmarks"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names = [node.module]
            else:
                continue
            found += [
                f"{path.relative_to(tests)}:{node.lineno} {n}"
                for n in names
                if n.split(".")[0] == BENCHMARKS.name
            ]
    assert not found, "library tests importing the benchmarks:\n" + "\n".join(found)


def test_one_solver_registry():
    """The estimator, the front ends, the node and the CLI read the registry: no comparison with
    a solver-name literal outside ``solvers/`` (the experiments name solvers in their claims)."""
    from rs_localizer.solvers.registry import SOLVERS

    names = set(SOLVERS)
    offenders = []
    for path in FILES:
        if _unit(path) in ("solvers", "experiments"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                consts = [
                    c.value
                    for c in [node.left, *node.comparators]
                    if isinstance(c, ast.Constant) and isinstance(c.value, str)
                ]
                if any(c in names for c in consts):
                    offenders.append(f"{path.relative_to(PKG)}:{node.lineno}")
    assert not offenders, "solver-name comparisons outside the registry: " + ", ".join(offenders)


def test_public_api():
    import rs_localizer
    from rs_localizer.camera import CameraModel
    from rs_localizer.estimation.estimate import EstimateOptions, estimate_rs_pose

    assert rs_localizer.estimate_rs_pose is estimate_rs_pose
    assert rs_localizer.EstimateOptions is EstimateOptions
    assert rs_localizer.CameraModel is CameraModel


#: where every public function and method carries type annotations: the solvers, the
#: estimator, the front ends, the ROS layer, the simulation, the command line and the camera
#: model
ANNOTATED = [
    *sorted((PKG / "solvers").glob("*.py")),
    *sorted((PKG / "estimation").glob("*.py")),
    *sorted((PKG / "tracking").glob("*.py")),
    *sorted((PKG / "frontends").glob("*.py")),
    *sorted((PKG / "ros").rglob("*.py")),
    *sorted((PKG / "sim").rglob("*.py")),
    *sorted((PKG / "cli").glob("*.py")),
    *sorted((PKG / "mapping").glob("*.py")),
    *sorted((PKG / "maps").glob("*.py")),
    *sorted((PKG / "viz").glob("*.py")),
    PKG / "camera.py",
    PKG / "cv_compat.py",
]


def _public_functions(tree):
    """(qualified name, node) of the public functions and methods of public classes at module
    level, numba kernels excluded (numba does not read annotations)."""
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            for fn in _public_functions(node):
                yield f"{node.name}.{fn[0]}", fn[1]
        elif (
            isinstance(node, ast.FunctionDef)
            and (not node.name.startswith("_") or node.name == "__init__")
            and not any(
                ast.unparse(d).split("(")[0] in ("kernel", "njit") for d in node.decorator_list
            )
        ):
            yield node.name, node


def test_public_functions_are_annotated():
    missing = []
    for path in ANNOTATED:
        for name, fn in _public_functions(ast.parse(path.read_text())):
            args = [a for a in fn.args.args + fn.args.kwonlyargs if a.arg not in ("self", "cls")]
            args += [a for a in (fn.args.vararg, fn.args.kwarg) if a is not None]
            returns = fn.returns is not None or fn.name == "__init__"
            if not returns or any(a.annotation is None for a in args):
                missing.append(f"{path.relative_to(PKG.parent)}:{fn.lineno} {name}")
    assert not missing, "public functions without type annotations:\n" + "\n".join(missing)


def test_no_private_names_across_modules():
    """A helper another module uses is public where it belongs: no ``from m import _name``
    (``__dunder__`` names aside) and no ``from . import _module``."""
    found = []
    for path in sorted(PKG.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                found += [
                    f"{path.relative_to(PKG.parent)}:{node.lineno} {a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                ]
    assert not found, "private names imported across modules:\n" + "\n".join(found)


def test_tests_import_helpers_not_tests():
    """Test modules share code through ``test/helpers`` (fixtures: ``test/conftest.py``): none
    imports another test module or ``conftest``."""
    tests = PKG.parent / "test"
    found = []
    for path in sorted(tests.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names = [node.module]
            found += [
                f"{path.relative_to(tests)}:{node.lineno} {n}"
                for n in names
                if n.split(".")[0] == "conftest" or n.split(".")[0].startswith("test_")
            ]
    assert not found, "test modules importing tests or conftest:\n" + "\n".join(found)


def test_test_modules_have_unique_names():
    """pytest imports the test folders' modules by their file names (no packages): two test
    files of one name in two folders stop the suite at collection."""
    tests = PKG.parent / "test"
    seen: dict[str, list[str]] = {}
    for path in sorted(tests.rglob("test_*.py")):
        seen.setdefault(path.name, []).append(str(path.relative_to(tests)))
    twice = {name: paths for name, paths in seen.items() if len(paths) > 1}
    assert not twice, f"test modules of one name: {twice}"


#: the modules that define front ends: the registry builds them by name, the package re-exports
#: what the rest of the library uses
FRONTEND_MODULES = {"aruco", "boards", "features", "tracking"}


def test_front_end_modules_imported_through_the_registry_or_the_package():
    """Outside ``frontends/`` no module of the package imports a front-end module by path:
    it uses :mod:`rs_localizer.frontends` (its re-exports, ``make_frontend``) or the registry."""
    bad = []
    for path in FILES:
        if _unit(path) == "frontends":
            continue
        for mod, line in _imports(path):
            parts = mod.split(".")
            if (
                parts[:2] == ["rs_localizer", "frontends"]
                and parts[2:3]
                and (parts[2] in FRONTEND_MODULES)
            ):
                bad.append(f"{path.relative_to(PKG)}:{line} {mod}")
    assert not bad, "front-end modules imported by path:\n" + "\n".join(bad)


def test_no_import_circle_among_the_front_ends():
    """Inside ``frontends/`` imports (function-level ones too) form no circle: the registry
    (and the package's re-exports and its map cache) import the front-end modules, a front end
    imports only the helpers it builds on (image codecs, OpenCV compatibility, the per-image
    front end the video one extends), never the registry."""
    pkg = PKG / "frontends"
    graph = {}
    for path in sorted(pkg.glob("*.py")):
        deps = set()
        for mod, _ in _imports(path):
            parts = mod.split(".")
            if parts[:2] == ["rs_localizer", "frontends"] and len(parts) > 2:
                deps.add(parts[2])
        graph[path.stem] = deps - {path.stem}
    for name in set(graph) - {"registry", "shared", "__init__"}:
        assert "registry" not in graph[name], f"frontends/{name}.py imports the registry"

    def reach(start, node, seen):
        for d in graph.get(node, ()):
            if d == start:
                return True
            if d not in seen:
                seen.add(d)
                if reach(start, d, seen):
                    return True
        return False

    circles = [n for n in graph if reach(n, n, set())]
    assert not circles, f"import circle through frontends/{circles}"


def test_architecture_names_every_module():
    """docs/architecture.md's "Modules" table has one row per module of the package (its path
    under ``rs_localizer/``; ``__init__.py`` files aside), and no row for a module that does not
    exist; the "Layers" table's rows name the package's subpackages."""
    doc = (PKG.parent / "docs" / "architecture.md").read_text()
    section = doc.split("\n## Modules\n", 1)[1].split("\n## ", 1)[0]
    named = []
    for line in section.splitlines():
        cells = line.split("|")
        if line.startswith("| `") and len(cells) > 2:
            named.append(cells[1].strip().strip("`"))
    modules = sorted(str(p.relative_to(PKG)) for p in FILES if p.name != "__init__.py")
    assert len(named) == len(set(named)), "modules named twice in the Modules table"
    missing, extra = sorted(set(modules) - set(named)), sorted(set(named) - set(modules))
    assert not missing, f"modules missing from the Modules table: {missing}"
    assert not extra, f"Modules table rows for no module: {extra}"
    layers = doc.split("\n## Layers\n", 1)[1].split("\n## ", 1)[0]
    for unit in sorted({_unit(p) for p in FILES} - TOP):
        if (PKG / unit).is_dir():
            assert f"`{unit}/`" in layers, f"{unit}/ has no row in the Layers table"
