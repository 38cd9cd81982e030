"""No frame waits on the compiler: after the node's warm-up (as the node runs it, for its
configuration), replaying real bags through the node's frame pipeline (cold and tracked
frames, the twist filter and its smoother, correspondences, keypoints and image mode) uses no
numba kernel signature the warm-up did not make. On a cold cache any new signature would be
compiled inside a frame.

The check runs in a fresh process: signatures loaded by earlier tests of this session would
otherwise hide what the warm-up misses.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = r"""
import json, sys
from numba.core.registry import CPUDispatcher
from rs_localizer.ros.config import build_config
from rs_localizer.ros.pipeline import log_warm_up
from rs_localizer.ros.bags.replay import replay, replay_parameters


def signatures():
    out = {}
    for name, mod in list(sys.modules.items()):
        if name.startswith("rs_localizer") and mod is not None:
            for obj in list(vars(mod).values()):
                if isinstance(obj, CPUDispatcher):
                    key = f"{obj.py_func.__module__}.{obj.py_func.__qualname__}"
                    out[key] = sorted(map(str, obj.signatures))
    return out


class Log:
    def info(self, m):
        print(m, file=sys.stderr)

    warning = info


runs = json.loads(sys.argv[1])  # [(bag, source, parameter files, parameters)]
before = None
solved = {}
for bag, source, files, params in runs:
    if before is None:  # the node's warm-up, for the configuration of the first run
        values, _ = replay_parameters(bag, files, params, source)
        cfg = build_config(values)
        assert cfg.tracking is not None, "the default node tracks"
        log_warm_up(cfg.solver, cfg.options, cfg.tracking, Log())
        before = signatures()
    res = replay(bag, params_files=files, params=params, source=source, progress=None)
    solved[bag] = sum(bool(r["success"]) for r in res.rows), len(res.rows)
after = signatures()
new = {k: sorted(set(v) - set(before.get(k, []))) for k, v in after.items()}
print(json.dumps({"new": {k: v for k, v in new.items() if v}, "solved": solved}))
"""


def test_node_warm_up_covers_every_kernel_of_real_frames():
    pytest.importorskip("rosbags")
    from rs_localizer.ros.bags.bag_io import read_bag_info

    config = str(ROOT / "config" / "rs_localizer.yaml")
    images = ROOT / "data" / "sample_images"
    rs = read_bag_info(images)["rs"]
    image_params = {  # (configured as the demo configures the node on this bag)
        "frontend": "aruco",
        "frontend_map": str((images / "markers.yaml").resolve()),
        "rs.line_delay": float(rs["line_delay"]),
        "rs.readout_time": 0.0,
        "rs.stamp_row": float(rs["stamp_row"]),
    }
    runs = [
        (str(ROOT / "data" / "sample"), "correspondences", [config], {}),
        (
            str(images),
            "image",
            [config, str(ROOT / "config" / "rs_localizer_images.yaml")],
            image_params,
        ),
        (str(ROOT / "test" / "data" / "keypoints"), "keypoints", [config], {}),
    ]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, json.dumps(runs)],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    for bag, (solved, frames) in res["solved"].items():
        assert frames > 0 and solved == frames, (bag, solved, frames)
    assert not res["new"], f"kernels first used by a real frame, after the warm-up: {res['new']}"


def test_late_warm_up_makes_the_signatures_the_estimator_uses():
    """The parallel warm-up's shares (the split of the cold RANSAC batch's callees, then
    warm_late: the refinement, the MAP step and the twist filter) compile with exactly the
    argument types the estimator and the tracker pass them: after the node's warm-up they add
    no signature (a different one would be compiled for nothing, and the real one again
    inside the first frames). Each kernel is compiled once: no literal-argument duplicates."""
    import sys

    from numba.core.registry import CPUDispatcher

    from rs_localizer.estimation import prior, refine, sampling, scoring
    from rs_localizer.runtime.warmup import fused_cached, split_batch, warm_late, warm_up
    from rs_localizer.tracking import fusion
    from rs_localizer.tracking.tracker import TrackerOptions

    warm_up("r6p_1lin", tracking=TrackerOptions())
    solvers = [
        sys.modules[f"rs_localizer.solvers.{m}"] for m in ("lambda_twist", "r6p_1lin", "r5p_w")
    ]
    kernels = {  # "module.function" -> dispatcher
        f"{mod.__name__.rsplit('.', 1)[1]}.{name}": obj
        for mod in (refine, prior, fusion, scoring, sampling, *solvers)
        for name, obj in vars(mod).items()
        if isinstance(obj, CPUDispatcher)
    }
    before = {name: set(k.signatures) for name, k in kernels.items()}
    for name in (
        "refine._lm_refine",
        "refine._posterior_step",
        "prior._conflict",
        "fusion._update_window",
        "fusion._predict_row",
    ):
        assert before[name], name  # (the node's warm-up used it)
    # the batch's callees are compiled inside it (or it is loaded whole from the cache): their
    # signatures are in numba's cache index
    split = (
        "scoring.msac_scores",
        "sampling.p3p_mounted",
        "sampling.p3p_mounted_into",
        "r6p_1lin._kernel",
        "r5p_w._kernel",
    )

    def cached(name):
        return {key[0] for key in kernels[name]._cache._cache_file._load_index()}

    in_cache = {name: cached(name) for name in split}
    for name in split:
        assert in_cache[name], name
    split_batch("r6p_1lin", first=True)
    split_batch("r6p_1lin", first=False)
    warm_late("r6p_1lin", tracking=TrackerOptions())
    assert {name: set(k.signatures) for name, k in kernels.items() if name not in split} == {
        name: sigs for name, sigs in before.items() if name not in split
    }
    assert {name: cached(name) for name in split} == in_cache
    assert fused_cached("r6p_1lin")  # (the tests' cache is writable)


def test_second_compiling_process_uses_this_package(tmp_path, monkeypatch):
    """The helper process imports the package this process runs (not a copy in the working
    directory), finds the kernels in the same cache (the cold batch included: it goes on to
    the tracker's videos and ends) and reports what it compiled."""
    from rs_localizer.runtime.warmup import _SecondProcess, warm_late
    from rs_localizer.tracking.tracker import TrackerOptions

    warm_late("r6p_1lin", tracking=TrackerOptions())  # (cached: the helper only loads)
    decoy = tmp_path / "rs_localizer"
    decoy.mkdir()
    (decoy / "__init__.py").write_text("raise ImportError('the working directory copy')\n")
    monkeypatch.chdir(tmp_path)
    lines = []
    helper = _SecondProcess(["r6p_1lin"], True, lines.append)
    assert helper._proc.wait(timeout=300) == 0, lines  # (it ends on its own: all cached)
    helper.stop()
    assert helper.kernels == [], lines  # everything loaded from the cache


def test_fused_kernels_not_cached_in_an_empty_cache(tmp_path):
    """fused_cached reads numba's index: a copy of the package that was never compiled, with an
    empty cache directory, holds nothing."""
    import shutil

    shutil.copytree(
        ROOT / "rs_localizer",
        tmp_path / "pkg" / "rs_localizer",
        ignore=shutil.ignore_patterns("__pycache__"),
    )
    code = (
        f"import rs_localizer; assert rs_localizer.__file__.startswith({str(tmp_path)!r}); "
        "from rs_localizer.runtime.warmup import fused_cached; "
        "print(fused_cached('r6p_1lin'), fused_cached('r6p'))"
    )
    env = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
        "PYTHONPATH": str(tmp_path / "pkg"),
    }
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "True"]  # (r6p has no fused kernels)
