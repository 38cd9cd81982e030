"""Build the ``tf2_msgs`` message package (``tf2_msgs/msg/TFMessage``) for the ROS 2 Jazzy
wheels from PyPI, which do not include it, so that the node can publish ``/tf``.

    .venv/bin/python tools/build_tf2_msgs.py          # or: make tf2-msgs

``TFMessage`` is ``geometry_msgs/TransformStamped[] transforms``. The script generates its C
and Python code with the rosidl generators the wheels already bring (``rosidl_generator_c``,
``rosidl_generator_py``, the ``rosidl_typesupport_c``/``introspection_c``/``fastrtps_c`` type
supports), compiles them with the system's C and C++ compilers (``cc``, ``c++``) against the
wheels' headers and libraries, and installs the libraries into ``<prefix>/lib`` (where the
wheels' own message libraries are found) and the Python package into the prefix's
site-packages. On a ROS 2 install (``/opt/ros/jazzy``) tf2_msgs is already there: nothing to do.

Exit status 0 when ``tf2_msgs`` is importable afterwards (or already was), 1 with the reason
otherwise (no compiler, generators missing, a compile error).
"""

from __future__ import annotations

import argparse
import logging
import os
import pathlib
import shutil
import subprocess
import sys
import sysconfig
import tempfile

IDL = """\
#include "geometry_msgs/msg/TransformStamped.idl"

module tf2_msgs {
  module msg {
    struct TFMessage {
      sequence<geometry_msgs::msg::TransformStamped> transforms;
    };
  };
};
"""
TYPESUPPORTS = (
    "rosidl_typesupport_c",
    "rosidl_typesupport_fastrtps_c",
    "rosidl_typesupport_introspection_c",
)


class _SameEntryPointTwice(logging.Filter):
    """Drops rosidl_cli's warning about an entry point found twice when both are the same one
    (the wheels' distribution is seen through two paths of the environment): nothing is wrong."""

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if not text.startswith("Found duplicate entry point"):
            return True
        first, _, second = text.partition(": got ")[2].partition(" and ")
        return first != second


def generate(out: pathlib.Path, share: pathlib.Path) -> None:
    """The generators' C, C++ and Python sources of TFMessage under ``out``."""
    from rosidl_generator_c.cli import GenerateC
    from rosidl_generator_py.cli import GeneratePython
    from rosidl_typesupport_c.cli import GenerateCTypesupport
    from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
    from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

    logging.getLogger("rosidl_cli.entry_points").addFilter(_SameEntryPointTwice())
    (out / "idl" / "msg").mkdir(parents=True)
    (out / "idl" / "msg" / "TFMessage.idl").write_text(IDL)
    files = [f"{out / 'idl'}:msg/TFMessage.idl"]
    for cls, name in (
        (GenerateC, "c"),
        (GeneratePython, "py"),
        (GenerateCTypesupport, "typesupport_c"),
        (GenerateIntrospectionCTypesupport, "introspection_c"),
        (GenerateFastRTPSCTypesupport, "fastrtps_c"),
    ):
        cls(name).generate("tf2_msgs", files, [str(share)], out / name)


def _run(cmd: list[str]) -> None:
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode:
        raise RuntimeError(f"{' '.join(cmd[:1])} failed:\n{res.stderr[-2000:]}")


