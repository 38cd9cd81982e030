"""Adding a front end, a solver or a lens model is adding it to its one table: what the camera
node and the rig node accept is read from ``frontends/registry.py``, ``solvers/registry.py``
and ``camera.DISTORTION_MODELS``, and no rig-only module names a front end or a solver
(docs/architecture.md's recipes). No DDS: the configuration and map loading both nodes call."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from rs_localizer.camera import DISTORTION_MODELS
from rs_localizer.frames import Mounting
from rs_localizer.frontends import registry
from rs_localizer.frontends.shared import MapCache
from rs_localizer.ros import config as C
from rs_localizer.ros import params as P
from rs_localizer.solvers.registry import SOLVERS
from rs_localizer.tracking.video import Localizer, LocalizerSettings

PKG = Path(__file__).resolve().parents[2] / "rs_localizer"
#: the modules a single camera never runs (tools/architecture_report.py's RIG_ONLY)
RIG_ONLY = (
    "estimation/rig.py",
    "tracking/rig.py",
    "ros/rig_node.py",
    "calibration/mountings.py",
    "cli/calibrate_rig.py",
)

#: names a rig-only module may use for a concept of its own: (module, name) -> what it is
OWN_NAMES: dict[tuple[str, str], str] = {}


class _Dots:
    """A front end of a kind the package does not have: it hands out the map's points at the
    pixels it was built with (what it was given is kept to be checked)."""

    def __init__(self, loaded, scale=1.0):
        self.points, self.scale = loaded, scale

    def process(self, image, camera, encoding="mono8", prediction=None):
        raise AssertionError("not run here")


def test_a_front_end_added_to_the_registry_is_accepted_by_both_nodes(monkeypatch, tmp_path):
    pts = np.arange(12.0).reshape(4, 3)
    path = tmp_path / "dots.npy"
    np.save(path, pts)
    kind = registry.FrontendKind(
        load=lambda p: np.load(p),
        make=_Dots,
        make_video=_Dots,
        map_file="dots .npy",
        options=lambda values: {"scale": float(values["ransac.threshold_px"])},
    )
    values = {**P.default_values(), "frontend": "dots", "frontend_map": str(path)}
    with pytest.raises(C.ConfigError, match="unknown frontend 'dots'"):
        C.build_config(values)
    monkeypatch.setitem(registry.FRONTEND_KINDS, "dots", kind)
    cfg = C.build_config({**values, "ransac.threshold_px": 3.5}).camera
    assert cfg.frontend_kind == "dots" and cfg.frontend_options == {"scale": 3.5}
    with pytest.raises(C.ConfigError, match=r"needs frontend_map \(dots \.npy\)"):
        C.build_config({**values, "frontend_map": ""})
    # the camera node's and the rig node's front end: load_maps(camera).frontend
    cache = MapCache()
    fe = [cache.load_maps("", cfg.frontend_kind, cfg.frontend_map, cfg.frontend_options)]
    fe.append(cache.load_maps("", cfg.frontend_kind, cfg.frontend_map, cfg.frontend_options))
    assert all(isinstance(f.frontend, _Dots) and f.frontend.scale == 3.5 for f in fe)
    assert np.array_equal(fe[0].frontend.points, pts) and cache.loads == 1  # (one map)
    assert fe[0].frontend is not fe[1].frontend  # (an object per camera)
    rig = Localizer(
        LocalizerSettings(
            {n: Mounting.from_pose(np.eye(3), np.zeros(3) + i) for i, n in enumerate("ab")}
        )
    )
    for n, f in zip("ab", fe, strict=True):
        rig.set_frontend(n, f.frontend, cfg.frontend_kind)
        assert rig.frontend(n) is not None


def test_solvers_and_lens_models_are_the_tables_entries():
    values = P.default_values()
    for name in SOLVERS:
        assert C.build_config({**values, "solver": name}).solver == name
    with pytest.raises(C.ConfigError, match="unknown solver"):
        C.build_config({**values, "solver": "r7p"})
    described = P.PARAMETERS["camera.distortion_model"].description
    assert set(re.findall(r"[a-z_]+", described.split(":", 1)[1])) - {"or"} == set(
        DISTORTION_MODELS
    )
    for model in DISTORTION_MODELS:
        n = max(DISTORTION_MODELS[model])
        cam = C.build_config(
            {
                **values,
                "camera.fx": 500.0,
                "camera.fy": 500.0,
                "camera.cx": 320.0,
                "camera.cy": 240.0,
                "camera.width": 640,
                "camera.height": 480,
                "camera.distortion_model": model,
                "camera.d": [0.01] * n or [0.0],
            }
        ).camera.fallback
        assert cam.distortion_model == model


@pytest.mark.parametrize("module", RIG_ONLY)
def test_no_rig_only_module_names_a_front_end_or_a_solver(module):
    text = (PKG / module).read_text()
    named = [
        n
        for n in (*registry.FRONTENDS, *SOLVERS)
        if re.search(rf"[\"']{n}[\"']", text) and (module, n) not in OWN_NAMES
    ]
    assert named == [], f"{module} names {named}: dispatch on the registry instead"
