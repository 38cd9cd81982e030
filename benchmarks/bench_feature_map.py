"""Feature maps from photos: ``python -m benchmarks.bench_feature_map``.

Renders ``--photos`` global-shutter photos of ``textured_room`` on a slow walk (640x480, the
``vga`` lens), reconstructs them with pycolmap (:func:`rs_localizer.mapping.colmap.reconstruct`,
two threads for extraction and matching, one for the mapping, sequential matching: the photos
are a walk), imports the model (:func:`~rs_localizer.mapping.colmap.feature_map_from_colmap`,
track >= 3) and aligns it on the scene's ten markers. Then renders ``--frames`` rolling-shutter
frames (hand-held ``shake``, 30 ms readout, sensor noise) and localizes each with the features
front end and ``r6p_1lin`` / ``p3p`` against this map and against the renderer-built SIFT map
(:func:`rs_localizer.sim.feature_map.build_feature_map`, six views of the same motion).

Prints: reconstruction time and size; the ArUco corners detected in the photos against their
true projections; the marker alignment (refined on the detections, the default, and from the
triangulated corners alone) against the oracle alignment, the best-fit similarity of the
model's points to their ground truth (the median over each point's track of the renderer's
ray cast of its observations), with the 3D point errors; per map, median matches, correct
matches (within 3 px of the true projection of the matched point's ground truth), the median
distance of the correct ones to that projection (px) and median rotation / position errors of
``r6p_1lin`` and ``p3p``. Besides the COLMAP map as the user gets it, the rows separate what
limits it: the same map aligned on the triangulated corners, with its descriptors
unconverted, and three oracle rows that no matcher or alignment can beat: the map moved by the
best-fit similarity, the map's points replaced by their ground truth (same matches), and only
the matches within 1.5 px of the true projection. Then the front end + estimator time per
frame against a map padded to ``--map-size`` descriptors (detection, matching, estimation;
brute force and FLANN with 64, 32 and 16 checks, interleaved frame by frame) and the
targets, checked. One OpenCV / BLAS thread for the timings.

    python -m benchmarks.bench_feature_map [--photos 40] [--frames 20]
        [--map-size 100000] [--matching sequential|exhaustive] [--seed 0] [--workdir DIR]

``--workdir DIR`` keeps the photos and the reconstruction; a second run with the same photos,
matching and seed reuses them (then the reconstruction is not timed).

A reconstruction that the marker alignment refuses (bent by photos registered at wrong poses
where the tiled textures repeat) is reported as such, with exit code 1.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.frontends.features import FeatureFrontend
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.maps.features import FeatureMap
from rs_localizer.sim.feature_map import build_feature_map, photo_walk
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import NoiseModel, Renderer, camera_preset
from rs_localizer.sim.render.scene import load_scene

__all__ = ["main"]


def _true_points(model: Path, fm: FeatureMap, renderer: Renderer, poses: list) -> np.ndarray:
    """(M, 3) m: the ground truth of each map row, the median over its track of the renderer's
    ray cast of each observation (COLMAP pixel - 0.5) from the photo's true pose; NaN where
    no ray hits."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model))
    rows, images, uv = [], [], []
    for k, pid in enumerate(fm.landmark_ids):
        for el in rec.points3D[int(pid)].track.elements:
            rows.append(k)
            images.append(el.image_id)
            uv.append(np.asarray(rec.images[el.image_id].points2D[el.point2D_idx].xy) - 0.5)
    rows, images, uv = np.array(rows), np.array(images), np.array(uv)
    X = np.full((len(rows), 3), np.nan)
    for iid in np.unique(images):
        R, p = poses[int(rec.images[int(iid)].name[6:9])]
        sel = images == iid
        X[sel] = renderer.cast(uv[sel], pose=(R, p))[0]
    truth = np.full((len(fm), 3), np.nan)
    order = np.argsort(rows, kind="stable")
    bounds = np.flatnonzero(np.diff(rows[order])) + 1
    for grp in np.split(order, bounds):
        hit = X[grp][np.isfinite(X[grp]).all(axis=1)]
        if len(hit):
            truth[rows[grp[0]]] = np.median(hit, axis=0)
    return truth


