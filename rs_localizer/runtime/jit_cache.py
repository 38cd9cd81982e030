"""Where numba keeps the compiled kernels, and progress reports while it compiles.

numba compiles the package's kernels (declared with :func:`rs_localizer._jit.kernel`:
``cache=True``) on first use and caches the machine code next to the sources, in each
subpackage's ``__pycache__``. An installed package is often read-only (a system install, a
read-only image, another user's venv): numba then silently falls back to its own per-user
directory, or compiles on every start. This module, called by ``rs_localizer/__init__.py``
before anything imports numba, makes that explicit:

* ``NUMBA_CACHE_DIR`` already set: kept (numba caches there).
* package directory writable: numba's default (``__pycache__`` next to the sources).
* otherwise: ``NUMBA_CACHE_DIR = $XDG_CACHE_HOME/rs_localizer/numba`` (default
  ``~/.cache/rs_localizer/numba``).

Compiling at install time (``rs-localizer compile`` right after ``pip install`` or ``colcon
build``, while the package directory is still writable) leaves the kernels in the package's
``__pycache__``. When the package is read-only at run time, :func:`seed_cache` copies those
files into the user cache directory (a few MB, milliseconds; only files missing there or older
than the package's), so even the first start of every user loads compiled kernels instead of
compiling them. numba validates each cached kernel against its source file (content hash or
modification time + size, depending on the numba version) and the CPU, and
:func:`rs_localizer._jit.kernel` adds the files of the kernels it calls (compiled into it), so
a stale or foreign entry is recompiled, never used.

:func:`compile_progress` reports each kernel numba compiles (name, seconds) to a callback: the
node logs them during its warm-up and ``rs-localizer compile`` prints them.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

__all__ = [
    "PACKAGE_DIR",
    "CompileProgress",
    "cache_state",
    "compile_progress",
    "configure",
    "numba_error",
    "package_writable",
    "seed_cache",
    "user_cache_dir",
]

#: the installed package directory (``rs_localizer``) as Python imports it (not
#: symlink-resolved: numba names its cache directories after this path)
PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_SUFFIXES = (".nbi", ".nbc")  # numba's index and data files

_state = {"mode": "unconfigured", "dir": None, "seeded": 0}
_numba = {"error": None}


def numba_error() -> str | None:
    """Why numba could not be imported in this process (``None``: it was). Then
    :func:`configure` put a stand-in in its place, so that the package imports and runs on
    its NumPy implementation (:mod:`rs_localizer.estimation.numpy_impl`); calling a kernel raises
    RuntimeError with this reason."""
    return _numba["error"]


class _KernelUnavailable:
    """Stand-in for a numba kernel where numba is missing: calling it raises RuntimeError
    (the NumPy implementation never calls one); ``py_func`` is the Python function."""

    def __init__(self, fn):
        self.py_func = fn
        self.__name__ = getattr(fn, "__name__", "kernel")
        self.__doc__ = getattr(fn, "__doc__", None)

    def __call__(self, *args, **kwargs):
        raise RuntimeError(
            f"{self.__name__} is a compiled kernel and numba is not available "
            f"({_numba['error']}): only the uncompiled path runs here"
        )


def _numba_standin() -> dict:
    """Modules that stand in for numba (``numba``, ``numba.types``, ``numba.extending``,
    ``numba.core``, ``numba.core.ir``, ``numba.core.imputils``) with what the package uses at
    import time: ``njit`` (kernels that raise when called), ``prange``, the extension
    decorators (no-ops)."""
    import types as _pytypes

    def njit(*args, **kwargs):
        if len(args) == 1 and callable(args[0]) and not kwargs:
            return _KernelUnavailable(args[0])
        return _KernelUnavailable

    def decorator_factory(*_a, **_k):
        return lambda f: f

    class _Type:
        def __init__(self, name: str = "", *a, **k):
            self.name = name

    mods = {
        n: _pytypes.ModuleType(n)
        for n in (
            "numba", "numba.types", "numba.extending", "numba.core", "numba.core.ir",
            "numba.core.imputils",
        )
    }  # fmt: skip
    top, ext = mods["numba"], mods["numba.extending"]
    top.njit = top.jit = njit
    top.prange = range
    top.types, top.extending, top.core = mods["numba.types"], ext, mods["numba.core"]
    top.__rs_localizer_standin__ = True
    mods["numba.types"].Type = _Type
    ext.overload = ext.register_model = ext.unbox = ext.box = decorator_factory
    ext.NativeValue = lambda *a, **k: None
    ext.models = _pytypes.SimpleNamespace(OpaqueModel=object, StructModel=object)
    mods["numba.core"].ir = mods["numba.core.ir"]
    mods["numba.core"].imputils = mods["numba.core.imputils"]
    mods["numba.core.imputils"].lower_constant = decorator_factory
    mods["numba.core.ir"].Var = type("Var", (), {})
    return mods


def _import_numba() -> None:
    """Import numba; if that fails (missing, or broken: llvmlite, a CPU it does not support),
    record why (:func:`numba_error`) and install the stand-in modules."""
    if "numba" in sys.modules:
        return
    try:
        import numba  # noqa: F401
    except Exception as e:  # (ImportError, or anything numba's own import raises)
        _numba["error"] = f"{type(e).__name__}: {e}"
        for name in [n for n in sys.modules if n == "numba" or n.startswith("numba.")]:
            del sys.modules[name]
        sys.modules.update(_numba_standin())


def user_cache_dir(environ=None) -> str:
    """``$XDG_CACHE_HOME/rs_localizer/numba``, default ``~/.cache/rs_localizer/numba``."""
    env = os.environ if environ is None else environ
    base = env.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "rs_localizer", "numba")


def _package_dirs(package_dir: str):
    for root, dirs, files in os.walk(package_dir):
        dirs[:] = [d for d in dirs if d != "__pycache__" and not d.startswith(".")]
        if any(f.endswith(".py") for f in files):
            yield root


def package_writable(package_dir: str = PACKAGE_DIR) -> bool:
    """numba's own test, for every source directory of the package: can ``__pycache__`` be
    created and a file written in it? (A chmod'ed directory is writable for root; a read-only
    mount is not.)"""
    for d in _package_dirs(package_dir):
        cache = os.path.join(d, "__pycache__")
        try:
            os.makedirs(cache, exist_ok=True)
            tempfile.TemporaryFile(dir=cache).close()
        except OSError:
            return False
    return True


def _numba_subdir(source_dir: str) -> str:
    """numba's name for the cache directory of the sources in ``source_dir`` under
    ``NUMBA_CACHE_DIR`` (``<dir name>_<sha1 of the absolute path>``, numba >= 0.49)."""
    return f"{os.path.basename(source_dir)}_{hashlib.sha1(source_dir.encode()).hexdigest()}"


def seed_cache(package_dir: str, cache_dir: str) -> int:
    """Copy the compiled kernels found in the package's ``__pycache__`` directories into
    ``cache_dir`` (a ``NUMBA_CACHE_DIR``), where a file is missing or older. Atomic per file
    (several processes may start at once). Returns the number of files copied; never raises
    (a cache that cannot be seeded is only slower)."""
    copied = 0
    for d in _package_dirs(package_dir):
        src = os.path.join(d, "__pycache__")
        try:
            names = [n for n in os.listdir(src) if n.endswith(_SUFFIXES)]
        except OSError:
            continue
        if not names:
            continue
        dst_dir = os.path.join(cache_dir, _numba_subdir(d))
        for n in names:
            s, t = os.path.join(src, n), os.path.join(dst_dir, n)
            try:
                st = os.stat(s)
                if os.path.exists(t) and os.stat(t).st_mtime >= st.st_mtime:
                    continue
                os.makedirs(dst_dir, exist_ok=True)
                fd, tmp = tempfile.mkstemp(dir=dst_dir, prefix=".seed-")
                os.close(fd)
                shutil.copy2(s, tmp)
                os.replace(tmp, t)
                copied += 1
            except OSError:
                continue
    return copied


def configure(environ=None, package_dir: str = PACKAGE_DIR) -> dict:
    """Choose numba's cache directory (see the module docstring); call before numba is
    imported. Sets ``NUMBA_CACHE_DIR`` in ``environ`` (default ``os.environ``) when the package
    is not writable and seeds it from the package; for the process's own configuration it
    then imports numba (a stand-in where that fails, :func:`numba_error`). Returns
    ``{"mode", "dir", "seeded"}`` (see :func:`cache_state`, which keeps the result for this
    package and ``os.environ``)."""
    env = os.environ if environ is None else environ
    if env.get("NUMBA_CACHE_DIR"):
        mode, cache = "NUMBA_CACHE_DIR", env["NUMBA_CACHE_DIR"]
    elif package_writable(package_dir):
        mode, cache = "package", None
    else:
        mode, cache = "user", user_cache_dir(env)
        env["NUMBA_CACHE_DIR"] = cache
        if "numba" in sys.modules:  # imported before us: make numba read the variable again
            try:
                from numba.core import config

                config.reload_config()
            except Exception:
                pass
    seeded = seed_cache(package_dir, cache) if cache else 0
    state = {
        "mode": mode,
        "dir": cache or os.path.join(package_dir, "**", "__pycache__"),
        "seeded": seeded,
    }
    if environ is None and package_dir == PACKAGE_DIR:  # the process's own configuration
        _state.update(state)
        _import_numba()
    return state


def cache_state() -> dict:
    """``{"mode": "package" | "user" | "NUMBA_CACHE_DIR", "dir": path, "seeded": files}``."""
    return dict(_state)


@dataclass
class CompileProgress:
    """What :func:`compile_progress` saw: ``kernels`` (name, seconds) compiled at top level
    (a kernel's callees compile inside it), ``seconds`` spent compiling."""

    kernels: list = field(default_factory=list)
    seconds: float = 0.0


@contextmanager
def compile_progress(log=None):
    """Report every kernel numba compiles inside the ``with`` block (not those loaded from
    the cache): ``log("compiling <module.kernel> ...")`` when it starts and ``log("compiled
    <kernel> in X s (N kernels, Y s so far)")`` when it is done. Yields a
    :class:`CompileProgress`. Uses numba's event API (``numba.core.event``); without it
    (numba < 0.52) nothing is reported."""
    prog = CompileProgress()
    try:
        from numba.core import event
    except ImportError:
        yield prog
        return
    t_start = time.perf_counter()
    local = threading.local()

    def name(ev):
        d = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
        f = getattr(d, "py_func", None)
        return f"{f.__module__}.{f.__qualname__}" if f is not None else str(d)

    class _Listener(event.Listener):
        def on_start(self, ev):
            stack = getattr(local, "stack", None)
            if stack is None:
                stack = local.stack = []
            stack.append(time.perf_counter())
            if len(stack) == 1 and log is not None:
                log(f"compiling {name(ev)} ...")

        def on_end(self, ev):
            stack = getattr(local, "stack", None)
            if not stack:
                return
            t0 = stack.pop()
            if not stack:
                dt = time.perf_counter() - t0
                prog.kernels.append((name(ev), dt))
                prog.seconds += dt
                if log is not None:
                    log(
                        f"compiled {name(ev)} in {dt:.1f} s ({len(prog.kernels)} kernels, "
                        f"{time.perf_counter() - t_start:.1f} s so far)"
                    )

    listener = _Listener()
    event.register("numba:compile", listener)
    try:
        yield prog
    finally:
        event.unregister("numba:compile", listener)
