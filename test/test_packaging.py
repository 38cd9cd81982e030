"""What the distro install (docs/install.md; .ci/distro) relies on: package.xml (rosdep
keys) and requirements.txt (pip, what has no usable key) together declare every third-party
module the package and its launch file import, and numba kernels inline only through
``_so3.INLINE`` (Debian 12's numba 0.56 takes > 20 min over a kernel with ``inline="always"``
helpers)."""

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: rosdep keys of Python libraries (rosdistro's rosdep/python.yaml; each resolves to the Debian /
#: Ubuntu package of the same name) -> the module they provide
KEY_MODULES = {
    "python3-numpy": "numpy",
    "python3-scipy": "scipy",
    "python3-opencv": "cv2",
    "python3-numba": "numba",
    "python3-matplotlib": "matplotlib",
    "python3-yaml": "yaml",
    "python3-skimage": "skimage",
    "python3-tqdm": "tqdm",
    "python3-pytest": "pytest",
    "python3-hypothesis": "hypothesis",
}
#: imported only where present, or brought by a declared package
OPTIONAL = {
    "PIL": "Pillow, a dependency of matplotlib (python3-matplotlib depends on python3-pil)",
    "threadpoolctl": "benchmarks only (extra 'bench'), imported inside a try",
    "pycolmap": "map-features only (extra 'mapping'), imported where used, says how to install",
    "foxglove": "rs-localizer view only (extra 'view'), imported where used, says how to install",
    "pupil_apriltags": "the AprilTag library's PyPI binding (setup.py); the distro route has "
    "Debian's python3-apriltag (key apriltag); imported inside a try, OpenCV stands in",
}


def _third_party_imports(paths):
    found = {}
    for p in paths:
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top != "rs_localizer":
                    found.setdefault(top, p.relative_to(ROOT))
    return found


def _declared():
    keys = [
        e.text.strip()
        for e in ET.parse(ROOT / "package.xml").getroot()
        if e.tag in ("depend", "exec_depend", "test_depend", "build_depend")
    ]
    reqs = [
        line.split("#")[0].strip() for line in (ROOT / "requirements.txt").read_text().splitlines()
    ]
    reqs = [r.split(">")[0].split("=")[0].split("<")[0].strip().lower() for r in reqs if r]
    return keys, reqs


def test_every_import_is_declared():
    keys, reqs = _declared()
    unknown = [k for k in keys if k.startswith("python3-") and k not in KEY_MODULES]
    assert not unknown, f"add the module of these rosdep keys to KEY_MODULES: {unknown}"
    modules = {KEY_MODULES.get(k, k) for k in keys} | set(reqs)  # ROS keys: the package name
    files = list((ROOT / "rs_localizer").rglob("*.py")) + list((ROOT / "launch").glob("*.py"))
    imports = _third_party_imports(files)
    assert {"numpy", "cv2", "rclpy", "poselib", "rosbags", "launch_ros"} <= set(imports)
    missing = {m: str(f) for m, f in imports.items() if m not in modules and m not in OPTIONAL}
    assert not missing, f"imported but in neither package.xml nor requirements.txt: {missing}"


def test_no_key_is_also_a_pip_requirement():
    keys, reqs = _declared()
    both = {KEY_MODULES.get(k, k) for k in keys} & set(reqs)
    assert not both, f"declared twice (rosdep and pip would both install them): {both}"


def test_numba_inlining_goes_through_the_switch():
    """``inline=`` of every numba decorator is ``INLINE`` (never a literal "always")."""
    literal = []
    for p in sorted((ROOT / "rs_localizer").rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            if (
                isinstance(node, ast.keyword)
                and node.arg == "inline"
                and not (isinstance(node.value, ast.Name) and node.value.id == "INLINE")
            ):
                literal.append(f"{p.relative_to(ROOT)}:{node.value.lineno}")
    assert not literal, f"use inline=INLINE (rs_localizer._so3) at {literal}"
