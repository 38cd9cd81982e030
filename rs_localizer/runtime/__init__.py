"""The process around the estimator: where numba caches the compiled kernels, compiling them
(the warm-up, ``rs-localizer compile``), and which implementation of the estimator is ready.

* :mod:`.jit_cache`: numba's cache directory (chosen before anything imports numba: the
  package's ``__init__`` calls :func:`.jit_cache.configure`), compile progress, the stand-in
  where numba is missing;
* :mod:`.warmup`: the JIT warm-up on synthetic problems, ``rs-localizer compile``
  (:func:`.warmup.compile_kernels`), with a second compiling process
  (:mod:`.second_process`);
* :mod:`.background`: a node's start on a cold cache (frames solved at once by the NumPy
  implementation while :mod:`.background_process` compiles the kernels), and
  :func:`.background.ready_implementation`, the implementation the frames take now.

This package imports nothing at its top (``rs_localizer/__init__.py`` imports
:mod:`.jit_cache` before numba).
"""
