"""Which set of a rig's mountings fits corners it was not estimated from: a held-out check of
``calibrate-rig`` against a TagSLAM recording's references.

The recording's rig frames are cut into ``blocks`` runs of consecutive rig frames, the even
runs one part, the odd runs the other (:func:`split`): each part spans the whole video (every
camera sees tags in both, so each part calibrates every camera), and consecutive rig frames,
whose errors are alike (the same view of the same tags a frame apart), stay in one part but
at the runs' ends. ``calibrate-rig``
(:func:`~rs_localizer.calibration.calibrate_mountings`, as
:func:`benchmarks.real_rig_mountings.calibrate_estimates` calls it) calibrates the mountings on
one part; on the other part every candidate set of mountings is scored the same way:

* **held-out reprojection** (:func:`reprojection`): each rig frame's pose fitted to all its
  cameras' corners with the candidate's mountings held fixed
  (:class:`~benchmarks.joint_reference.TagSLAMCorners`, every mounting fixed, the map
  points fixed; each corner's error in pixels of its camera's distorted image, the soft-L1
  loss of its distance at ``f_scale`` px, SciPy ``least_squares``), then each corner's error
  at that pose: per camera its median, 90th percentile and RMS (px), over the corners every
  candidate keeps;
* **cameras posed alone** (:func:`alone_poses`, :func:`relative_disagreement`): every camera
  frame of two or more tags posed alone on the map (the same solve, a rig of one camera), the
  relative pose of two cameras in one rig frame against the candidate's (rotation deg,
  position of the second camera in the first's frame, mm): the median of the per-frame
  disagreement and the disagreement of the per-frame relative poses' median (axis by axis).

Every candidate is scored on the same rig frames (those with a reference pose and tags in two
or more cameras), on the same tag map; ``calibrate-rig``'s on the part it did not see, the
two parts' scores pooled. The references (TagSLAM's extrinsics, the joint solution's,
:mod:`benchmarks.joint_reference`) were estimated from every rig frame, the held-out ones
too, and the joint solution's map with the joint solution's mountings: the check favours them.
So does it ``calibrate-rig`` on every rig frame (``"calibrate-rig, all"``), scored next to
them in-sample as they are; the held-out candidate, from half the rig frames, carries that
half's noise besides.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.joint_reference import (
    TagSLAMCorners,
    recording,
    recording_parser,
    rig_part,
    soft_l1,
    with_reference,
)
from benchmarks.tagslam_data import RealRig
from rs_localizer.geometry import matrix_to_rotvec

__all__ = [
    "Scores",
    "alone_poses",
    "calibrated_mounts",
    "given_extrinsics",
    "held_out",
    "main",
    "relative_disagreement",
    "report",
    "reprojection",
    "split",
]


def split(rig: RealRig, blocks: int = 10) -> tuple[list, list]:
    """``rig.frames`` cut into ``blocks`` runs of consecutive rig frames (as equal as they
    divide): the even runs' frames, the odd runs'."""
    runs = np.array_split(np.arange(len(rig.frames)), blocks)
    parts: tuple[list, list] = ([], [])
    for k, run in enumerate(runs):
        parts[k % 2].extend(rig.frames[i] for i in run)
    return parts


def calibrated_mounts(rig: RealRig, min_inliers=(20, 8)) -> tuple[dict, int]:
    """``calibrate-rig``'s mountings of ``rig`` (its frames and tag map; the first camera at
    its reference mounting), with the first of ``min_inliers`` that calibrates every camera
    (:func:`~benchmarks.real_rig_mountings.calibrate_every_camera`): ``(camera -> (R (3, 3), c
    (3,) m) as RealRig.mounts, the min_inliers)``.

    Raises:
        ValueError: no ``min_inliers`` calibrates every camera.
    """
    from benchmarks.real_rig_mountings import calibrate_every_camera

    why: dict = {}  # min_inliers -> why it did not calibrate every camera
    est, mi = calibrate_every_camera(rig, min_inliers, why.__setitem__)
    if est is not None and all(n in est for n in rig.cameras):
        return {n: (est[n].mount.R, est[n].mount.c) for n in rig.cameras}, mi
    if est is not None:
        why[mi] = f"{sorted(set(rig.cameras) - set(est))} not calibrated"
    said = "; ".join(f"{k}: {why[k]}" for k in min_inliers if k in why)
    raise ValueError(f"{rig.name}: calibrate-rig with min_inliers {list(min_inliers)}: {said}")


def given_extrinsics(folder: Path) -> dict:
    """The extrinsics ``camera_poses.yaml`` gives TagSLAM (each camera's pose in the rig: its
    position, m, and rotation vector, rad, camera -> rig), as :attr:`RealRig.mounts` (camera
    -> ``(R, c)``, ``x_cam = R x_rig + c``); {} without the file."""
    import yaml

    from rs_localizer.geometry import rotvec_to_matrix

    path = Path(folder) / "camera_poses.yaml"
    if not path.is_file():
        return {}
    out = {}
    for name, v in (yaml.safe_load(path.read_text()) or {}).items():
        p, r = v["pose"]["position"], v["pose"]["rotation"]
        R = rotvec_to_matrix(np.array([r[k] for k in "xyz"], dtype=float)).T
        out[name] = (R, -R @ np.array([p[k] for k in "xyz"], dtype=float))
    return out


def _rig_frames(rig: RealRig, frames: list) -> list:
    """The rig frames of ``frames`` with a reference pose and tags in two or more cameras."""
    return [(s, v) for s, v in frames if s in rig.reference and len(v) >= 2]


def reprojection(rig: RealRig, frames: list, mounts: dict, f_scale: float = 2.0) -> dict:
    """Each rig frame of ``frames`` (``(stamp, {camera: (uv, X)})``; each needs a pose in
    ``rig.reference`` to start from) posed on all its cameras' corners with ``mounts``
    (camera -> ``(R, c)``, ``x_cam = R x_rig + c``) held fixed, the map points ``X`` fixed
    (:class:`~benchmarks.joint_reference.TagSLAMCorners`, soft-L1 loss of each corner's
    distance at ``f_scale`` px): ``{"error": (N,) px each corner's distance at the fitted pose
    (NaN: not projected at the start), "camera": (N,) camera index (``rig.cameras``' order),
    "frame": (N,) index into frames}``."""
    names = list(rig.cameras)
    uv, X, cam, fr = [], [], [], []
    for f, (_, views) in enumerate(frames):
        for n, (u, x) in views.items():
            uv.append(u)
            X.append(x)
            cam.append(np.full(len(u), names.index(n)))
            fr.append(np.full(len(u), f))
    uv, X, cam, fr = (np.concatenate(a) for a in (uv, X, cam, fr))
    R0 = np.array([rig.reference[s][0] for s, _ in frames])
    C0 = np.array([rig.reference[s][1] for s, _ in frames])
    Rm = np.array([mounts[n][0] for n in names])
    cm = np.array([mounts[n][1] for n in names])
    problem = TagSLAMCorners(uv, [rig.cameras[n] for n in names], cam, fr, cam, (R0, C0),
                             (Rm, cm), np.zeros(len(names), bool), X)  # fmt: skip
    sol = problem.solve(f_scale, loss="corner_soft_l1", max_nfev=100, ftol=1e-10, xtol=1e-10)
    err = np.full(len(uv), np.nan)
    if sol is not None:
        e = problem.errors(sol.result.x)
        err = np.where(sol.keep, np.linalg.norm(e, axis=1), np.nan)
    return {"error": err, "camera": cam, "frame": fr}


def alone_poses(rig: RealRig, frames: list, f_scale: float = 2.0, min_tags: int = 2) -> dict:
    """Every camera frame of ``frames`` with ``min_tags`` tags or more posed alone on the map
    (the same solve as :func:`reprojection`, a rig of one camera at the identity mounting;
    started at the rig frame's reference pose through ``rig.mounts``): ``{(frame index,
    camera): (R (3, 3) world -> camera, C (3,) m)}``."""
    names = list(rig.cameras)
    keys, uv, X, cam, g = [], [], [], [], []
    for f, (_, views) in enumerate(frames):
        for n, (u, x) in views.items():
            if len(u) >= 4 * min_tags:
                g.append(np.full(len(u), len(keys)))
                keys.append((f, n))
                uv.append(u)
                X.append(x)
                cam.append(np.full(len(u), names.index(n)))
    if not keys:
        return {}
    uv, X, cam, g = (np.concatenate(a) for a in (uv, X, cam, g))
    R0, C0 = [], []
    for f, n in keys:
        R, C = rig.reference[frames[f][0]]
        Rm, cm = rig.mounts[n]
        R0.append(Rm @ R)
        C0.append(Rm @ C + cm)
    problem = TagSLAMCorners(uv, [rig.cameras[n] for n in names], cam, g,
                             np.zeros(len(uv), int), (np.array(R0), np.array(C0)),
                             (np.eye(3)[None], np.zeros((1, 3))), np.zeros(1, bool), X)  # fmt: skip
    sol = problem.solve(f_scale, loss="corner_soft_l1", max_nfev=100, ftol=1e-10, xtol=1e-10)
    if sol is None:
        return {}
    Rf, Cf = sol.rig
    return {k: (Rf[i], Cf[i]) for i, k in enumerate(keys)}


def _relative(Ra, ca, Rb, cb):
    """Camera a -> camera b rotation and camera b's centre in camera a's frame (m) of two
    poses ``x_a = Ra x + ca``, ``x_b = Rb x + cb`` of one frame ``x``."""
    return Rb @ Ra.T, Ra @ (-Rb.T @ cb) + ca


def relative_disagreement(poses: dict, candidates: dict, pairs: list) -> dict:
    """Per camera pair ``(a, b)`` of ``pairs`` and candidate (name -> camera -> ``(R, c)``;
    a value may be a list, one per frame index, when the candidate differs by frame: None
    there skips it): the relative pose of ``a`` and ``b`` posed alone in one rig frame
    (:func:`alone_poses`' ``poses``) against the candidate's mountings' -> ``{"frames",
    "median_deg", "median_mm": the per-frame disagreements' medians, "bias_deg", "bias_mm":
    the norm of the per-frame differences' median (rotation vector and position, axis by
    axis)}``."""
    out = {}
    frames_of: dict = {}
    for f, n in poses:
        frames_of.setdefault(f, set()).add(n)
    for a, b in pairs:
        fs = sorted(f for f, ns in frames_of.items() if a in ns and b in ns)
        for name, cand in candidates.items():
            rows = []
            for f in fs:
                m = cand(f) if callable(cand) else cand
                if m is None:
                    continue
                Rr, pr = _relative(*poses[(f, a)], *poses[(f, b)])
                Rc, pc = _relative(*m[a], *m[b])
                rows.append(np.r_[matrix_to_rotvec(Rr @ Rc.T), pr - pc])
            if not rows:
                continue
            d = np.array(rows)
            med = np.median(d, axis=0)
            out[(a, b, name)] = {
                "frames": len(d),
                "median_deg": float(np.rad2deg(np.median(np.linalg.norm(d[:, :3], axis=1)))),
                "median_mm": float(1e3 * np.median(np.linalg.norm(d[:, 3:], axis=1))),
                "bias_deg": float(np.rad2deg(np.linalg.norm(med[:3]))),
                "bias_mm": float(1e3 * np.linalg.norm(med[3:])),
            }
    return out


@dataclass
class Scores:
    """A candidate's held-out reprojection: per camera (``rig.cameras``' order) and in total
    (last) the corners, median, 90th percentile and RMS of their errors (px); ``cost``: the
    corners' mean soft-L1 loss at 2 px (px^2, the fit's robust cost per corner, in total);
    ``frame_median`` (F,) px each rig frame's median corner error (for paired comparisons)."""

    corners: list
    median: list
    p90: list
    rms: list
    frame_median: np.ndarray
    cost: float = np.nan


