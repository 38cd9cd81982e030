"""Marker detection on a textured AprilTag room, each detector and decimation:
``python -m benchmarks.bench_markers`` (from the repository root).

Renders a hand-held (``shake``) rolling-shutter video (30 Hz, 30 ms readout, sensor noise) of
the built-in scene ``apriltag_room`` (AprilTag 36h11 tags of 14-25 cm on brick, gravel and
noise walls, one leaning panel) for each camera preset (``vga`` 640x480, ``hd`` 1280x720) and
runs on every frame, one thread each:

* ``opencv``: OpenCV's ArUco detector with the ArUco front end's settings
  (``DICT_APRILTAG_36h11``, what the front end used for AprilTag maps before the AprilTag
  library);
* ``apriltag dN``: the AprilTag 3 library at ``quad_decimate`` N (``--decimate``).

Prints per preset and detector: detection time per frame (median, p99, ms; and the median CPU
time of the detecting thread, what a loaded machine does not inflate), the share of the
fully visible tags found, corner error against the renderer's exact rolling-shutter projection
of the mapped corners (median, p90, px; fully visible tags only), and the pose error of the
package's estimator (``r6p_1lin``, per frame, the true marker map) against the truth (rotation
deg, position cm; median over the frames posed). Then false markers: the same room with its
tags removed (textured walls only), ``--false-frames`` frames searched for each of
``--false-dictionaries`` (36h11, and 16h5, the weakest family): markers reported by each
detector, and the AprilTag library's raw (unfiltered: up to 2 corrected bits, any decision
margin) detections there with their largest decision margin, against the smallest on the true
tags of the video.

    python -m benchmarks.bench_markers [--frames 20] [--presets vga,hd] [--decimate 1,1.5,2]
        [--false-frames 100] [--false-dictionaries DICT_APRILTAG_36h11,DICT_APRILTAG_16h5]
        [--seed 0] [--map-frames 150]

With ``--map-frames N``: ``rs-localizer map-markers`` on an N-frame ``shake`` video (640x480)
with each detector (:func:`run_map_markers`): its time (wall, CPU), the map's corner error
after a rigid fit to the truth and the corner offset it finds.
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.frontends.aruco import ArucoFrontend
from rs_localizer.frontends.image import to_gray
from rs_localizer.frontends.marker_detection import (
    DetectorOptions,
    apriltag_binding,
    make_marker_detector,
)
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.maps.scenes import scene_path
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import NoiseModel, Renderer, camera_preset
from rs_localizer.sim.render.scene import load_scene

FPS = 30.0
SCENE = "apriltag_room"


def detectors(scene, decimations) -> dict:
    """name -> detector: OpenCV with the front end's settings, the AprilTag library per
    decimation (when a binding is installed)."""
    out = {
        "opencv": ArucoFrontend.from_scene(
            scene, detector_options=DetectorOptions(detector="opencv")
        ).detector
    }
    if apriltag_binding() is not None:
        for d in decimations:
            out[f"apriltag d{d:g}"] = make_marker_detector(
                scene.dictionary, DetectorOptions(detector="apriltag", quad_decimate=d)
            )
    return out


def run_video(preset: str, frames: int, decimations, seed: int = 0) -> dict:
    """Detect and localize ``frames`` frames of the room's ``shake`` video with every detector
    (interleaved frame by frame). Returns {name: {"t" (F,) s, "cpu" (F,) thread CPU s,
    "found" (F,), "visible" (F,), "err" (N,) px, "rot" (F,) deg, "pos" (F,) m (NaN: not
    posed), "margins" (M,) raw decision margins of the true tags (AprilTag)}}."""
    scene = load_scene(SCENE)
    camera = camera_preset(preset)
    motion = make_motion("shake", scene, duration=frames / FPS + 0.1)
    r = Renderer(scene, camera, noise=NoiseModel())
    dets = detectors(scene, decimations)
    mc = scene.marker_corners()
    mids = np.array(sorted(mc), np.int64)
    X_all = np.concatenate([mc[int(m)] for m in mids])
    res = {
        n: {k: [] for k in ("t", "cpu", "found", "visible", "err", "rot", "pos", "margins")}
        for n in dets
    }
    for k in range(frames):
        t_first = k / FPS
        f = r.render(motion, t_first, rng=seed + k)
        gray = to_gray(f.image)
        _, vis = r.project(X_all, motion, t_first, occlusion=True)
        visible = set(mids[vis.reshape(-1, 4).all(axis=1)].tolist())
        for name, det in dets.items():
            t0, c0 = time.perf_counter(), time.thread_time()
            corners, ids, _ = det.detect(gray)
            res[name]["t"].append(time.perf_counter() - t0)
            res[name]["cpu"].append(time.thread_time() - c0)
            if det.backend == "apriltag":
                _, rid, _, mar = det.raw(gray)
                res[name]["margins"].extend(mar[np.isin(rid, mids)].tolist())
            keep = np.array([int(i) in mc for i in ids], bool)
            corners, ids = corners[keep], ids[keep]
            res[name]["visible"].append(len(visible))
            res[name]["found"].append(len(visible & set(ids.tolist())))
            if len(ids) == 0:
                res[name]["rot"].append(np.nan)
                res[name]["pos"].append(np.nan)
                continue
            uv = corners.reshape(-1, 2)
            X = np.concatenate([mc[int(i)] for i in ids])
            gt, _ = r.project(X, motion, t_first, occlusion=False)
            full = np.repeat([int(i) in visible for i in ids], 4)
            res[name]["err"].extend(np.linalg.norm(uv - gt, axis=1)[full].tolist())
            est = estimate_rs_pose(uv, X, camera, "r6p_1lin") if len(uv) >= 12 else None
            ok = est is not None and est.success
            res[name]["rot"].append(
                rotation_angle_deg(est.orientation, f.orientation) if ok else np.nan
            )
            res[name]["pos"].append(
                float(np.linalg.norm(est.position - f.position)) if ok else np.nan
            )
    return {n: {k: np.asarray(v, float) for k, v in o.items()} for n, o in res.items()}


def run_false(
    preset: str, frames: int, decimations, dictionary: str = "DICT_APRILTAG_36h11", seed: int = 1000
) -> dict:
    """The room without its tags, searched for ``dictionary``: {name: (markers reported (F,),
    raw decision margins (M,) of the AprilTag library's unfiltered detections)}."""
    import yaml

    data = yaml.safe_load(scene_path(SCENE).read_text())
    data.pop("markers")
    bare = load_scene(data)
    bare.dictionary = dictionary
    camera = camera_preset(preset)
    motion = make_motion("shake", bare, duration=frames / FPS + 0.1)
    r = Renderer(bare, camera, noise=NoiseModel())
    dets = detectors(bare, decimations)
    out = {n: ([], []) for n in dets}
    for k in range(frames):
        gray = to_gray(r.render(motion, k / FPS, rng=seed + k).image)
        for name, det in dets.items():
            _, ids, _ = det.detect(gray)
            out[name][0].append(len(ids))
            if det.backend == "apriltag":
                out[name][1].extend(det.raw(gray)[3].tolist())
    return {n: (np.asarray(a), np.asarray(b)) for n, (a, b) in out.items()}


def run_map_markers(frames: int, detectors=("opencv", "apriltag"), seed: int = 0) -> dict:
    """``rs-localizer map-markers`` (its defaults: the rolling-shutter map, the corner offset
    estimated) on a ``frames``-frame ``shake`` video of the room (640x480, 30 Hz, 30 ms
    readout; rendered with ``render-bag``), once per detector. Returns {detector: {"wall",
    "cpu" (s, the whole command: detection, adjustment, covariance, report), "err" (N,) corner
    errors (m) of the markers mapped after the rigid best fit to the scene's true corners,
    "markers", "offset", "offset_std" (px, from the report), "readout" (s)}}."""
    import tempfile
    from pathlib import Path

    import yaml

    from rs_localizer.cli import main as cli
    from rs_localizer.mapping.marker_model import fit_rigid
    from rs_localizer.maps import load_marker_map

    truth = load_scene(SCENE).marker_corners()
    sides = {m: float(np.linalg.norm(c[1] - c[0])) for m, c in truth.items()}
    sizes = ",".join(f"{m}:{s:.4f}" for m, s in sorted(sides.items()))
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "video"
        argv = ["render-bag", str(bag), "--scene", SCENE, "--motion", "shake", "--camera", "vga"]
        argv += ["--frames", str(frames), "--frontend", "none", "--seed", str(seed), "--quiet"]
        cli(argv)
        for det in detectors:
            res = Path(tmp) / det
            argv = ["map-markers", str(bag), "-o", str(res / "map.yaml"), "--report", str(res)]
            argv += ["--marker-size", "0.18", "--marker-sizes", sizes, "--detector", det]
            t0, c0 = time.perf_counter(), time.process_time()
            cli([*argv, "--quiet"])
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            _, corners = load_marker_map(res / "map.yaml")
            ids = sorted(set(corners) & set(truth))
            src = np.concatenate([corners[m] for m in ids])
            dst = np.concatenate([truth[m] for m in ids])
            R, t = fit_rigid(src, dst)
            rep = yaml.safe_load((res / "report.yaml").read_text())
            out[det] = {
                "wall": wall,
                "cpu": cpu,
                "err": np.linalg.norm(src @ R.T + t - dst, axis=1),
                "markers": len(ids),
                "offset": float(rep["corner_offset_px"]),
                "offset_std": float(rep.get("corner_offset_std_px", np.nan)),
                "readout": float(rep["line_delay_s"]) * camera_preset("vga").height,
            }
    return out


def print_map_markers(frames: int, seed: int = 0) -> None:
    """Print :func:`run_map_markers` with the targets: the rolling-shutter map in <= 60 s on
    one core, and its corner error (RMS after the rigid fit) <= 0.5x the OpenCV map's."""
    dets = ["opencv"] + (["apriltag"] if apriltag_binding() is not None else [])
    res = run_map_markers(frames, dets, seed)
    print(f"map-markers, {frames} frames 640x480 of {SCENE} (shake, RS), one thread")
    print(
        "  detector   wall s  CPU s | markers | corner err mm (rigid fit) RMS  median   p90 "
        "| corner offset px (std)"
    )
    for det, r in res.items():
        e = r["err"] * 1e3
        print(
            f"  {det:9s} {r['wall']:7.1f} {r['cpu']:6.1f} | {r['markers']:7d} | "
            f"{np.sqrt(np.mean(e**2)):30.2f} {np.median(e):7.2f} {np.percentile(e, 90):5.2f} "
            f"| {r['offset']:+.3f} ({r['offset_std']:.3f})"
        )
    if "apriltag" in res:
        a, o = res["apriltag"], res["opencv"]
        ratio = np.sqrt(np.mean(a["err"] ** 2)) / np.sqrt(np.mean(o["err"] ** 2))
        print(
            f"  targets: apriltag map {a['cpu']:.1f} s CPU (<= 60 s: "
            f"{'met' if a['cpu'] <= 60 else 'missed'}); corner error RMS {ratio:.2f}x OpenCV's "
            f"(<= 0.5x: {'met' if ratio <= 0.5 else 'missed'})"
        )


def main(argv: list | None = None) -> int:
    """Run the benchmark (see the module doc). Returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=20, help="video frames per preset (30 Hz)")
    ap.add_argument("--presets", default="vga,hd", help="camera presets, comma-separated")
    ap.add_argument("--decimate", default="1,1.5,2", help="AprilTag quad_decimate values")
    ap.add_argument("--false-frames", type=int, default=100, help="frames without tags (vga)")
    ap.add_argument("--seed", type=int, default=0, help="sensor noise seed")
    ap.add_argument(
        "--false-dictionaries",
        default="DICT_APRILTAG_36h11,DICT_APRILTAG_16h5",
        help="dictionaries searched on the frames without tags (16h5: the weakest family)",
    )
    ap.add_argument(
        "--map-frames",
        type=int,
        default=0,
        help="also run map-markers on a video of this many frames with each detector (0: no)",
    )
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    dec = [float(v) for v in a.decimate.split(",") if v]
    b = apriltag_binding()
    print(f"load: {os.getloadavg()[0]:.2f} (1 min average); AprilTag binding: {b and b[0]}")
    for preset in [p for p in a.presets.split(",") if p]:
        res = run_video(preset, a.frames, dec, a.seed)
        cam = camera_preset(preset)
        print(f"{preset} {cam.width}x{cam.height}, {a.frames} frames of {SCENE} (shake, RS)")
        print(
            "  detector       detect ms median   p99 (CPU median) | tags found | corner err px "
            "median   p90 | rot deg  pos cm | posed"
        )
        for name, r in res.items():
            ok = np.isfinite(r["rot"])
            found = r["found"].sum() / max(r["visible"].sum(), 1)
            t_med, t_p99 = np.median(r["t"]) * 1e3, np.percentile(r["t"], 99) * 1e3
            print(
                f"  {name:14s} {t_med:16.1f} {t_p99:5.1f} {np.median(r['cpu']) * 1e3:12.1f}"
                f" | {found:10.3f} | {np.median(r['err']):20.3f} {np.percentile(r['err'], 90):5.3f}"
                f" | {np.nanmedian(r['rot']):7.3f} {np.nanmedian(r['pos']) * 100:6.2f}"
                f" | {ok.sum()}/{len(ok)}"
            )
        for name, r in res.items():
            if len(r["margins"]):
                print(
                    f"  {name}: decision margin of the true tags: min {r['margins'].min():.1f}, "
                    f"1st percentile {np.percentile(r['margins'], 1):.1f}"
                )
    for dictionary in [d for d in a.false_dictionaries.split(",") if d] * (a.false_frames > 0):
        fr = run_false("vga", a.false_frames, dec, dictionary)
        print(
            f"false markers: {a.false_frames} frames 640x480 of {SCENE} without its tags, "
            f"{dictionary}"
        )
        for name, (n, m) in fr.items():
            extra = (
                f"; raw detections {len(m)}, largest margin {m.max():.1f}"
                if len(m)
                else ("; raw detections 0" if name != "opencv" else "")
            )
            print(f"  {name:14s} markers reported {int(n.sum())}{extra}")
    if a.map_frames > 0:
        print_map_markers(a.map_frames, a.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
