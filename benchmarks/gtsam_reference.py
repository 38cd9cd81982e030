"""A TagSLAM recording's reference from TagSLAM's own factor graph optimized in batch by GTSAM
(:func:`solve_gtsam`, :func:`gtsam_reference` with its cache), an optimum independent of
rs_localizer's code, and the recording's figures measured against it (:func:`main`).

TagSLAM publishes its rig poses while it runs; unless it runs in ``optimizer_mode: slow`` they
are not optimized again with the later frames. Its factor graph is kept here as it is: the
unknowns are every rig (body) pose of a rig frame with a reference pose, every camera's
extrinsics and every tag's pose; each tag seen by a camera in a rig frame gives one factor of
its 4 corners' errors in the distorted image (px), isotropic noise of ``pixel_noise`` = 1 px,
no robust loss; the cameras are equidistant (fisheye) ones, GTSAM's ``Cal3Fisheye`` (OpenCV's
fisheye model). The gauge is TagSLAM's: the tags ``tagslam.yaml`` gives a pose
(:attr:`~benchmarks.tagslam_data.RealRig.anchors`) and the first camera's extrinsics
(``camera_poses.yaml``'s prior) are held at the published solution's by priors of 1e-6 (rad,
m). GTSAM's Levenberg-Marquardt optimizer minimizes it from TagSLAM's published solution; the
Jacobians come from GTSAM's own ``Pose3.compose``, ``Pose3.transformFrom`` and
``PinholeCameraCal3Fisheye.project``. The result is a
:class:`~benchmarks.joint_reference.JointSolution`, so
:func:`~benchmarks.joint_reference.with_reference` measures a recording against it.

GTSAM is an optional dependency of the benchmarks (``pip install gtsam``); without it
:func:`solve_gtsam` raises ImportError saying so.
"""

from __future__ import annotations

import hashlib
import time
from pathlib import Path

import numpy as np

from benchmarks.joint_reference import JointSolution, cached_solution
from benchmarks.tagslam_data import RealRig, errors, tag_corners

__all__ = [
    "CACHE",
    "GTSAM_MISSING",
    "distances",
    "gtsam_reference",
    "import_gtsam",
    "main",
    "solve_gtsam",
]

#: where :func:`gtsam_reference` keeps its solutions (outside the repository)
CACHE = Path("/tmp/rs_localizer_gtsam_reference")
#: rad and m; the priors holding TagSLAM's gauge (its anchored tags, its first camera)
_GAUGE_SIGMA = 1e-6
#: what :func:`import_gtsam` says without GTSAM
GTSAM_MISSING = (
    "benchmarks.gtsam_reference needs GTSAM's Python package (4.3 or later): pip install gtsam"
)
# (Levenberg-Marquardt's bounds: at most 100 iterations, a relative and absolute error
# decrease of 1e-10 to stop at; every recording measured stops within 10)
_MAX_ITERATIONS, _TOL = 100, 1e-10


def import_gtsam():
    """The ``gtsam`` module.

    Raises:
        ImportError: GTSAM is not installed (the message names ``pip install gtsam``).
    """
    try:
        import gtsam
    except ImportError as exc:
        raise ImportError(GTSAM_MISSING) from exc
    return gtsam


def _calibration(gtsam, cam):
    """GTSAM's ``Cal3Fisheye`` of an ``equidistant``
    :class:`~rs_localizer.camera.CameraModel` (OpenCV's fisheye model, as TagSLAM's)."""
    if cam.distortion_model != "equidistant":
        raise ValueError(f"a {cam.distortion_model} camera: only equidistant (fisheye) ones")
    K = cam.K
    k = [*np.asarray(cam.D, float).ravel()[:4], 0.0, 0.0, 0.0, 0.0][:4]
    return gtsam.Cal3Fisheye(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2], *k)


def _pose3(gtsam, R: np.ndarray, t: np.ndarray):
    return gtsam.Pose3(gtsam.Rot3(np.asarray(R, float)), np.asarray(t, float))