def _scores(res: dict, keep: np.ndarray, n_cams: int, n_frames: int) -> Scores:
    e, cam, fr = res["error"][keep], res["camera"][keep], res["frame"][keep]
    out = Scores([], [], [], [], np.full(n_frames, np.nan), float(np.mean(soft_l1(e * e, 2.0))))
    for sel in [cam == i for i in range(n_cams)] + [np.ones(len(e), bool)]:
        x = e[sel]
        out.corners.append(len(x))
        ok = len(x) > 0
        out.median.append(float(np.median(x)) if ok else np.nan)
        out.p90.append(float(np.percentile(x, 90)) if ok else np.nan)
        out.rms.append(float(np.sqrt(np.mean(x * x))) if ok else np.nan)
    order = np.argsort(fr, kind="stable")
    fs, starts = np.unique(fr[order], return_index=True)
    for f, part in zip(fs, np.split(e[order], starts[1:]), strict=True):
        out.frame_median[f] = np.median(part)
    return out


def held_out(
    rig: RealRig,
    references: dict,
    blocks: int = 10,
    min_inliers=(20, 8),
    f_scale: float = 2.0,
    min_tags: int = 2,
    whole: bool = True,
) -> dict:
    """The held-out check of ``rig`` (its tag map; its reference poses start each rig
    frame's fit): ``calibrate-rig`` on each part of :func:`split` scored on the other part,
    next to ``references`` (name -> camera -> ``(R, c)``) scored on the same rig frames.
    ``whole``: also ``calibrate-rig`` on every rig frame, the scored ones too (candidate
    ``"calibrate-rig, all"``), in-sample as the references are: what its mountings fit when
    they have seen the corners, next to the held-out ones (the difference: the calibration's
    noise from half the rig frames). Returns ``{"scores": name -> :class:`Scores`, "alone":
    :func:`relative_disagreement`'s, "min_inliers": per part, "frames": the rig frames scored,
    "names": candidates}``; ``calibrate-rig``'s held-out candidate is ``"calibrate-rig"``.

    Raises:
        ValueError: a part ``calibrate-rig`` cannot calibrate every camera on.
    """
    parts = split(rig, blocks)
    ours, used = [], []
    for k in (1, 0):  # (the mountings scored on part k come from the other part)
        m, mi = calibrated_mounts(rig_part(rig, parts[k]), min_inliers)
        ours.append(m)
        used.append(mi)
    scored = [_rig_frames(rig, p) for p in parts]
    frames = scored[0] + scored[1]
    owner = np.r_[np.zeros(len(scored[0]), int), np.ones(len(scored[1]), int)]
    references = dict(references)
    if whole:
        references["calibrate-rig, all"] = calibrated_mounts(rig, min_inliers)[0]
    names = ["calibrate-rig", *references]
    res = {}
    for name in names:
        if name == "calibrate-rig":
            a = reprojection(rig, scored[0], ours[0], f_scale)
            b = reprojection(rig, scored[1], ours[1], f_scale)
            b["frame"] = b["frame"] + len(scored[0])
            res[name] = {k: np.concatenate([a[k], b[k]]) for k in a}
        else:
            res[name] = reprojection(rig, frames, references[name], f_scale)
    keep = np.logical_and.reduce([np.isfinite(r["error"]) for r in res.values()])
    cams = list(rig.cameras)
    scores = {n: _scores(res[n], keep, len(cams), len(frames)) for n in names}
    poses = alone_poses(rig, frames, f_scale, min_tags)
    pairs = [(a, b) for i, a in enumerate(cams) for b in cams[i + 1 :]]
    cands = {n: references[n] for n in references}
    cands["calibrate-rig"] = lambda f: ours[owner[f]]
    alone = relative_disagreement(poses, cands, pairs)
    return {"scores": scores, "alone": alone, "min_inliers": used, "frames": len(frames),
            "names": names}  # fmt: skip


