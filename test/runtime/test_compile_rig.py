"""``rs-localizer compile --params-file RIG.yaml`` compiles the rig's kernels too: after it, a
rig replay (the rig node's pipeline) adds no signature to any numba dispatcher of the package,
while a compile without the rig leaves the rig estimator's kernels (its compiled search
batch, its residuals) uncompiled. Run in a fresh process, so that no earlier test has loaded
them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rosbags")

ROOT = Path(__file__).resolve().parents[2]

_SCRIPT = r"""
import json, sys
from numba.core.registry import CPUDispatcher

from rs_localizer.cli.compile import compile_targets
from rs_localizer.runtime.warmup import compile_kernels


def signatures():
    out = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith("rs_localizer"):
            continue
        for attr, obj in list(vars(mod).items()):
            if isinstance(obj, CPUDispatcher):
                out[f"{name}.{attr}"] = sorted(str(s) for s in obj.signatures)
    return out


bag, params = sys.argv[1], sys.argv[2]
what = compile_targets([params])
assert what["rig"] is not None
kw = dict(tracking=what["tracking"], jobs=1, options=what["options"], gyro=what["gyro"],
          log=lambda m: None)
compile_kernels(what["solvers"], rig=None, **kw)
without = signatures()
compile_kernels(what["solvers"], rig=what["rig"], **kw)
with_rig = signatures()
from rs_localizer.ros.bags.replay import replay

res = replay(bag, progress=None)
after = signatures()
print(json.dumps({"without": without, "with_rig": with_rig, "after": after,
                  "solved": res.solved}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("gyro", [False, True])
def test_compile_with_rig_parameters_leaves_nothing_for_the_rig_to_compile(tmp_path, gyro):
    from rs_localizer.cli import main

    bag = tmp_path / "rig"
    argv = ["make-bag", str(bag), "--rig", "2" if gyro else "3", "--frames", "8",
            "--points", "100", "--quiet"] + (["--imu-rate", "400"] if gyro else [])  # fmt: skip
    assert main(argv) == 0
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", _SCRIPT, str(bag), str(bag / "rig_params.yaml")],
        capture_output=True, text=True, env=env, timeout=1200, check=False,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["solved"] == 8
    search = "rs_localizer.estimation.rig_batch.search_batch"
    residuals = "rs_localizer.estimation.scoring.best_mounted"
    for k in (search, residuals):  # (the rig's kernels: not compiled by the camera's warm-up)
        assert not r["without"].get(k) and r["with_rig"].get(k), k
    new = {
        k: sorted(set(v) - set(r["with_rig"].get(k, [])))
        for k, v in r["after"].items()
        if set(v) - set(r["with_rig"].get(k, []))
    }
    assert not new, f"compiled by the rig replay after compile: {new}"
