"""The one decorator of the package's numba kernels, :func:`kernel`, and the options every
kernel shares.

- ``cache=True``: the machine code is kept on disk (where: :mod:`rs_localizer.runtime.jit_cache`),
  so that a process loads it instead of compiling it again.
- ``nogil=True``: a kernel called from Python releases the GIL while it runs. The kernels
  compile in nopython mode and take and return NumPy arrays, numbers and tuples only (no
  Python object, no callback into Python), so nothing inside needs the GIL; meanwhile the
  node's executor thread keeps taking frame messages while its worker thread is inside a
  kernel (``test/runtime/test_kernels_release_the_gil.py``).
- The cached machine code of a kernel also holds the kernels it calls (numba compiles them
  into it), but numba checks only the kernel's own source file (its modification time and
  size) before it loads the cached code. :func:`kernel` therefore adds to that check a content
  hash of the source file of every kernel it calls, transitively (:func:`callee_files`): after
  an update that changes only a callee's file, the caller is compiled again instead of running
  the old callee's code. Files of the package that no kernel calls into (the ROS node, the
  command line) never invalidate a kernel.
"""

from __future__ import annotations

import hashlib
import threading
import types

from numba import njit

__all__ = ["callee_files", "kernel"]


def kernel(fn=None, /, **options):
    """numba's ``njit`` with ``cache=True, nogil=True`` and ``options`` (``inline``,
    ``fastmath``, ``parallel``): ``@kernel`` or ``@kernel(fastmath=FMA)``; ``kernel(fn)``
    compiles an existing function. The cache entry is valid only while the source files of
    the kernel and of every kernel it calls are unchanged (module docstring)."""
    decorate = njit(cache=True, nogil=True, **options)

    def decorate_stamped(f):
        disp = decorate(f)
        _stamp_callees(disp)
        return disp

    return decorate_stamped if fn is None else decorate_stamped(fn)


# --- the callees' files in the cache stamp ------------------------------------------------

_lock = threading.Lock()
_file_hashes: dict[str, str] = {}  # source file -> content hash, once per process
_overloads = {"n": -1, "by_id": {}}  # numba's @overload registry: id(function) -> impls


def _file_hash(path: str) -> str:
    """SHA-256 of ``path``'s bytes (computed once per process; "missing" when unreadable)."""
    h = _file_hashes.get(path)
    if h is None:
        try:
            with open(path, "rb") as f:
                h = hashlib.sha256(f.read()).hexdigest()
        except OSError:
            h = "missing"
        _file_hashes[path] = h
    return h


def _overload_impls(fn) -> list:
    """The implementation generators registered with numba's ``@overload(fn)`` (what a
    kernel calling the Python function ``fn`` compiles into itself)."""
    try:
        from numba.core.typing.templates import builtin_registry
    except ImportError:
        return []
    reg = builtin_registry.globals
    if _overloads["n"] != len(reg):  # (re)built when modules registered more overloads
        by_id: dict[int, list] = {}
        for val, typ in list(reg):
            for tmpl in getattr(typ, "templates", ()):
                impl = getattr(tmpl, "_overload_func", None)
                if impl is not None:
                    by_id.setdefault(id(val), []).append(impl)
        _overloads.update(n=len(reg), by_id=by_id)
    return _overloads["by_id"].get(id(fn), [])


def _codes(code):
    """``code`` and the code objects nested in it (inner functions, lambdas)."""
    yield code
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            yield from _codes(c)


def _referenced(py_func) -> list:
    """The objects ``py_func``'s code can reach by name: its globals named in its code (and
    nested code), their attributes named there (``module.kernel``), the values of dicts,
    lists and tuples among them, and its closure's cells."""
    names: set[str] = set()
    for c in _codes(py_func.__code__):
        names.update(c.co_names)
    glb = getattr(py_func, "__globals__", {})
    found = []
    for n in sorted(names):
        if n not in glb:
            continue
        v = glb[n]
        found.append(v)
        if isinstance(v, types.ModuleType):
            found.extend(getattr(v, a) for a in sorted(names) if a in vars(v))
    for cell in py_func.__closure__ or ():
        try:
            found.append(cell.cell_contents)
        except ValueError:  # an empty cell
            continue
    out = []
    for v in found:
        out.append(v)
        if isinstance(v, dict):
            out.extend(v.values())
        elif isinstance(v, (list, tuple)):
            out.extend(v)
    return out