def compile_and_install(
    gen: pathlib.Path, ros: pathlib.Path, lib: pathlib.Path, site: pathlib.Path
) -> None:
    """Compile the generated sources against the ROS headers and libraries of the environment
    ``ros``; install the libraries into ``lib`` and the package into ``site`` once all of them
    compiled (a failed build installs nothing)."""
    prefix, final_lib, final_site = ros, lib, site
    lib, site = gen / "out" / "lib", gen / "out" / "site"
    inc = gen / "include"
    (inc / "tf2_msgs").mkdir(parents=True)
    for d in ("c", "introspection_c", "fastrtps_c"):
        shutil.copytree(gen / d / "msg", inc / "tf2_msgs" / "msg", dirs_exist_ok=True)
    incs = [f"-I{inc}", f"-I{prefix / 'include'}"]
    incs += [f"-I{d}" for d in sorted((prefix / "include").iterdir()) if d.is_dir()]
    import numpy

    incs += [f"-I{sysconfig.get_paths()['include']}", f"-I{numpy.get_include()}"]
    flags = ["-O2", "-fPIC", "-shared", *incs, f"-L{ros / 'lib'}", f"-L{lib}"]
    cc, cxx = shutil.which("cc") or shutil.which("gcc"), shutil.which("c++") or shutil.which("g++")
    if not cc or not cxx:
        raise RuntimeError("no C/C++ compiler (cc, c++) on PATH")
    base = ["-lrosidl_runtime_c", "-lrcutils"]
    gc = ["-ltf2_msgs__rosidl_generator_c"]
    d = gen / "c" / "msg" / "detail"
    steps = [
        (
            cc,
            [
                d / "tf_message__functions.c",
                d / "tf_message__type_support.c",
                d / "tf_message__description.c",
            ],
            lib / "libtf2_msgs__rosidl_generator_c.so",
            ["-lgeometry_msgs__rosidl_generator_c", *base],
        ),
        (
            cc,
            [gen / "introspection_c/msg/detail/tf_message__type_support.c"],
            lib / "libtf2_msgs__rosidl_typesupport_introspection_c.so",
            [*gc, "-lgeometry_msgs__rosidl_typesupport_introspection_c", *base],
        ),
        (
            cxx,
            [gen / "fastrtps_c/msg/detail/tf_message__type_support_c.cpp"],
            lib / "libtf2_msgs__rosidl_typesupport_fastrtps_c.so",
            [
                *gc,
                "-lgeometry_msgs__rosidl_typesupport_fastrtps_c",
                "-lgeometry_msgs__rosidl_generator_c",
                "-lrosidl_typesupport_fastrtps_c",
                "-lfastcdr",
                *base,
            ],
        ),
        (
            cxx,
            [gen / "typesupport_c/msg/tf_message__type_support.cpp"],
            lib / "libtf2_msgs__rosidl_typesupport_c.so",
            [*gc, "-lrosidl_typesupport_c", *base],
        ),
        (
            cc,
            [gen / "py/msg/_tf_message_s.c"],
            lib / "libtf2_msgs__rosidl_generator_py.so",
            [
                *gc,
                "-lgeometry_msgs__rosidl_generator_py",
                "-lgeometry_msgs__rosidl_generator_c",
                *base,
            ],
        ),
    ]
    pkg = site / "tf2_msgs"
    (pkg / "msg").mkdir(parents=True, exist_ok=True)
    for ts in TYPESUPPORTS:
        steps.append(
            (
                cc,
                [gen / f"py/_tf2_msgs_s.ep.{ts}.c"],
                pkg / f"tf2_msgs_s__{ts}.so",
                ["-ltf2_msgs__rosidl_generator_py", f"-ltf2_msgs__{ts}", *gc, "-lrmw", *base],
            )
        )
    lib.mkdir(parents=True, exist_ok=True)
    for compiler, sources, target, libs in steps:
        std = ["-std=c++17"] if compiler == cxx else []
        _run([compiler, *std, *flags, *map(str, sources), "-o", str(target), *libs])
    shutil.copy(gen / "py" / "msg" / "_tf_message.py", pkg / "msg")
    shutil.copy(gen / "py" / "msg" / "__init__.py", pkg / "msg")
    (pkg / "__init__.py").touch()
    final_lib.mkdir(parents=True, exist_ok=True)
    for f in lib.iterdir():
        shutil.copy(f, final_lib / f.name)
    shutil.copytree(pkg, final_site / "tf2_msgs", dirs_exist_ok=True)


def have_tf2_msgs() -> bool:
    """tf2_msgs imports and serializes in a fresh interpreter of this environment."""
    code = (
        "from rclpy.serialization import serialize_message\n"
        "from tf2_msgs.msg import TFMessage\n"
        "serialize_message(TFMessage())\n"
    )
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--prefix", default=sys.prefix, help="install into PREFIX/lib (default: this environment)"
    )
    ap.add_argument("--site", help="site-packages to install into (default: the prefix's)")
    ap.add_argument("--force", action="store_true", help="build even if tf2_msgs imports")
    args = ap.parse_args(argv)
    prefix = pathlib.Path(args.prefix)
    site = pathlib.Path(args.site or sysconfig.get_paths(vars={"base": prefix})["purelib"])
    if not args.force and have_tf2_msgs():
        print("tf2_msgs is already importable: nothing to do")
        return 0
    try:
        with tempfile.TemporaryDirectory() as tmp:
            gen = pathlib.Path(tmp)
            ros = pathlib.Path(sys.prefix)  # the wheels' headers, libraries and .idl files
            # (the generators find their templates through the ament index of the wheels)
            os.environ.setdefault("AMENT_PREFIX_PATH", str(ros))
            generate(gen, ros / "share")
            compile_and_install(gen, ros, prefix / "lib", site)
    except (ImportError, RuntimeError, OSError) as e:
        print(f"tf2_msgs not built ({type(e).__name__}: {e}); the node will not publish /tf")
        return 1
    print(f"built tf2_msgs into {prefix / 'lib'} and {site / 'tf2_msgs'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
