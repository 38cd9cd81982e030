"""Video through the tracking feature front end: ``python -m
benchmarks.bench_tracking``.

Renders two rolling-shutter videos of ``textured_room`` at 30 Hz (640x480 RGB, the ``vga``
lens, 30 ms readout, sensor noise): a hand-held one (``shake``) and a slow walk (``walk`` at
0.2 m/s), the walk with the view blanked (black frames) for ``--blank`` s in its middle. Each
is localized frame by frame against the renderer-built SIFT map of the scene
(:func:`rs_localizer.sim.feature_map.build_feature_map`, six global-shutter views per video)
padded to ``--map-size`` descriptors with distractors (shuffled descriptors, far points),
with :class:`~rs_localizer.frontends.tracking.TrackingFeatureFrontend` tracking on and off
(off: full detection + FLANN matching on every frame, the per-frame front end) and the
``r6p_1lin`` estimator (:func:`rs_localizer.estimation.estimate.estimate_rs_pose`).

Prints per video and mode: frames per kind (global / tracked), correspondences per kind,
the per-frame time split (tracking, guided join, detection + global matching, estimation;
median and p99, ms), rotation and position errors against the renderer's truth (median over
the frames, first and last 50 frames), the inliers' distances to the true projections of
their map points per kind of correspondence, the frames posed, and after the blank the frames
until posed again; then the targets, checked. The frames are fed as fast as they are processed, so
a background refresh spans more frames than it would on a live camera; ``--realtime`` feeds
them at 30 Hz instead (a frame that takes longer is followed at once). One OpenCV / BLAS
thread.

    python -m benchmarks.bench_tracking [--frames 300] [--map-size 100000]
        [--blank 1.0] [--seed 0] [--realtime]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import cv2
import numpy as np

from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.frontends.tracking import TrackingFeatureFrontend
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.maps.features import FeatureMap
from rs_localizer.sim.feature_map import build_feature_map
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import NoiseModel, Renderer, camera_preset
from rs_localizer.sim.render.scene import load_scene
from rs_localizer.tracking.tracker import CarriedPrediction

__all__ = ["main", "median_ratio_interval", "padded_map", "run_video"]

FPS = 30.0
#: frames per block of the moving-block bootstrap (1 s at 30 Hz: neighbouring frames' errors
#: are correlated, so frames are resampled in runs of this length)
BLOCK_FRAMES = 30


def padded_map(fm: FeatureMap, size: int, seed: int = 0) -> FeatureMap:
    """``fm`` plus distractor rows up to ``size``: its descriptors with their 128 bins
    shuffled (SIFT-like statistics, matching nothing), points far away (N(0, 100 m)), fresh
    landmark ids."""
    rng = np.random.default_rng(seed)
    n = max(0, int(size) - len(fm))
    if n == 0:
        return fm
    d = fm.descriptors.shape[1]
    src = fm.descriptors[rng.integers(0, len(fm), n)]
    fake = np.take_along_axis(src, rng.permuted(np.tile(np.arange(d), (n, 1)), axis=1), 1)
    return FeatureMap(
        np.concatenate([fm.points, rng.normal(0, 100, (n, 3))]),
        np.concatenate([fm.descriptors, fake]).astype(np.float32),
        np.concatenate([fm.landmark_ids, fm.landmark_ids.max() + 1 + np.arange(n)]),
        "sift",
    )


def run_video(
    fm: FeatureMap,
    frames: list,
    camera,
    tracking: bool,
    period_s: float = 0.0,
    truth: tuple | None = None,
    **kw,
) -> dict:
    """Localize ``frames`` (:class:`~rs_localizer.sim.render.renderer.RenderedFrame`, None
    entries are blanked: a black image) in order. Returns per-frame arrays: ``kind`` (str),
    ``tracked``/``guided``/``global`` correspondences, times (s) ``tracking``, ``guided``,
    ``detection``, ``estimation``, ``frontend`` (all of the front end), ``rot`` (deg) and
    ``pos`` (m) errors (NaN: not posed), ``blank`` (bool), ``waited`` (bool: the frame waited
    for a late refresh). ``period_s`` > 0: the next frame is given no earlier than this many
    seconds after the previous one (a live camera's frame period; the background refresh
    runs meanwhile); 0: as soon as the previous frame is done. ``truth``: ``(renderer,
    motion)`` of the video: then ``px_err`` holds per frame the estimate's inliers' distances
    (px) to the true rolling-shutter projections of their map points and ``px_kind`` their
    kinds (0 tracked, 1 guided, 2 global), and ``pos_shuffled`` (m, NaN on global frames)
    the position error of each tracked frame estimated again from the true projections of
    its inliers plus the same pixel errors shuffled among them (the errors' sizes kept, their
    arrangement over the image lost)."""
    fe = TrackingFeatureFrontend(fm, tracking=tracking, **kw)
    carry = CarriedPrediction()  # (the last solved frame carried: the front end's search)
    out = {
        k: []
        for k in (
            "kind",
            "tracked",
            "guided",
            "global",
            "tracking",
            "guided_ms",
            "detection",
            "estimation",
            "frontend",
            "rot",
            "pos",
            "blank",
            "waited",
            "px_err",
            "px_kind",
            "pos_shuffled",
        )
    }
    rng = np.random.default_rng(0)
    for f, blank in frames:
        img = np.zeros_like(f.image) if blank else f.image
        stamp = int(round(f.t_first * 1e9))
        t0 = time.perf_counter()
        pred = carry.predict(stamp, camera)
        uv, X, _ = fe.process(img, camera, encoding="rgb8", prediction=pred)
        t1 = time.perf_counter()
        est = estimate_rs_pose(uv, X, camera, "r6p_1lin") if len(uv) >= 6 else None
        t2 = time.perf_counter()
        fe.observe(stamp, None, est)
        carry.update(stamp, est)
        rep = fe.report
        out["kind"].append(rep.kind)
        out["tracked"].append(rep.tracked)
        out["guided"].append(rep.guided)
        out["global"].append(rep.global_)
        out["tracking"].append(rep.times.get("tracking", 0.0))
        out["guided_ms"].append(rep.times.get("guided", 0.0))
        out["detection"].append(rep.times.get("detection", 0.0))
        out["estimation"].append(t2 - t1)
        out["frontend"].append(t1 - t0)
        ok = est is not None and est.success
        out["rot"].append(rotation_angle_deg(est.pose.orientation, f.orientation) if ok else np.nan)
        out["pos"].append(float(np.linalg.norm(est.pose.position - f.position)) if ok else np.nan)
        out["blank"].append(bool(blank))
        out["waited"].append(rep.refresh_waited)
        shuffled = np.nan
        if truth is not None and ok:
            gt, _ = truth[0].project(X, truth[1], f.t_first, occlusion=False)
            inl = np.asarray(est.inliers, bool) & np.isfinite(gt).all(axis=1)
            out["px_err"].append(np.linalg.norm(uv[inl] - gt[inl], axis=1))
            out["px_kind"].append(np.asarray(fe.last_kinds)[inl])
            if rep.kind == "tracked" and inl.sum() >= 6:
                e = (uv - gt)[inl]
                again = estimate_rs_pose(
                    gt[inl] + e[rng.permutation(len(e))], X[inl], camera, "r6p_1lin"
                )
                if again.success:
                    shuffled = float(np.linalg.norm(again.pose.position - f.position))
        out["pos_shuffled"].append(shuffled)
        if period_s > 0:  # (the truth's checks above run within the frame period)
            time.sleep(max(0.0, period_s - (time.perf_counter() - t0)))
    px = {k: out.pop(k) for k in ("px_err", "px_kind")}
    res = {k: np.array(v) for k, v in out.items()}
    res.update({k: np.concatenate(v) if v else np.zeros(0) for k, v in px.items()})
    return res


def median_ratio_interval(
    a: np.ndarray,
    b: np.ndarray,
    block: int = BLOCK_FRAMES,
    resamples: int = 2000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile interval of ``nanmedian(a) / nanmedian(b)`` by a paired moving-block
    bootstrap over frames (Kunsch, "The jackknife and the bootstrap for general stationary
    observations", Ann. Statist. 17(3), 1989): each resample draws ``ceil(n / block)`` runs of
    ``block`` consecutive frames with replacement (the same frames for ``a`` and ``b``) and
    takes the ratio of the two medians.

    How far a ratio of median errors measured on one video can be trusted: the per-frame
    errors of a video are correlated over neighbouring frames, so an interval from frames
    resampled one by one would be too narrow.

    Args:
        a, b: (n,) per-frame errors of the two methods on the same frames (NaN: not posed).
        block: frames per run (1 <= block <= n). resamples: bootstrap resamples.
        level: the interval's coverage (0 < level < 1). seed: the resampling's seed.
    Returns:
        ``(low, high)``, the ``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles of the
        resampled ratios (resamples in which a method posed no frame are left out).
    Raises:
        ValueError: ``a`` and ``b`` of other shapes than the same (n,), n < 1, or ``block``
            or ``level`` out of range.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.ndim != 1 or a.shape != b.shape or len(a) < 1:
        raise ValueError(f"a and b must be (n,) arrays of one length, got {a.shape}, {b.shape}")
    n = len(a)
    if not 1 <= block <= n or not 0.0 < level < 1.0:
        raise ValueError(f"block must be in [1, {n}] and level in (0, 1)")
    rng = np.random.default_rng(seed)
    runs = -(-n // block)
    starts = rng.integers(0, n - block + 1, size=(resamples, runs))
    idx = (starts[:, :, None] + np.arange(block)).reshape(resamples, -1)[:, :n]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a resample with no posed frame
        ratios = np.nanmedian(a[idx], axis=1) / np.nanmedian(b[idx], axis=1)
    ratios = ratios[np.isfinite(ratios)]
    q = (1.0 - level) / 2.0
    return float(np.quantile(ratios, q)), float(np.quantile(ratios, 1.0 - q))


def _ms(a: np.ndarray) -> str:
    if len(a) == 0:
        return "    -/    -"
    return f"{np.median(a) * 1e3:5.1f}/{np.percentile(a, 99) * 1e3:5.1f}"


def _first_last(r: dict) -> str:
    """Median rotation (deg) and position (cm) errors of the first and the last 50 frames."""
    a, b = slice(None, 50), slice(-50, None)
    return (
        f"{np.nanmedian(r['rot'][a]):.4f}/{np.nanmedian(r['rot'][b]):.4f} deg, "
        f"{np.nanmedian(r['pos'][a]) * 100:.3f}/{np.nanmedian(r['pos'][b]) * 100:.3f} cm"
    )


def _refound(r: dict) -> int | None:
    """Frames after the last blank frame until a frame is posed (0: the first one)."""
    blank = np.flatnonzero(r["blank"])
    if len(blank) == 0:
        return None
    after = np.flatnonzero(np.isfinite(r["rot"][blank[-1] + 1 :]))
    return int(after[0]) if len(after) else None


def main(argv: list | None = None) -> int:
    """Run the benchmark (see the module doc). Returns 0 when every target checked is met,
    else 1."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=300, help="frames per video (30 Hz)")
    ap.add_argument("--map-size", type=int, default=100_000, help="map descriptors")
    ap.add_argument("--blank", type=float, default=1.0, help="s of black frames in the walk")
    ap.add_argument("--seed", type=int, default=0, help="sensor noise seed")
    ap.add_argument(
        "--realtime",
        action="store_true",
        help="give the frames at 30 Hz (a live camera) instead of as fast as processed",
    )
    ap.add_argument(
        "--size", choices=["vga", "hd"], default="vga", help="640x480 (vga) or 1280x720 (hd)"
    )
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    scene = load_scene("textured_room")
    rs = camera_preset(args.size)
    gs = camera_preset(args.size, line_delay=0.0)
    duration = args.frames / FPS
    videos = {
        "hand-held": make_motion("shake", scene, duration=duration),
        "walk": make_motion("walk", scene, duration=duration, velocity=(0.0, 0.0, 0.2)),
    }
    t0 = time.perf_counter()
    maps = [
        build_feature_map(scene, gs, (m, np.linspace(0.0, duration, 6)), kind="sift")
        for m in videos.values()
    ]
    base = FeatureMap(
        np.concatenate([m.points for m in maps]),
        np.concatenate([m.descriptors for m in maps]).astype(np.float32),
        np.concatenate(
            [maps[0].landmark_ids, maps[1].landmark_ids + maps[0].landmark_ids.max() + 1]
        ),
        "sift",
    )
    fm = padded_map(base, args.map_size, seed=1)
    renderer = Renderer(scene, rs, noise=NoiseModel())
    print(
        f"map: {len(base)} SIFT descriptors from 12 renders, padded to {len(fm)} "
        f"({time.perf_counter() - t0:.0f} s); rendering {len(videos)} x {args.frames} frames "
        f"{rs.width}x{rs.height} RGB ..."
    )
    n_blank = int(round(args.blank * FPS))
    mid = args.frames // 2
    results = {}
    for name, motion in videos.items():
        frames = list(renderer.render_sequence(motion, args.frames, fps=FPS, seed=args.seed))
        blank = [name == "walk" and mid <= k < mid + n_blank for k in range(len(frames))]
        for tracking in (True, False):
            results[name, tracking] = run_video(
                fm,
                list(zip(frames, blank, strict=True)),
                rs,
                tracking,
                period_s=1.0 / FPS if args.realtime else 0.0,
                truth=(renderer, motion),
            )
    print(
        f"\n{args.frames} frames per video, {rs.width}x{rs.height}, map {len(fm)} descriptors, "
        "one thread; times median/p99 ms; frames given "
        + ("at 30 Hz" if args.realtime else "as fast as processed")
    )
    head = (
        f"{'video':10s} {'tracking':8s} {'kinds g/t':>9s} {'corr t/gd/gl':>13s} "
        f"{'track':>11s} {'guided':>11s} {'detect':>11s} {'estimate':>11s} "
        f"{'fe+est':>11s} {'deg':>7s} {'cm':>6s} {'posed':>7s}"
    )
    print(head)
    for (name, tracking), r in results.items():
        k = r["kind"]
        tr = k == "tracked"
        total = r["frontend"] + r["estimation"]
        print(
            f"{name:10s} {'on' if tracking else 'off':8s} "
            f"{np.sum(k == 'global'):4d}/{np.sum(tr):4d} "
            f"{np.median(r['tracked'][tr]) if tr.any() else 0:4.0f}/"
            f"{np.median(r['guided'][tr]) if tr.any() else 0:3.0f}/"
            f"{np.median(r['global'][~tr]) if (~tr).any() else 0:4.0f} "
            f"{_ms(r['tracking'][tr])} {_ms(r['guided_ms'][tr])} "
            f"{_ms(r['detection'][~tr])} {_ms(r['estimation'])} {_ms(total)} "
            f"{np.nanmedian(r['rot']):7.4f} {np.nanmedian(r['pos']) * 100:6.3f} "
            f"{np.sum(np.isfinite(r['rot'])):3d}/{len(k)}"
        )
        px = "; ".join(
            f"{kind} {np.median(r['px_err'][r['px_kind'] == i]):.3f}"
            for i, kind in enumerate(("tracked", "guided", "global"))
            if np.any(r["px_kind"] == i)
        )
        print(f"{'':19s} inliers' distance to the true projection, median px: {px}")
        if not tracking:
            print(f"{'':19s} first/last 50 frames {_first_last(r)}")
        if tracking and np.isfinite(r["pos_shuffled"]).any():
            off = results[name, False]["pos"]
            both = tr & np.isfinite(r["pos"]) & np.isfinite(off)
            print(
                f"{'':19s} tracked frames' position, median: {np.median(r['pos'][both]) * 100:.3f}"
                f" cm; the same pixel errors shuffled among each frame's inliers: "
                f"{np.nanmedian(r['pos_shuffled'][both]) * 100:.3f} cm; per-frame global "
                f"matching on these frames: {np.median(off[both]) * 100:.3f} cm"
            )
        if tracking:
            print(
                f"{'':19s} tracked frames fe+est {_ms(total[tr])}; global frames "
                f"{_ms(total[~tr])}; first/last 50 frames {_first_last(r)}; "
                f"{int(r['waited'].sum())} frames "
                "waited for a refresh"
                + (
                    f"; posed again {_refound(r)} frames after the blank"
                    if r["blank"].any()
                    else ""
                )
            )
    on_tr = [results[n, True] for n in videos]
    tr_tot = np.concatenate(
        [(r["frontend"] + r["estimation"])[r["kind"] == "tracked"] for r in on_tr]
    )
    # median-error ratio, tracking on to off, and its interval: (video, metric, the whole
    # video or only its last 50 frames) -> (ratio, low, high)
    ratios = {}
    for n in videos:
        for k in ("rot", "pos"):
            for part, sl, block in (
                ("all", slice(None), BLOCK_FRAMES),
                ("last", slice(-50, None), 10),
            ):
                on, off = results[n, True][k][sl], results[n, False][k][sl]
                ratios[n, k, part] = (
                    np.nanmedian(on) / np.nanmedian(off),
                    *median_ratio_interval(on, off, block=block),
                )
    print(
        "\nratios to per-frame global matching, median over the frames (95 % interval, "
        f"moving-block bootstrap of {BLOCK_FRAMES}-frame runs, 10-frame runs for the last 50):"
    )
    for n in videos:
        print(
            f"  {n:10s} "
            + "; ".join(
                "{} {:.2f}x [{:.2f}, {:.2f}], last 50 frames {:.2f}x [{:.2f}, {:.2f}]".format(
                    unit, *ratios[n, k, "all"], *ratios[n, k, "last"]
                )
                for k, unit in (("rot", "rotation"), ("pos", "position"))
            )
        )
    worst = max(r[0] for (_, _, part), r in ratios.items() if part == "all")
    # (the last 50 frames against per-frame global matching's last 50)
    drift = max(r[0] for (_, _, part), r in ratios.items() if part == "last")
    refound = _refound(results["walk", True])
    unposed = sum(int(np.sum(~np.isfinite(r["rot"]) & ~r["blank"])) for r in on_tr)
    targets = [
        (
            f"tracked frames front end + estimate median <= 15 ms "
            f"({np.median(tr_tot) * 1e3:.1f} ms)",
            bool(len(tr_tot)) and np.median(tr_tot) <= 0.015,
        ),
        (
            f"tracked frames p99 <= 40 ms ({np.percentile(tr_tot, 99) * 1e3:.1f} ms)",
            bool(len(tr_tot)) and np.percentile(tr_tot, 99) <= 0.040,
        ),
        (f"accuracy within 1.1x of per-frame global matching ({worst:.2f}x)", worst <= 1.1),
        (
            f"no drift: last 50 frames within 1.1x of per-frame global matching ({drift:.2f}x)",
            drift <= 1.1,
        ),
        (f"every frame with a view posed ({unposed} not)", unposed == 0),
        (
            f"posed again within 2 frames after the blank ({refound} frames)",
            refound is not None and refound <= 2,
        ),
    ]
    print("\ntargets:")
    for text, ok in targets:
        print(f"  [{'x' if ok else ' '}] {text}")
    return 0 if all(ok for _, ok in targets) else 1


if __name__ == "__main__":
    sys.exit(main())
