"""The offline commands that solve frames on the compiled kernels (``replay``,
``calibrate-rig``, ``calibrate-readout``) say once, before the first frame, that the kernels
compile now when numba's cache does not hold them (:func:`.background.cold_compile_note`), and
nothing when it does."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from rs_localizer.runtime import background, warmup
from rs_localizer.runtime.background import CameraKernels, RigKernels, cold_compile_note

#: the note's words (its first ones, and the command that compiles ahead)
NOTE = "before the first frame: numba compiles them once"
AHEAD = "`rs-localizer compile [--params-file FILE]`"


def _cache(monkeypatch, cached: bool) -> None:
    """Fake numba's cache check (the node's, :meth:`CameraKernels.cached` /
    :meth:`RigKernels.cached`) both ways; the process compiles."""
    monkeypatch.setattr(warmup, "fused_cached", lambda solver, anchored=True: cached)
    monkeypatch.setattr(warmup, "rig_cached", lambda: cached)
    monkeypatch.setattr(background, "compiled_ready", lambda: True)


@pytest.mark.parametrize("cached", [False, True])
def test_the_note_follows_the_cache_check(monkeypatch, cached):
    _cache(monkeypatch, cached)
    rig = RigKernels(SimpleNamespace(single_camera=False))  # (a rig of several cameras)
    for kernels, what in ((CameraKernels("r6p_1lin"), "kernels"), (rig, "the rig's kernels")):
        out = io.StringIO()
        assert cold_compile_note(kernels, out) is (not cached)
        text = out.getvalue()
        if cached:
            assert text == ""
        else:
            assert text.startswith(f"compiling {what} {NOTE}") and text.count("\n") == 1
            assert AHEAD in text and background.cache_state()["dir"] in text


def test_nothing_is_said_where_the_frames_take_the_uncompiled_path(monkeypatch):
    """RS_LOCALIZER_COMPILED=0 (or numba unusable): a NumPy solver's frames compile nothing;
    a solver without a NumPy implementation still compiles."""
    _cache(monkeypatch, False)
    monkeypatch.setattr(background, "compiled_ready", lambda: False)
    out = io.StringIO()
    assert not cold_compile_note(CameraKernels("r6p_1lin"), out) and out.getvalue() == ""
    from rs_localizer.solvers.registry import SOLVER_NAMES

    no_numpy = next(s for s in SOLVER_NAMES if s not in background.NUMPY_SOLVERS)
    assert cold_compile_note(CameraKernels(no_numpy), out)


def test_an_empty_numba_cache_is_not_cached(tmp_path):
    """The check itself, on a real empty cache directory (no kernel compiled: it reads the
    cache index only)."""
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(root)}
    code = (
        "from types import SimpleNamespace as S\n"
        "from rs_localizer.runtime.background import CameraKernels, RigKernels\n"
        "print(CameraKernels('r6p_1lin').cached(), RigKernels(S(single_camera=False)).cached())"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    pytest.importorskip("rosbags")
    from rs_localizer.cli import main

    root = tmp_path_factory.mktemp("cold")
    cam, rig = root / "cam", root / "rig"
    assert main(["make-bag", str(cam), "--frames", "4", "--points", "120", "--quiet"]) == 0
    assert main(["make-bag", str(rig), "--rig", "2", "--frames", "4", "--points", "120",
                 "--quiet"]) == 0  # fmt: skip
    return cam, rig


@pytest.mark.parametrize("cached", [False, True])
def test_replay_and_the_calibrations_say_it_once_on_stderr(bags, monkeypatch, capsys, cached):
    from rs_localizer.cli import main

    _cache(monkeypatch, cached)
    cam, rig = bags
    for argv, what in (
        (["replay", str(cam), "--json", "--quiet"], "kernels"),
        (["replay", str(rig), "--json", "--quiet"], "the rig's kernels"),
        (["calibrate-rig", str(rig), "--json", "--min-inliers", "6"], "kernels"),
        (["calibrate-readout", str(cam)], "kernels"),
    ):
        capsys.readouterr()
        main(argv)
        printed = capsys.readouterr()
        assert NOTE not in printed.out
        assert printed.err.count(NOTE) == (0 if cached else 1), (argv, printed.err)
        if not cached:  # (said before anything of the frames)
            assert printed.err.startswith(f"compiling {what} {NOTE}"), printed.err