def _numbas(f) -> bool:
    """Whether ``f`` is numba's own (its NumPy support, registered lazily as numba compiles:
    following it would make the stamp depend on what this process compiled before; numba's
    index checks its own version)."""
    mod = getattr(f, "__module__", None) or ""
    return mod == "numba" or mod.startswith("numba.")


def callee_files(py_func) -> dict[str, str]:
    """``{module name: source file}`` of the kernels ``py_func`` calls, transitively (also
    through numba ``@overload`` implementations it calls; numba's own code excepted),
    ``py_func``'s own file included.
    Deterministic: independent of the order modules were imported in, as long as the callees
    exist when it is called (at the kernel's first call, when it is compiled or loaded)."""
    from numba.core.dispatcher import Dispatcher

    files: dict[str, str] = {}
    seen: set[int] = set()
    todo = [py_func]
    while todo:
        f = todo.pop()
        if id(f) in seen or not isinstance(f, types.FunctionType) or _numbas(f):
            continue
        seen.add(id(f))
        path = f.__code__.co_filename
        files.setdefault(f"{f.__module__}:{path.rsplit('/', 1)[-1]}", path)
        for v in _referenced(f):
            if isinstance(v, Dispatcher):
                todo.append(v.py_func)
            elif isinstance(v, types.FunctionType):
                todo.extend(_overload_impls(v))
    return files


def _callee_stamp(py_func) -> tuple:
    """The content hashes of :func:`callee_files` but ``py_func``'s own file (numba stamps
    that one), sorted by module: ``((module:file, sha256), ...)``."""
    own = py_func.__code__.co_filename
    files = callee_files(py_func)
    return tuple(sorted((k, _file_hash(p)) for k, p in files.items() if p != own))


def _stamp_callees(disp) -> None:
    """Make ``disp``'s cache index carry, besides numba's stamp of the kernel's source file,
    :func:`_callee_stamp` (computed at the first load or save of the index, when every
    callee exists; numba then treats a changed callee file as a stale cache: it compiles the
    kernel again and overwrites the entry)."""
    cache = getattr(disp, "_cache", None)
    index = getattr(cache, "_cache_file", None)
    if (
        _CalleeStampedIndex is None
        or type(index) is not _CalleeStampedIndex.__bases__[0]
        or "_source_stamp" not in vars(index)
    ):
        return  # (no cache, or a numba whose cache we do not know: its own check only)
    stamped = _CalleeStampedIndex.__new__(_CalleeStampedIndex)
    state = dict(vars(index))
    state["_file_stamp"] = state.pop("_source_stamp")
    state["_py_func"] = disp.py_func
    state["_full_stamp"] = None
    stamped.__dict__.update(state)
    cache._cache_file = stamped


def _index_class():
    from numba.core.caching import IndexDataCacheFile

    class CalleeStampedIndex(IndexDataCacheFile):
        """numba's cache index whose source stamp is ``(numba's stamp of the kernel's file,
        the callees' files' hashes)``; see :func:`_stamp_callees`."""

        @property
        def _source_stamp(self):
            if self._full_stamp is None:
                with _lock:
                    if self._full_stamp is None:
                        self._full_stamp = (self._file_stamp, _callee_stamp(self._py_func))
            return self._full_stamp

        @_source_stamp.setter
        def _source_stamp(self, value):
            self._file_stamp, self._full_stamp = value, None

    return CalleeStampedIndex


try:
    _CalleeStampedIndex = _index_class()
except ImportError:  # numba stand-in (rs_localizer.runtime.jit_cache): no cache at all
    _CalleeStampedIndex = None
