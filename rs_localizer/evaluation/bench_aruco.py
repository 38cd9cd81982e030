"""Marker video through the ArUco front end, windowed vs full-frame detection: ``python -m
rs_localizer.evaluation.bench_aruco``.

Renders a hand-held (``shake``) rolling-shutter video of ``aruco_room`` (``--scene``: another
built-in marker scene, e.g. the single board ``aruco_board``) at 30 Hz for each
camera preset (``vga`` 640x480, ``hd`` 1280x720; 30 ms readout, sensor noise) and localizes
it frame by frame with :class:`~rs_localizer.frontends.aruco.ArucoFrontend` and the
``r6p_1lin`` estimator, once with full-frame detection on every frame and once with windowed
detection (``windowed=True``), the two runs interleaved frame by frame on the same images.

Prints per preset and mode: the detection time per frame (median and p90, ms), frames
detected in windows / over the full frame, correspondences per frame, rotation and position
errors against the renderer's truth (median over the frames posed) and the frames posed; and
the largest difference between a marker corner found in a window and the same corner found
over the full frame (px). ``--threshold-steps`` adds full-frame detection time and corner
error against the renderer's truth per OpenCV ``adaptiveThreshWinSizeStep``. One OpenCV / BLAS
thread.

    python -m rs_localizer.evaluation.bench_aruco [--frames 90] [--margin 16] [--every 10]
        [--scene aruco_room] [--presets vga,hd] [--threshold-steps 10,20]
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from ..estimation.estimate import estimate_rs_pose
from ..frontends.aruco import ArucoFrontend
from ..geometry import rotation_angle_deg
from ..sim.render.motion import make_motion
from ..sim.render.renderer import NoiseModel, Renderer, camera_preset
from ..sim.render.scene import load_scene

__all__ = ["main", "render_video", "run_interleaved", "threshold_steps"]

FPS = 30.0


def render_video(preset: str, frames: int, seed: int = 0, scene: str = "aruco_room") -> tuple:
    """``(scene, camera, rendered frames)``: ``frames`` frames at 30 Hz of a ``shake`` video of
    the built-in scene ``scene`` with camera preset ``preset``."""
    scene = load_scene(scene)
    camera = camera_preset(preset)
    motion = make_motion("shake", scene, duration=frames / FPS + 0.1)
    r = Renderer(scene, camera, noise=NoiseModel())
    return scene, camera, [r.render(motion, k / FPS, rng=seed + k) for k in range(frames)]


def run_interleaved(scene, camera, frames: list, **windowed_kw) -> dict:
    """Localize ``frames`` with a full-frame and a windowed front end, frame by frame in turn.
    Returns ``{"full": ..., "windowed": ...}`` of per-frame arrays ``detect`` (s), ``n``
    (correspondences), ``rot`` (deg), ``pos`` (m) (NaN: not posed), ``win`` (bool: searched
    in windows), plus ``corner_diff``
    (px): the largest distance between a corner found by both on the same frame, and
    ``summary`` (the windowed front end's :meth:`~ArucoFrontend.summary`)."""
    fes = {
        "full": ArucoFrontend.from_scene(scene),
        "windowed": ArucoFrontend.from_scene(scene, windowed=True, **windowed_kw),
    }
    out = {m: {k: [] for k in ("detect", "n", "rot", "pos", "win")} for m in fes}
    diff = 0.0
    for f in frames:
        stamp = int(round(f.t_first * 1e9))
        got = {}
        for mode, fe in fes.items():
            t0 = time.perf_counter()
            c = fe.process(f.image, camera, encoding="rgb8", stamp_ns=stamp)
            out[mode]["detect"].append(time.perf_counter() - t0)
            est = estimate_rs_pose(c.pixels, c.points, camera, "r6p_1lin") if len(c) >= 6 else None
            fe.observe(stamp, None, est)
            ok = est is not None and est.success
            out[mode]["n"].append(len(c))
            out[mode]["win"].append(fe.last_kind == "windowed")
            out[mode]["rot"].append(
                rotation_angle_deg(est.orientation, f.orientation) if ok else np.nan
            )
            out[mode]["pos"].append(
                float(np.linalg.norm(est.position - f.position)) if ok else np.nan
            )
            got[mode] = dict(zip(c.ids.tolist(), c.pixels, strict=True))
        common = got["full"].keys() & got["windowed"].keys()
        if common:
            d = max(float(np.linalg.norm(got["full"][i] - got["windowed"][i])) for i in common)
            diff = max(diff, d)
    res = {m: {k: np.array(v) for k, v in o.items()} for m, o in out.items()}
    res["corner_diff"] = diff
    res["summary"] = fes["windowed"].summary()
    return res


def threshold_steps(scene, camera, frames: list, steps: list) -> dict:
    """Full-frame detection of ``frames`` with OpenCV's ``adaptiveThreshWinSizeStep`` set to
    each of ``steps`` (thresholding windows 3..23 px; 10: 3, 13, 23 - the default; 20: 3, 23),
    interleaved frame by frame. Returns ``{step: (detect times (F,) s, corner errors (N,) px
    against the exact RS projection of the mapped corners, corners found)}``."""
    from ..frontends import cv_compat
    from ..maps import marker_dictionary

    motion = make_motion("shake", scene, duration=len(frames) / FPS + 0.1)
    r = Renderer(scene, camera, noise=NoiseModel())
    fes = {}
    for step in steps:
        fe = ArucoFrontend.from_scene(scene)
        fe.params.adaptiveThreshWinSizeStep = int(step)
        fe.detector = cv_compat.MarkerDetector(marker_dictionary(scene.dictionary), fe.params)
        fes[step] = fe
    out = {step: ([], [], 0) for step in steps}
    for k, f in enumerate(frames):
        for step, fe in fes.items():
            t0 = time.perf_counter()
            c = fe.process(f.image, camera)
            dt = time.perf_counter() - t0
            gt, _ = r.project(c.points, motion, k / FPS, occlusion=False)
            ts, es, n = out[step]
            ts.append(dt)
            es.append(np.linalg.norm(c.pixels - gt, axis=1))
            out[step] = (ts, es, n + len(c))
    return {s_: (np.array(t), np.concatenate(e), n) for s_, (t, e, n) in out.items()}


def main(argv: list | None = None) -> int:
    """Run the benchmark (see the module doc). Returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=90, help="frames per video (30 Hz)")
    ap.add_argument("--margin", type=float, default=16.0, help="window margin (px)")
    ap.add_argument("--every", type=int, default=10, help="full frame every N frames")
    ap.add_argument("--scene", default="aruco_room", help="built-in marker scene")
    ap.add_argument(
        "--threshold-steps",
        default="",
        help="also compare full-frame detection with these adaptiveThreshWinSizeStep values "
        "(comma-separated, e.g. 10,20)",
    )
    ap.add_argument("--presets", default="vga,hd", help="camera presets, comma-separated")
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    print(f"load: {os.getloadavg()[0]:.2f} (1 min average)")
    for preset in a.presets.split(","):
        scene, camera, frames = render_video(preset, a.frames, scene=a.scene)
        res = run_interleaved(
            scene, camera, frames, window_margin_px=a.margin, full_frame_every=a.every
        )
        print(f"{preset} {camera.width}x{camera.height}, {len(frames)} frames")
        for mode in ("full", "windowed"):
            r = res[mode]
            ok = np.isfinite(r["rot"])
            w = r["win"]
            tw = f"{np.median(r['detect'][w]) * 1e3:5.1f}" if w.any() else "    -"
            print(
                f"  {mode:9s} detect ms median {np.median(r['detect']) * 1e3:5.1f} "
                f"p90 {np.percentile(r['detect'], 90) * 1e3:5.1f} "
                f"(windowed frames {tw})  corr/frame {np.mean(r['n']):5.1f}  "
                f"rot err {np.nanmedian(r['rot']):.4f} deg  "
                f"pos err {np.nanmedian(r['pos']) * 1e3:.2f} mm  posed {ok.sum()}/{len(ok)}"
            )
        print(
            f"  windowed frames: {res['summary']}; largest corner difference to full frame "
            f"{res['corner_diff']:.4f} px"
        )
        if a.threshold_steps:
            steps = [int(v) for v in a.threshold_steps.split(",")]
            for step, (t, e, n) in threshold_steps(scene, camera, frames, steps).items():
                print(
                    f"  full frame, adaptiveThreshWinSizeStep {step:3d}: detect ms median "
                    f"{np.median(t) * 1e3:5.1f}  corners/frame {n / len(frames):5.1f}  corner err "
                    f"median {np.median(e):.3f} p95 {np.percentile(e, 95):.3f} px"
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