def _tag_error(gtsam, uv: np.ndarray, corners: np.ndarray, K):
    """A ``CustomFactor``'s error function of one tag seen by one camera in one rig frame: its
    keys the rig (body -> world), the camera (camera -> body) and the tag (tag -> world)
    poses; (8,) the 4 corners' projections (``corners`` (4, 3) m in the tag's frame) minus
    ``uv`` (8,) px, with the (8, 6) Jacobians by each key."""
    corners = [np.array(c, float) for c in corners]
    uv = np.array(uv, float)

    def error(this, values, H):
        kb, km, kt = this.keys()
        Twb, Tbc, Twt = values.atPose3(kb), values.atPose3(km), values.atPose3(kt)
        if H is None:
            cam = gtsam.PinholeCameraCal3Fisheye(Twb.compose(Tbc), K)
            return np.concatenate([cam.project(Twt.transformFrom(c)) for c in corners]) - uv
        Hb, Hm = np.zeros((6, 6), order="F"), np.zeros((6, 6), order="F")
        cam = gtsam.PinholeCameraCal3Fisheye(Twb.compose(Tbc, Hb, Hm), K)
        Ht, Hp = np.zeros((3, 6), order="F"), np.zeros((3, 3), order="F")
        Dc, Dp = np.zeros((2, 6), order="F"), np.zeros((2, 3), order="F")
        Dk = np.zeros((2, 9), order="F")
        e, Jc, Jt = np.empty(8), np.empty((8, 6)), np.empty((8, 6))
        for k, c in enumerate(corners):
            e[2 * k : 2 * k + 2] = cam.project(Twt.transformFrom(c, Ht, Hp), Dc, Dp, Dk)
            Jc[2 * k : 2 * k + 2] = Dc
            Jt[2 * k : 2 * k + 2] = Dp @ Ht
        H[0], H[1], H[2] = Jc @ Hb, Jc @ Hm, Jt
        return e - uv

    return error


def _stamps(rig: RealRig, frames: int | None) -> list:
    """The rig frames with a reference pose (``frames``: the first that many of them)."""
    return [s for s, _ in rig.frames if s in rig.reference][:frames]


