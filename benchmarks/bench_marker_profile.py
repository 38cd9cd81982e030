"""Where a frame's marker detection time goes, and what the AprilTag library's options cost
and buy: ``python -m benchmarks.bench_marker_profile`` (from the repository root).

Renders the hand-held (``shake``) rolling-shutter video of ``apriltag_room`` that
``python -m benchmarks.bench_markers`` uses (36h11 tags on textured walls, sensor noise) and
times, frame by frame in turn and ``--repeats`` times over the video, the CPU time
(``time.process_time``; one BLAS / OpenCV thread) of each step of the marker front end's
full-frame path on one frame:

* ``to_gray``: the RGB image to grayscale (:func:`~rs_localizer.frontends.image.to_gray`);
* ``library``: the AprilTag library's detection as the binding returns it;
* ``detect``: the detector's ``detect`` (the library, then corner order and pixel convention,
  weak and repeated tags refused);
* ``front end``: :meth:`~rs_localizer.frontends.aruco.ArucoFrontend.process` on the RGB image
  (all of the above, then the map lookup into correspondences).

Then the library's options (``--variants``, :class:`DetectorOptions` fields), interleaved the
same way: the detection's CPU time, the fully visible tags found and the corner error against
the renderer's exact corners.

    python -m benchmarks.bench_marker_profile [--preset vga] [--frames 30] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from rs_localizer.frontends.aruco import ArucoFrontend
from rs_localizer.frontends.image import to_gray
from rs_localizer.frontends.marker_detection import DetectorOptions, make_marker_detector
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import NoiseModel, Renderer, camera_preset

from .bench_markers import FPS, room

__all__ = ["main", "profile_steps", "variants"]


def _video(preset: str, frames: int, seed: int = 0) -> list:
    """``[(rgb (H, W, 3), {id: exact corners (4, 2) px}, fully visible ids)]`` per frame."""
    scene = room()
    motion = make_motion("shake", scene, duration=frames / FPS + 0.1)
    r = Renderer(scene, camera_preset(preset), noise=NoiseModel())
    mc = scene.marker_corners()
    mids = np.array(sorted(mc), np.int64)
    X = np.concatenate([mc[int(m)] for m in mids])
    out = []
    for k in range(frames):
        f = r.render(motion, k / FPS, rng=seed + k)
        gt, _ = r.project(X, motion, k / FPS, occlusion=False)
        _, vis = r.project(X, motion, k / FPS, occlusion=True)
        visible = set(mids[vis.reshape(-1, 4).all(axis=1)].tolist())
        out.append((f.image, dict(zip(mids.tolist(), gt.reshape(-1, 4, 2), strict=True)), visible))
    return out


def profile_steps(video: list, repeats: int) -> dict:
    """CPU seconds per frame of each step (module notes): {step: (F * repeats,) s}."""
    fe = ArucoFrontend.from_scene(room(), detector_options=DetectorOptions(nthreads=1))
    det = fe.detector
    lib = det._detector(det.decimation(video[0][0].shape)) if det.backend == "apriltag" else None
    grays = [to_gray(rgb) for rgb, _, _ in video]
    steps = {"to_gray": [], "library": [], "detect": [], "front end": []}
    for _ in range(repeats):
        for (rgb, _, _), g in zip(video, grays, strict=True):
            t = time.process_time()
            to_gray(rgb)
            steps["to_gray"].append(time.process_time() - t)
            if lib is not None:
                t = time.process_time()
                lib.detect(g)
                steps["library"].append(time.process_time() - t)
            t = time.process_time()
            det.detect(g)
            steps["detect"].append(time.process_time() - t)
            fe.reset()
            t = time.process_time()
            fe.process(rgb)
            steps["front end"].append(time.process_time() - t)
    return {k: np.asarray(v) for k, v in steps.items() if v}


def variants(video: list, options: dict, repeats: int) -> dict:
    """Each ``{name: DetectorOptions}`` on the video, interleaved: {name: (CPU s (F * repeats,),
    tags found, tags visible, corner errors (N,) px)}."""
    dets = {n: make_marker_detector("DICT_APRILTAG_36h11", o) for n, o in options.items()}
    grays = [to_gray(rgb) for rgb, _, _ in video]
    res = {n: ([], 0, 0, []) for n in dets}
    for rep in range(repeats):
        for (_, gt, visible), g in zip(video, grays, strict=True):
            for n, d in dets.items():
                t = time.process_time()
                corners, ids, _ = d.detect(g)
                cpu, found, vis, err = res[n]
                cpu.append(time.process_time() - t)
                if rep:
                    continue
                seen = [(c, int(i)) for c, i in zip(corners, ids, strict=True) if int(i) in visible]
                err.extend(np.linalg.norm(c - gt[i], axis=1).tolist() for c, i in seen)
                res[n] = (cpu, found + len(seen), vis + len(visible), err)
    return {
        n: (np.asarray(c), f, v, np.concatenate(e) if e else np.zeros(0))
        for n, (c, f, v, e) in res.items()
    }


VARIANTS = {
    "default": {},
    "refine_edges false": {"refine_edges": False},
    "decode_sharpening 0": {"decode_sharpening": 0.0},
    "quad_sigma 0.8": {"quad_sigma": 0.8},
    "quad_decimate 2": {"quad_decimate": 2.0},
}


def main(argv: list | None = None) -> int:
    """Run the benchmark (see the module doc). Returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="vga", help="camera preset (vga 640x480, hd 1280x720)")
    ap.add_argument("--frames", type=int, default=30, help="video frames (30 Hz)")
    ap.add_argument("--repeats", type=int, default=3, help="passes over the video")
    ap.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help=f"AprilTag option variants, comma-separated, of: {', '.join(VARIANTS)}",
    )
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    video = _video(a.preset, a.frames)
    h, w = video[0][0].shape[:2]
    print(f"load: {os.getloadavg()[0]:.2f} (1 min average)")
    print(f"{w}x{h}, {a.frames} frames of apriltag_room x {a.repeats}, CPU ms per frame:")
    for step, t in profile_steps(video, a.repeats).items():
        print(
            f"  {step:10s} median {np.median(t) * 1e3:6.2f}  p90 {np.percentile(t, 90) * 1e3:6.2f}"
            f"  p99 {np.percentile(t, 99) * 1e3:6.2f}"
        )
    opts = {
        n: DetectorOptions(nthreads=1, detector="apriltag", **VARIANTS[n])
        for n in a.variants.split(",")
    }
    print("AprilTag options (interleaved):")
    for n, (cpu, found, vis, err) in variants(video, opts, a.repeats).items():
        e = f"{np.median(err):.4f} / {np.percentile(err, 90):.4f}" if len(err) else "-"
        print(
            f"  {n:20s} CPU ms median {np.median(cpu) * 1e3:6.2f}  p99 "
            f"{np.percentile(cpu, 99) * 1e3:6.2f} | tags found {found}/{vis} | corner error "
            f"median / p90 {e} px"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