def _best_similarity(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Oracle alignment: (scale, R, t) with ``dst ~ scale R src + t`` (Umeyama,
    ``cv2.estimateAffine3D``) over the rows with a ground truth, refitted three times on the
    rows within 3x the median distance."""
    ok = np.isfinite(dst).all(axis=1)
    for _ in range(4):
        Rt, scale = cv2.estimateAffine3D(src[ok], dst[ok], force_rotation=True)
        Rt = np.asarray(Rt, float)
        e = np.linalg.norm(scale * src @ Rt[:, :3].T + Rt[:, 3] - dst, axis=1)
        ok = np.isfinite(e) & (e < 3 * np.nanmedian(e))
    return float(scale), Rt[:, :3], Rt[:, 3]


def _marker_corner_errors(photos: Path, poses: list, camera) -> tuple[np.ndarray, np.ndarray]:
    """ArUco corners detected in the photos against their true projections: (distance (K,)
    px, component (K,) px along the direction from the marker's projected centre to the
    corner, negative towards the centre)."""
    from rs_localizer.frontends.aruco import ArucoFrontend
    from rs_localizer.maps import load_marker_map

    dictionary, corners3d = load_marker_map("textured_room")
    det = ArucoFrontend(corners3d, dictionary)
    dist, radial = [], []
    for k, (R, p) in enumerate(poses):
        gray = cv2.imread(str(photos / f"photo_{k:03d}.png"), cv2.IMREAD_GRAYSCALE)
        px, mids = det.detect(gray, "mono8")
        found_all = np.asarray(px, float).reshape(-1, 4, 2)
        for found, m in zip(found_all, np.asarray(mids).ravel(), strict=True):
            if int(m) not in corners3d:
                continue
            Xc = (corners3d[int(m)] - p) @ R
            uv = camera.distort(Xc[:, :2] / Xc[:, 2:])
            out = uv - uv.mean(axis=0)
            e = found - uv
            dist.extend(np.linalg.norm(e, axis=1))
            radial.extend(np.einsum("ij,ij->i", e, out / np.linalg.norm(out, axis=1)[:, None]))
    return np.array(dist), np.array(radial)


def _padded(fm: FeatureMap, size: int, rng: np.random.Generator) -> FeatureMap:
    """The map plus distractors up to ``size`` rows: its descriptors shuffled across their
    128 bins (SIFT-like statistics, matching nothing), far-away points, fresh ids."""
    n = max(0, int(size) - len(fm))
    if n == 0:
        return fm
    src = fm.descriptors[rng.integers(0, len(fm), n)]
    fake = np.take_along_axis(src, rng.permuted(np.tile(np.arange(128), (n, 1)), axis=1), 1)
    return FeatureMap(
        np.concatenate([fm.points, rng.normal(0, 100, (n, 3))]),
        np.concatenate([fm.descriptors, fake]).astype(np.float32),
        np.concatenate([fm.landmark_ids, fm.landmark_ids.max() + 1 + np.arange(n)]),
        "sift",
    )


def _localize(
    fm: FeatureMap,
    frames: list,
    camera,
    renderer,
    motion,
    matcher: str = "bf",
    truth: np.ndarray | None = None,
    oracle_px: float | None = None,
):
    """Per frame: correct-match fraction, matches, (rot deg, pos m) per solver, times (s) of
    detection, matching, estimation, median distance (px) of the correct matches.

    A match is correct within 3 px of the true projection of its map row's true point
    (``truth`` (M, 3), default the map's points). ``oracle_px``: the estimator gets only the
    matches within that distance of it."""
    fe = FeatureFrontend(fm, matcher=matcher)
    row_of = {int(i): k for k, i in enumerate(fm.landmark_ids)}
    truth = fm.points if truth is None else truth
    rows = []
    for t, f in frames:
        t0 = time.perf_counter()
        fe.detector.detectAndCompute(cv2.cvtColor(f.image, cv2.COLOR_RGB2GRAY), None)
        t1 = time.perf_counter()
        uv, X, ids = fe.process(f.image, camera)
        t2 = time.perf_counter()
        true = truth[[row_of[int(i)] for i in ids]].reshape(-1, 3)
        gt, ok = renderer.project(np.nan_to_num(true, nan=1e6), motion, t, occlusion=True)
        err = np.where(ok, np.linalg.norm(uv - np.nan_to_num(gt), axis=1), np.inf)
        good = err[err < 3.0]
        row = [np.mean(err < 3.0) if len(err) else 0.0, len(uv)]
        if oracle_px is not None:
            uv, X = uv[err < oracle_px], X[err < oracle_px]
        t_est = 0.0
        for solver in ("r6p_1lin", "p3p"):
            t3 = time.perf_counter()
            est = estimate_rs_pose(uv, X, camera, solver)
            if solver == "r6p_1lin":
                t_est = time.perf_counter() - t3
            row += (
                [
                    rotation_angle_deg(est.pose.orientation, f.orientation),
                    float(np.linalg.norm(est.pose.position - f.position)),
                ]
                if est.success
                else [np.nan, np.nan]
            )
        row += [t1 - t0, (t2 - t1) - (t1 - t0), t_est, np.median(good) if len(good) else np.nan]
        rows.append(row)
    return np.array(rows)


def _moved(fm: FeatureMap, points: np.ndarray) -> FeatureMap:
    """The map with other points (same rows, descriptors, ids)."""
    out = fm.subset(np.arange(len(fm)))
    out.points = np.asarray(points, float)
    return out


def _photos_and_model(args, tmp: Path, poses: list, gs, gs_renderer) -> tuple[Path, Path, float]:
    """Render the photos and reconstruct them (or reuse ``--workdir``'s); returns (photos dir,
    model dir, reconstruction seconds, NaN when reused)."""
    from rs_localizer.mapping.colmap import reconstruct

    root = Path(args.workdir) if args.workdir else tmp
    photos, work = root / "photos", root / "work"
    stamp = root / "bench_feature_map.txt"
    key = f"photos {args.photos} matching {args.matching} seed {args.seed}\n"
    if (work / "model").is_dir() and stamp.is_file() and stamp.read_text() == key:
        return photos, work / "model", float("nan")
    photos.mkdir(parents=True, exist_ok=True)
    for old in photos.glob("photo_*.png"):
        old.unlink()
    for k, (R, p) in enumerate(poses):
        img = gs_renderer.render_pose(R, p)
        cv2.imwrite(str(photos / f"photo_{k:03d}.png"), img[:, :, ::-1])
    stamp.unlink(missing_ok=True)
    t0 = time.perf_counter()
    model = reconstruct(photos, gs, work, progress=None, matching=args.matching, seed=args.seed)
    t_rec = time.perf_counter() - t0
    stamp.write_text(key)
    return photos, model, t_rec


def _timing(big: FeatureMap, frames: list, camera) -> dict:
    """Median per frame of (detection ms, matching ms, estimation ms, matches, r6p_1lin
    rotation error deg) per matcher on ``big``: brute force and FLANN with 64, 32 (the
    default) and 16 checks, the matchers interleaved frame by frame."""
    fronts = {
        "brute force": FeatureFrontend(big, matcher="bf"),
        **{
            f"FLANN, {c} checks": FeatureFrontend(big, matcher="flann", flann_checks=c)
            for c in (64, 32, 16)
        },
    }
    rows: dict = {name: [] for name in fronts}
    for _, f in frames:
        gray = cv2.cvtColor(f.image, cv2.COLOR_RGB2GRAY)
        for name, fe in fronts.items():
            t0 = time.perf_counter()
            fe.detector.detectAndCompute(gray, None)
            t1 = time.perf_counter()
            uv, X, _ = fe.process(f.image, camera)
            t2 = time.perf_counter()
            est = estimate_rs_pose(uv, X, camera, "r6p_1lin")
            t3 = time.perf_counter()
            rot = rotation_angle_deg(est.pose.orientation, f.orientation) if est.success else np.nan
            rows[name].append(
                [(t1 - t0) * 1e3, ((t2 - t1) - (t1 - t0)) * 1e3, (t3 - t2) * 1e3, len(uv), rot]
            )
    return {name: np.nanmedian(np.array(r), axis=0) for name, r in rows.items()}


def main(argv: list | None = None) -> int:
    """Run the benchmark (see the module doc). Returns 0 when every target checked is met,
    else 1."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos", type=int, default=40, help="photos to reconstruct")
    ap.add_argument("--frames", type=int, default=20, help="rolling-shutter frames localized")
    ap.add_argument("--map-size", type=int, default=100_000, help="descriptors for the timing")
    ap.add_argument("--seed", type=int, default=0, help="COLMAP's RANSAC seed")
    ap.add_argument(
        "--matching", choices=["exhaustive", "sequential"], default="sequential", help="pairs"
    )
    ap.add_argument(
        "--workdir",
        metavar="DIR",
        help="keep photos and reconstruction here; a later run with the same --photos, "
        "--matching and --seed reuses them (the reconstruction is then not timed)",
    )
    args = ap.parse_args(argv)
    from rs_localizer.mapping.colmap import (
        align_feature_map,
        align_to_markers,
        feature_map_from_colmap,
    )

    scene = load_scene("textured_room")
    gs = camera_preset("vga", line_delay=0.0)
    rs = camera_preset("vga")
    gs_renderer = Renderer(scene, gs)
    poses = photo_walk(args.photos)
    with tempfile.TemporaryDirectory(prefix="bench_feature_map_") as tmp:
        photos, model, t_rec = _photos_and_model(args, Path(tmp), poses, gs, gs_renderer)
        raw = feature_map_from_colmap(model, min_track=3)
        unconverted = feature_map_from_colmap(model, min_track=3, opencv_normalisation=False)
        try:
            al = align_to_markers(model, photos, "textured_room")
            al_corners = align_to_markers(model, photos, "textured_room", refine=False)
        except ValueError as e:
            timed = "reused" if np.isnan(t_rec) else f"in {t_rec:.1f} s"
            print(
                f"reconstruction of {args.photos} photos ({args.matching} matching, seed "
                f"{args.seed}, {timed}) refused: {e}"
            )
            return 1
        fm = align_feature_map(raw, al)
        truth = _true_points(model, fm, gs_renderer, poses)
        corner_err, corner_radial = _marker_corner_errors(photos, poses, gs)
    oracle = _best_similarity(raw.points, truth)
    timed = "reused from --workdir" if np.isnan(t_rec) else f"in {t_rec:.1f} s"
    print(
        f"reconstruction: {args.photos} photos {timed} (pycolmap, 2 threads, mapping on 1, "
        f"{args.matching} matching, seed {args.seed}); {len(fm)} points with track >= 3"
    )
    print(
        f"marker alignment: {len(al.markers)} markers, {len(al.corners)} triangulated corners "
        f"(residual {al.residual_rms * 1000:.1f} mm RMS), {len(al.reprojection_errors)} "
        f"detections of a marker (centre residual median "
        f"{np.median(al.reprojection_errors):.2f} px)"
    )
    print(
        f"ArUco corners in the photos vs their true projections: median "
        f"{np.median(corner_err):.2f} px, towards the marker's centre by "
        f"{-np.mean(corner_radial):.2f} px on average ({len(corner_err)} corners)"
    )
    print("alignment vs the best-fit similarity of the points to their ground truth:")
    err3d = {}
    for name, (scale, R, t) in (
        ("on the detections (default)", (al.scale, al.R, al.t)),
        ("on the triangulated corners", (al_corners.scale, al_corners.R, al_corners.t)),
        ("best-fit similarity (oracle)", oracle),
    ):
        err3d[name] = np.linalg.norm(scale * raw.points @ R.T + t - truth, axis=1)
        print(
            f"  {name:30s} rotation {rotation_angle_deg(R, oracle[1]):.4f} deg, scale "
            f"{(scale / oracle[0] - 1) * 1e6:+5.0f} ppm; 3D point error median "
            f"{np.nanmedian(err3d[name]) * 1000:.2f} mm, p90 "
            f"{np.nanpercentile(err3d[name], 90) * 1000:.2f} mm"
        )
    motion = make_motion("shake", scene, duration=2.0)
    renderer = Renderer(scene, rs, noise=NoiseModel())
    times = np.linspace(0.05, 1.95, args.frames)
    frames = [(t, renderer.render(motion, t, rng=i)) for i, t in enumerate(times)]
    ref = build_feature_map(scene, gs, (motion, np.linspace(0.0, 2.0, 6)), kind="sift")
    cv2.setNumThreads(1)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    s_o, R_o, t_o = oracle
    known = np.isfinite(truth).all(axis=1)  # rows whose observations hit the scene
    rows = {
        "COLMAP map": (fm, {}),
        "  aligned on triangulated corners": (align_feature_map(raw, al_corners), {}),
        "  descriptors unconverted": (align_feature_map(unconverted, al), {}),
        "  oracle: best-fit similarity": (_moved(fm, s_o * raw.points @ R_o.T + t_o), {}),
        "  oracle: true points": (_moved(fm.subset(known), truth[known]), {}),
        "  oracle: matches within 1.5 px": (fm, {"oracle_px": 1.5}),
        "renderer-built map": (ref, {}),
    }
    truth_of = dict(zip(fm.landmark_ids.tolist(), truth, strict=True))
    res = {}
    for name, (m, kw) in rows.items():
        true = None if m is ref else np.array([truth_of[int(i)] for i in m.landmark_ids])
        res[name] = _localize(m, frames, rs, renderer, motion, truth=true, **kw)
    print(f"\n{args.frames} rolling-shutter frames (shake, 30 ms readout); medians")
    print(
        f"{'map':34s} {'matches':>8s} {'correct':>8s} {'px':>5s} {'r6p_1lin deg':>12s} "
        f"{'cm':>6s} {'p3p deg':>8s} {'cm':>6s}"
    )
    for name, a in res.items():
        med = np.nanmedian(a, axis=0)
        fails = int(np.isnan(a[:, 2]).sum())
        print(
            f"{name:34s} {med[1]:8.0f} {med[0]:8.1%} {med[9]:5.2f} {med[2]:12.4f} "
            f"{med[3] * 100:6.3f} {med[4]:8.4f} {med[5] * 100:6.2f}"
            + (f"  ({fails} frames failed)" if fails else "")
        )
    big = _padded(fm, args.map_size, np.random.default_rng(0))
    timing = _timing(big, frames[: min(8, len(frames))], rs)
    print(
        f"\n{len(big)}-descriptor map, one thread, {min(8, len(frames))} frames interleaved "
        "(medians; ms):"
    )
    for name, a in timing.items():
        print(
            f"  {name:22s} detection {a[0]:6.1f}, matching {a[1]:7.1f}, estimation {a[2]:4.1f}, "
            f"total {a[:3].sum():7.1f}; matches {a[3]:5.0f}, rotation error {a[4]:.4f} deg"
        )
    c = np.nanmedian(res["COLMAP map"], axis=0)
    r = np.nanmedian(res["renderer-built map"], axis=0)
    total = min(a[:3].sum() for a in timing.values())
    median3d = np.nanmedian(err3d["on the detections (default)"])
    targets = [
        ("median 3D point error <= 1 cm", median3d <= 0.01),
        ("rotation within 1.5x of the renderer-built map", c[2] <= 1.5 * r[2]),
        ("position within 1.5x of the renderer-built map", c[3] <= 1.5 * r[3]),
        ("r6p_1lin >= 5x better than p3p in rotation", c[4] >= 5 * c[2]),
        (f"front end + estimator <= 40 ms ({total:.1f} ms)", total <= 40.0),
        (
            f"reconstruction of {args.photos} photos <= 3 min ({t_rec:.0f} s)",
            None if np.isnan(t_rec) else t_rec <= 180.0,
        ),
    ]
    print("\ntargets:")
    for text, ok in targets:
        mark = "-" if ok is None else ("x" if ok else " ")
        print(f"  [{mark}] {text}" + (" (not timed: reused)" if ok is None else ""))
    return 0 if all(ok is not False for _, ok in targets) else 1


if __name__ == "__main__":
    sys.exit(main())