def _paired(a: np.ndarray, b: np.ndarray, chunks: int = 10) -> tuple[float, float]:
    """The mean of ``a - b`` over the rig frames both have (px) and its standard error from
    ``chunks`` runs of consecutive frames (neighbouring frames' errors are alike)."""
    ok = np.isfinite(a) & np.isfinite(b)
    d = (a - b)[ok]
    if len(d) < chunks:
        return float(np.mean(d)) if len(d) else np.nan, np.nan
    m = np.array([c.mean() for c in np.array_split(d, chunks)])
    return float(d.mean()), float(m.std(ddof=1) / np.sqrt(chunks))


def report(rig: RealRig, out: dict, label: str) -> None:
    """Print :func:`held_out`'s result (``label``: the tag map's name)."""
    cams = list(rig.cameras)
    sc = out["scores"]
    print(
        f"{rig.name}, {label} tag map: {out['frames']} rig frames with tags in two or more "
        f"cameras scored (calibrate-rig min_inliers per part {out['min_inliers']})"
    )
    print("  held-out reprojection, px: per camera median / p90 / RMS; all (corners); mean "
          "soft-L1 cost at 2 px (px^2); rig frames' median error minus calibrate-rig's (mean "
          "+- its standard error)")  # fmt: skip
    print("    " + " | ".join(["candidate", *cams, "all", "cost", "vs calibrate-rig"]))
    base = sc["calibrate-rig"].frame_median
    for n in out["names"]:
        s = sc[n]
        cols = [f"{s.median[i]:.3f} / {s.p90[i]:.3f} / {s.rms[i]:.2f}" for i in range(len(cams))]
        cols.append(f"{s.median[-1]:.3f} / {s.p90[-1]:.3f} / {s.rms[-1]:.2f} ({s.corners[-1]})")
        cols.append(f"{s.cost:.4f}")
        d, se = _paired(s.frame_median, base)
        cols.append("-" if n == "calibrate-rig" else f"{d:+.4f} +- {se:.4f}")
        print("    " + " | ".join([n, *cols]))
    print("  cameras posed alone (two tags or more), relative pose against each candidate's: "
          "median disagreement deg, mm; disagreement of the median, deg, mm")  # fmt: skip
    pairs = sorted(
        {(a, b) for a, b, _ in out["alone"]}, key=lambda p: (cams.index(p[0]), cams.index(p[1]))
    )
    for a, b in pairs:
        row = [f"{a}-{b} ({out['alone'][(a, b, out['names'][0])]['frames']} rig frames)"]
        for n in out["names"]:
            r = out["alone"].get((a, b, n))
            if r is not None:
                row.append(f"{n} {r['median_deg']:.3f}, {r['median_mm']:.1f}; "
                           f"{r['bias_deg']:.3f}, {r['bias_mm']:.1f}")  # fmt: skip
        print("    " + " | ".join(row))


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks.held_out --folder PATH/test_N``: ``calibrate-rig``'s mountings,
    TagSLAM's extrinsics and the joint solution's scored on rig frames the calibration did not
    see, on TagSLAM's tag map and on the joint solution's (the module docstring); the
    extrinsics ``camera_poses.yaml`` gives TagSLAM for every camera, if it does, too (unless
    TagSLAM's solution kept them)."""
    from benchmarks.tagslam_data import errors

    ap = recording_parser(main.__doc__)
    ap.add_argument("--min-inliers", type=int, nargs="+", default=[20, 8])
    ap.add_argument("--blocks", type=int, default=10, help="runs of consecutive rig frames")
    ap.add_argument("--no-whole", action="store_true",
                    help="without calibrate-rig on every rig frame (in-sample)")  # fmt: skip
    ap.add_argument("--maps", nargs="+", default=["tagslam", "joint"],
                    choices=["tagslam", "joint"])  # fmt: skip
    a = ap.parse_args(argv)
    if (loaded := recording(a)) is None:
        return
    rig, sol = loaded
    refs = {"TagSLAM's": rig.mounts, "joint": sol.mounts}
    given = given_extrinsics(a.folder)
    if set(given) >= set(rig.cameras):
        d = np.array([errors(*given[n], rig.mounts[n]) for n in rig.cameras])
        print(f"{rig.name}: camera_poses.yaml gives TagSLAM every camera's extrinsics; TagSLAM's "
              f"are within {d[:, 0].max():.1g} deg and {d[:, 1].max():.1g} mm of them")  # fmt: skip
        if d[:, 0].max() > 1e-3 or d[:, 1].max() > 1e-2:
            refs["given"] = {n: given[n] for n in rig.cameras}
    for m in a.maps:
        r = rig if m == "tagslam" else with_reference(rig, sol)
        label = "TagSLAM's" if m == "tagslam" else "the joint solution's"
        try:
            out = held_out(r, refs, a.blocks, a.min_inliers, whole=not a.no_whole)
        except ValueError as exc:
            print(f"{rig.name}, {label} tag map: {exc}")
            continue
        report(r, out, label)


if __name__ == "__main__":
    main()