def solve_gtsam(
    rig: RealRig, frames: int | None = None, max_iterations: int = _MAX_ITERATIONS
) -> JointSolution:
    """TagSLAM's factor graph of ``rig`` (a :class:`~benchmarks.tagslam_data.RealRig` with its
    tag poses, :func:`~benchmarks.tagslam_data.load_tagslam`; equidistant cameras) optimized
    in batch by GTSAM's Levenberg-Marquardt from its reference (the module's docstring):
    every rig pose of a rig frame with a reference pose (``frames``: the first that many, a
    contiguous window), every tag's pose and every camera's extrinsics, the anchored tags and
    the first camera held by TagSLAM's gauge priors. A tag whose corners the start does not
    project (a corner behind its camera) is left out of that view.

    Returns:
        a :class:`~benchmarks.joint_reference.JointSolution` (poses ``x_rig = R X + C``,
        tags ``x_map = R x_tag + p``, mounts ``x_cam = R x_rig + c``); ``info``: ``seconds``
        (CPU), ``iterations``, ``cost_start``, ``cost`` (GTSAM's error: half the sum of the
        squared corner errors, px^2), ``corners``, ``outliers`` (corners left out).
    Raises:
        ImportError: GTSAM is not installed. ValueError: the rig has no tag poses, no rig
        frame with a reference pose or a camera that is not equidistant.
    """
    gtsam = import_gtsam()
    from gtsam.symbol_shorthand import B, M, T

    stamps = _stamps(rig, frames)
    if not rig.tags or not stamps:
        raise ValueError(f"{rig.name}: no tag poses or no rig frame with a reference pose")
    t0 = time.process_time()
    names = list(rig.cameras)
    cal = {n: _calibration(gtsam, c) for n, c in rig.cameras.items()}
    start = gtsam.Values()
    for i, (R, p, _) in rig.tags.items():
        start.insert(T(i), _pose3(gtsam, R, p))
    for j, n in enumerate(names):
        R, c = rig.mounts[n]
        start.insert(M(j), _pose3(gtsam, R.T, -R.T @ c))
    for f, s in enumerate(stamps):
        R, C = rig.reference[s]
        start.insert(B(f), _pose3(gtsam, R.T, -R.T @ C))
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(8, 1.0)
    views_of = dict(rig.frames)
    corners = outliers = 0
    for f, s in enumerate(stamps):
        for n, (uv, _) in views_of[s].items():
            j = names.index(n)
            for q, i in enumerate(rig.tag_ids[s][n]):
                fn = _tag_error(gtsam, uv[4 * q : 4 * q + 4].ravel(),
                                tag_corners(rig.tags[i][2]), cal[n])  # fmt: skip
                factor = gtsam.CustomFactor(noise, [B(f), M(j), T(i)], fn)
                try:
                    factor.error(start)
                except RuntimeError:  # (GTSAM's cheirality exception: behind the camera)
                    outliers += 4
                    continue
                graph.add(factor)
                corners += 4
    gauge = gtsam.noiseModel.Isotropic.Sigma(6, _GAUGE_SIGMA)
    for i in sorted(rig.anchors):
        graph.add(gtsam.PriorFactorPose3(T(i), start.atPose3(T(i)), gauge))
    graph.add(gtsam.PriorFactorPose3(M(0), start.atPose3(M(0)), gauge))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(_TOL)
    params.setAbsoluteErrorTol(_TOL)
    params.setMaxIterations(max_iterations)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, start, params)
    cost_start = graph.error(start)
    res = opt.optimize()

    def inverse(P):  # (Pose3 a -> b as x_a = R x_b + c)
        R = P.rotation().matrix().T
        return R, -R @ P.translation()

    poses = {s: inverse(res.atPose3(B(f))) for f, s in enumerate(stamps)}
    tags = {
        i: (res.atPose3(T(i)).rotation().matrix(), res.atPose3(T(i)).translation(), side)
        for i, (_, _, side) in rig.tags.items()
    }
    mounts = {n: inverse(res.atPose3(M(j))) for j, n in enumerate(names)}
    info = {
        "seconds": time.process_time() - t0,
        "iterations": int(opt.iterations()),
        "cost_start": float(cost_start),
        "cost": float(graph.error(res)),
        "corners": corners,
        "outliers": outliers,
    }
    return JointSolution(poses, tags, mounts, info)


def _key(rig: RealRig, frames: int | None) -> str:
    """A digest of what the solution depends on: the corners, the start, the window and the
    optimizer's bounds."""
    h = hashlib.sha1(repr((frames, _MAX_ITERATIONS, _TOL, _GAUGE_SIGMA)).encode())
    for stamp in _stamps(rig, frames):
        h.update(np.float64(stamp).tobytes())
        h.update(np.ascontiguousarray(rig.reference[stamp][1]).tobytes())
        views = dict(rig.frames)[stamp]
        for name in sorted(views):
            h.update(name.encode())
            h.update(np.ascontiguousarray(views[name][0]).tobytes())
    for i in sorted(rig.tags):
        h.update(np.ascontiguousarray(rig.tags[i][1]).tobytes())
    for n in sorted(rig.mounts):
        h.update(np.ascontiguousarray(rig.mounts[n][1]).tobytes())
    return h.hexdigest()[:16]


def gtsam_reference(
    rig: RealRig, cache: Path | None = CACHE, frames: int | None = None
) -> JointSolution:
    """:func:`solve_gtsam`'s solution of ``rig`` (``frames``: its window), read from ``cache``
    (a folder; None: none) when it holds one of the same corners, start and window, else
    solved and saved there (``<name>_<digest>.npz``).

    Raises:
        ImportError: not cached and GTSAM is not installed. ValueError: as
        :func:`solve_gtsam`.
    """
    path = None if cache is None else Path(cache) / f"{rig.name}_{_key(rig, frames)}.npz"
    return cached_solution(path, lambda: solve_gtsam(rig, frames))


