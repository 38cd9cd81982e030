"""Marker video through the ArUco front end, windowed vs full-frame detection: ``python -m
benchmarks.bench_aruco``.

Renders a hand-held (``shake``) rolling-shutter video of ``aruco_room`` (``--scene``: another
built-in marker scene, e.g. the single board ``aruco_board``) at 30 Hz for each
camera preset (``vga`` 640x480, ``hd`` 1280x720; 30 ms readout, sensor noise) and localizes
it frame by frame with :class:`~rs_localizer.frontends.aruco.ArucoFrontend` and the
``r6p_1lin`` estimator, once with full-frame detection on every frame and once with windowed
detection (``windowed=True``), the two runs interleaved frame by frame on the same images.

Prints per preset and mode: the detection time per frame (median and p90, ms), frames
detected in windows / over the full frame, correspondences per frame, rotation and position
errors against the renderer's truth (median over the frames posed) and the frames posed, the
detection's CPU time (the thread's) and the corners found over the video; and
the largest difference between a marker corner found in a window and the same corner found
over the full frame (px). ``--threshold-steps`` adds full-frame detection time and corner
error against the renderer's truth per OpenCV ``adaptiveThreshWinSizeStep``. One OpenCV / BLAS
thread.

    python -m benchmarks.bench_aruco [--frames 90] [--margin 16] [--every 10]
        [--scene aruco_room] [--presets vga,hd] [--threshold-steps 10,20]
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from rs_localizer.frontends.aruco import ArucoFrontend
from rs_localizer.sim.aruco_video import FPS, render_video, run_interleaved
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import NoiseModel, Renderer

__all__ = ["main", "threshold_steps"]


def threshold_steps(scene, camera, frames: list, steps: list) -> dict:
    """Full-frame detection of ``frames`` with OpenCV's ``adaptiveThreshWinSizeStep`` set to
    each of ``steps`` (thresholding windows 3..23 px; 10: 3, 13, 23 - OpenCV's default; 20: 3,
    23 - the front end's), the front end's other settings, interleaved frame by frame.
    Returns ``{step: (detect times (F,) s, corner errors (N,) px
    against the exact RS projection of the mapped corners, corners found)}``."""
    from rs_localizer.frontends.marker_detection import OpenCVDetector

    motion = make_motion("shake", scene, duration=len(frames) / FPS + 0.1)
    r = Renderer(scene, camera, noise=NoiseModel())
    fes = {}
    for step in steps:
        fe = ArucoFrontend.from_scene(scene)
        fe.params.adaptiveThreshWinSizeStep = int(step)
        fe.detector = OpenCVDetector(scene.dictionary, fe.params)
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
            es.append(np.linalg.norm(c.points2d - gt, axis=1))
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
                f"(windowed frames {tw})  CPU ms median {np.median(r['cpu']) * 1e3:5.1f}  "
                f"corners {int(r['n'].sum())} ({np.mean(r['n']):5.1f}/frame)  "
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
