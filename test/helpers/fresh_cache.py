"""Code run in a fresh Python process on an empty numba cache, with what numba compiled or
loaded for it: the tests that a path compiles nothing (a node's frames while its kernels
compile in the background must never wait for a compile)."""

import json
import os
import subprocess
import sys

from .paths import ROOT

# runs the code (argv[1]; ARGS: the rest) inside compile_progress (numba's compile events),
# then lists every dispatcher of the package that holds a compiled version (compiled or loaded
# from the cache), and prints the code's ``result`` with both as the last line
_DRIVER = """
import json, sys
from rs_localizer.runtime.jit_cache import compile_progress
scope = {"__name__": "__fresh__", "ARGS": sys.argv[2:]}
with compile_progress() as prog:
    exec(sys.argv[1], scope)
used = sorted(
    f"{m}.{k}"
    for m, mod in list(sys.modules.items())
    if m.startswith("rs_localizer")
    for k, v in list(vars(mod).items())
    if hasattr(v, "overloads") and hasattr(v, "py_func") and len(v.overloads)
)
print(json.dumps({"result": scope.get("result"), "kernels": [k for k, _ in prog.kernels],
                  "used": used}))
"""


def run_on_empty_cache(code: str, cache_dir, *args, timeout: float = 120) -> dict:
    """Run ``code`` (Python source; ``ARGS`` holds ``args`` as strings; it leaves what it
    found in a JSON-serializable ``result``) in a new interpreter with ``NUMBA_CACHE_DIR`` =
    ``cache_dir`` (empty) and this checkout first on the path. Returns ``{"result": ...,
    "kernels": [names numba compiled], "used": [the package's dispatchers holding a compiled
    version]}``. Raises AssertionError (with the process's stderr) when it fails."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "PYTHONPATH": str(ROOT)}
    r = subprocess.run(
        [sys.executable, "-c", _DRIVER, code, *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=timeout,
    )
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])