def distances(rig: RealRig, sol: JointSolution, poses: dict, mounts: dict, tags: dict) -> dict:
    """Another solution of ``rig`` (``poses``: stamp -> ``(R, C)``, ``x_rig = R X + C``;
    ``mounts``: camera -> ``(R, c)``; ``tags``: id -> ``(R, p, side)``, as
    :class:`~benchmarks.tagslam_data.RealRig` holds them) against ``sol``: ``"poses"``
    (rig frames of ``sol`` with tags in two or more cameras): rotation deg and position mm,
    ``(median (2,), p90 (2,), max (2,))``, ``"frames"`` their number; ``"mounts"``: camera ->
    ``(deg, mm)``; ``"tags"``: ``(median (2,), max (2,))`` over the tags (deg, mm of their
    centres)."""
    views = dict(rig.frames)
    d = np.array([errors(*poses[s], sol.poses[s]) for s in sol.poses
                  if s in poses and len(views[s]) >= 2]).reshape(-1, 2)  # fmt: skip
    m = {n: errors(R, c, sol.mounts[n]) for n, (R, c) in mounts.items()}
    t = np.array([errors(tags[i][0].T, -tags[i][0].T @ tags[i][1],
                         (sol.tags[i][0].T, -sol.tags[i][0].T @ sol.tags[i][1]))
                  for i in sol.tags if i in tags]).reshape(-1, 2)  # fmt: skip
    return {
        "poses": (np.median(d, axis=0), np.percentile(d, 90, axis=0), np.max(d, axis=0)),
        "frames": len(d),
        "mounts": m,
        "tags": (np.median(t, axis=0), np.max(t, axis=0)),
    }


