"""A rendered hand-held marker video with its truth (:func:`render_video`), and the ArUco
front end on it with windowed and full-frame detection side by side (:func:`run_interleaved`):
the windowed detection's tests and ``python -m benchmarks.bench_aruco``."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..camera import CameraModel
from ..estimation.estimate import estimate_rs_pose
from ..frontends import ArucoFrontend
from ..geometry import rotation_angle_deg
from ..tracking.tracker import CarriedPrediction
from .render.motion import make_motion
from .render.renderer import NoiseModel, RenderedFrame, Renderer, camera_preset
from .render.scene import Scene, load_scene

__all__ = ["FPS", "render_video", "run_interleaved"]


#: Hz: the frame rate of :func:`render_video`
FPS = 30.0


def render_video(preset: str, frames: int, seed: int = 0, scene: str = "aruco_room") -> tuple:
    """``(scene, camera, rendered frames)``: ``frames`` frames at 30 Hz of a ``shake`` video of
    the built-in scene ``scene`` with camera preset ``preset``."""
    scene = load_scene(scene)
    camera = camera_preset(preset)
    motion = make_motion("shake", scene, duration=frames / FPS + 0.1)
    r = Renderer(scene, camera, noise=NoiseModel())
    return scene, camera, [r.render(motion, k / FPS, rng=seed + k) for k in range(frames)]


def run_interleaved(
    scene: Scene, camera: CameraModel, frames: list[RenderedFrame], **windowed_kw: Any
) -> dict:
    """Localize ``frames`` (:func:`render_video`) with a full-frame and a windowed
    :class:`~rs_localizer.frontends.aruco.ArucoFrontend` of ``scene`` (``windowed_kw``: its
    window options) and ``r6p_1lin``, frame by frame in turn.
    Returns ``{"full": ..., "windowed": ...}`` of per-frame arrays ``detect`` (s), ``cpu``
    (s, the thread's CPU time of the same), ``n``
    (correspondences), ``rot`` (deg), ``pos`` (m) (NaN: not posed), ``win`` (bool: searched
    in windows; each front end searches from the last solved frame carried to the frame's
    stamp, :class:`~rs_localizer.tracking.tracker.CarriedPrediction`), plus ``corner_diff``
    (px): the largest distance between a corner found by both on the same frame, and
    ``summary`` (the windowed front end's :meth:`~ArucoFrontend.summary`)."""
    fes = {
        "full": ArucoFrontend.from_scene(scene),
        "windowed": ArucoFrontend.from_scene(scene, windowed=True, **windowed_kw),
    }
    out = {m: {k: [] for k in ("detect", "cpu", "n", "rot", "pos", "win")} for m in fes}
    carry = {m: CarriedPrediction() for m in fes}
    diff = 0.0
    for f in frames:
        stamp = int(round(f.t_first * 1e9))
        got = {}
        for mode, fe in fes.items():
            t0, c0 = time.perf_counter(), time.thread_time()
            pred = carry[mode].predict(stamp, camera)
            c = fe.process(f.image, camera, encoding="rgb8", prediction=pred)
            out[mode]["detect"].append(time.perf_counter() - t0)
            out[mode]["cpu"].append(time.thread_time() - c0)
            est = (
                estimate_rs_pose(c.points2d, c.points, camera, "r6p_1lin") if len(c) >= 6 else None
            )
            fe.observe(stamp, None, est)
            carry[mode].update(stamp, est)
            ok = est is not None and est.success
            out[mode]["n"].append(len(c))
            out[mode]["win"].append(fe.last_kind == "windowed")
            out[mode]["rot"].append(
                rotation_angle_deg(est.pose.orientation, f.orientation) if ok else np.nan
            )
            out[mode]["pos"].append(
                float(np.linalg.norm(est.pose.position - f.position)) if ok else np.nan
            )
            got[mode] = dict(zip(c.ids.tolist(), c.points2d, strict=True))
        common = got["full"].keys() & got["windowed"].keys()
        if common:
            d = max(float(np.linalg.norm(got["full"][i] - got["windowed"][i])) for i in common)
            diff = max(diff, d)
    res = {m: {k: np.array(v) for k, v in o.items()} for m, o in out.items()}
    res["corner_diff"] = diff
    res["summary"] = fes["windowed"].summary()
    return res