def _print_distances(label: str, d: dict) -> None:
    (r, p), (r9, p9), (rx, px) = d["poses"]
    print(
        f"  {label} vs the GTSAM optimum: rig poses ({d['frames']} rig frames with tags in two "
        f"or more cameras) median {r:.3f} deg {p:.2f} mm, p90 {r9:.3f} deg {p9:.2f} mm, max "
        f"{rx:.3f} deg {px:.2f} mm; mountings "
        + ", ".join(f"{n} {a:.3f} deg {b:.2f} mm" for n, (a, b) in d["mounts"].items())
        + f"; tags median {d['tags'][0][0]:.3f} deg {d['tags'][0][1]:.2f} mm, max "
        f"{d['tags'][1][0]:.3f} deg {d['tags'][1][1]:.2f} mm"
    )


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks.gtsam_reference --folder PATH/test_N``: TagSLAM's factor graph
    of the recording optimized in batch by GTSAM (cached), then against that optimum:
    TagSLAM's published solution; with ``--scipy-check`` SciPy's least squares of the same
    cost started at the optimum (how far it moves); the joint solution
    (``benchmarks.joint_reference``, soft_l1; ``--no-joint`` leaves it out);
    ``calibrate-rig`` (the first of ``--min-inliers`` that calibrates every camera) on
    TagSLAM's tag map and on the optimum's, each camera's mounting's error, std, largest error
    over std of its 6 axes, NEES, and the rig posed with the latter's mountings, rig poses
    within 3 sigma of the optimum's (``--no-calibrate`` leaves them out); the rig estimator
    against PoseLib's generalized pose with the optimum's map and extrinsics (medians and
    their ratio; ``--no-poselib`` leaves it out)."""
    from benchmarks.bench_real_rig import rig_run, summary
    from benchmarks.joint_reference import (
        CACHE as JOINT_CACHE,
    )
    from benchmarks.joint_reference import (
        joint_reference,
        mounting_coverage,
        print_coverage,
        recording_parser,
        solve_joint,
        with_reference,
    )
    from benchmarks.real_rig_mountings import calibrate_every_camera, calibrated_rig_run
    from benchmarks.tagslam_data import load_tagslam
    from rs_localizer.experiments.timing import one_thread

    ap = recording_parser(main.__doc__)
    ap.set_defaults(cache=CACHE)
    ap.add_argument("--joint-cache", type=Path, default=JOINT_CACHE)
    ap.add_argument(
        "--frames", type=int, default=None, help="the first N rig frames with a reference pose"
    )
    ap.add_argument("--min-inliers", type=int, nargs="+", default=[20, 8])
    ap.add_argument("--no-joint", action="store_true", help="leave out the joint solution")
    ap.add_argument("--no-poselib", action="store_true", help="leave out the PoseLib ratio")
    ap.add_argument(
        "--no-calibrate", action="store_true", help="leave out calibrate-rig and the rig posed"
    )
    ap.add_argument(
        "--scipy-check",
        action="store_true",
        help="also start SciPy's least squares of the same cost (benchmarks.joint_reference, "
        "soft_l1 at 10^4 px: plain least squares) at the optimum and say how far it moves",
    )
    a = ap.parse_args(argv)
    if not a.folder.is_dir():
        print(f"{a.folder} absent: nothing to measure")
        return
    rig = load_tagslam(a.folder)
    sol = gtsam_reference(rig, a.cache, a.frames)
    info = sol.info
    print(
        f"{rig.name}: TagSLAM's factor graph optimized by GTSAM (batch Levenberg-Marquardt, "
        f"{len(sol.poses)} rig frames{'' if a.frames is None else ' (a window)'}, "
        f"{info['corners']} corners, {info['outliers']} left out): cost (half the sum of "
        f"squared px) {info['cost_start']:.1f} at TagSLAM's solution -> {info['cost']:.1f} "
        f"in {info['iterations']} iterations, {info['seconds']:.1f} s CPU"
    )
    _print_distances("TagSLAM's solution", distances(rig, sol, rig.reference, rig.mounts,
                                                     rig.tags))  # fmt: skip
    if a.scipy_check:
        p = solve_joint(with_reference(rig, sol), f_scale=1e4, ftol=1e-12)
        print(
            f"  SciPy's least squares of the same cost started at the optimum: cost "
            f"{p.info['cost_start']:.4f} -> {p.info['cost']:.4f} in {p.info['nfev']} evaluations"
        )
        _print_distances("its solution", distances(rig, sol, p.poses, p.mounts, p.tags))
    if not a.no_joint:
        j = joint_reference(rig, a.joint_cache)
        _print_distances("joint solution (soft_l1)", distances(rig, sol, j.poses, j.mounts,
                                                               j.tags))  # fmt: skip
    g = with_reference(rig, sol)
    first = next(iter(rig.cameras))
    with one_thread():
        maps = (("TagSLAM's", rig), ("the GTSAM optimum's", g))
        for label, r in () if a.no_calibrate else maps:
            est, mi = calibrate_every_camera(r, a.min_inliers)
            if est is None:
                print(f"calibrate-rig on {label} tag map: no camera calibrated")
                continue
            print(
                f"calibrate-rig (min_inliers {mi}) on {label} tag map vs the GTSAM optimum's "
                "mountings: error deg, mm; std deg, mm; largest |error| / std of the 6 axes; "
                "NEES (6)"
            )
            print_coverage(mounting_coverage(est, sol.mounts, first), rig.cameras)
            if r is not g:
                continue
            for v, (inside, posed, total) in calibrated_rig_run(g, est).items():
                print(
                    f"  the rig with these mountings ({v}): {inside} of {posed} rig poses "
                    f"within 3 sigma of the GTSAM optimum's ({100 * inside / max(posed, 1):.1f}"
                    f" %; {total} rig frames)"
                )
        if a.no_poselib:
            return
        s = summary(rig_run(g))
        (o_r, o_p), (p_r, p_p) = (np.median(s[k], axis=0) for k in ("ours", "poselib"))
        print(
            f"the rig estimator vs PoseLib's generalized pose on the GTSAM optimum's map and "
            f"extrinsics ({s['posed']} of {s['both']} rig frames with tags in two or more "
            f"cameras posed), median error from the optimum's poses: ours {o_r:.3f} deg "
            f"{o_p:.2f} mm, PoseLib {p_r:.3f} deg {p_p:.2f} mm; ratio rotation "
            f"{s['ratio_rot']:.2f}, position {s['ratio_pos']:.2f}"
        )


if __name__ == "__main__":
    main()
