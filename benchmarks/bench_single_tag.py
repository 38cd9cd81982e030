"""One marker in view: ``python -m benchmarks.bench_single_tag``.

A frame with one square marker has four corners, too few for the robust estimator; the
estimator poses it from them alone (:mod:`rs_localizer.estimation.single_tag`: OpenCV's IPPE,
the pose refined with the velocities held at the prediction's, the plane's ambiguity resolved
by the image or the prediction, or refused as ``ambiguous_tag``). Compared with OpenCV's IPPE
on the same corners (``cv2.solvePnPGeneric``, ``SOLVEPNP_IPPE``, the solution of lower
reprojection error):

1. rendered: a 20 cm tag at 0.6-1.5 m, seen 20-50 degrees off its axis by a 640x480 camera
   (500 px focal length) with a 30 us line delay, turning at ``--turn`` rad/s and moving at
   ``--speed`` m/s, 0.5 px corner noise; the estimator without a prediction and with one (the
   true model with its rotation off by 1 degree, its position by 1 cm). Ground truth: the
   rendered pose. Prints the median rotation error (deg) and position error (cm) and the frames
   posed;
2. real: TagSLAM's ``test_22`` (a RealSense T265 fisheye camera, global shutter, one 0.42 m tag
   at a known place, a walk away from it and back; ``../shared/data/real_markers/tagslam``):
   every frame with that tag posed from its four corners alone, each frame with the previous
   solved frame as its prediction. Reference: TagSLAM's own solution (a factor graph over the
   whole walk with the T265's odometry), not motion capture. Prints the frames posed and the
   median rotation error against the reference, absolute and between consecutive frames.

``--corner-noise`` prints instead the AprilTag library's corner noise on real tags of two
recordings (``test_22``'s tag and ``test_23``'s board of nine 49 mm tags seen by a RealSense
D435): each detection's four corners posed alone on the global-shutter model, the sum of
squared errors in measured pixels with 2 degrees of freedom (8 coordinates, 6 pose
parameters), and the corner noise ``sigma = sqrt(median(SSE / 2) / ln 2)`` (``SSE / 2`` of
Gaussian corner noise is ``sigma^2`` times an exponential variable, whose median is ``ln 2``;
the median keeps a few badly detected tags from inflating it). Tag side errors, print flatness
and calibration errors count as noise here too.

    python -m benchmarks.bench_single_tag [--frames 100] [--turn 1.5] [--speed 0.5]
    python -m benchmarks.bench_single_tag --corner-noise
    python -m benchmarks.bench_single_tag --test2

``--test2`` prints instead, per camera of TagSLAM's fisheye stereo ``test_2``, every tag
detection posed alone (no prediction): right (within 5 degrees of TagSLAM's solution), wrong,
or refused (by reason), and the median errors of the right ones.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from benchmarks.tagslam_data import DATA, errors, load_test2, quat_matrix, tag_corners
from rs_localizer.camera import CameraModel
from rs_localizer.estimation import InitialModel, estimate_rs_pose
from rs_localizer.experiments.timing import one_thread
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix

__all__ = [
    "corner_noise",
    "load_test22",
    "main",
    "opencv_ippe",
    "real",
    "relative_errors",
    "rendered",
    "test2_alone",
]

K_RENDER = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def opencv_ippe(
    uv: np.ndarray, X: np.ndarray, camera: CameraModel
) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's IPPE pose ``(R, C)`` (world -> camera) of the pixels ``uv`` (N, 2) of the
    coplanar points ``X`` (N, 3), undistorted with the camera's model: the solution of lower
    reprojection error."""
    x = camera.undistort(np.asarray(uv, dtype=float))
    n, rvecs, tvecs, err = cv2.solvePnPGeneric(
        np.ascontiguousarray(X, dtype=float), x, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE
    )
    k = int(np.argmin(np.ravel(err)[:n]))
    return cv2.Rodrigues(rvecs[k])[0], np.ravel(tvecs[k])


def _scene(rng: np.random.Generator, turn: float, speed: float):
    d = rng.uniform(0.6, 1.5)
    a, az = np.radians(rng.uniform(20, 50)), rng.uniform(0, 2 * np.pi)
    c = d * np.array([np.sin(a) * np.cos(az), np.sin(a) * np.sin(az), -np.cos(a)])
    z = -c / np.linalg.norm(c)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = rotvec_to_matrix(rng.normal(0, 0.05, 3)) @ np.stack([x, np.cross(z, x), z])
    om, v = rng.normal(size=3), rng.normal(size=3)
    return R, -R @ c, turn * om / np.linalg.norm(om), speed * v / np.linalg.norm(v)


def rendered(frames: int, turn: float, speed: float, noise_px: float = 0.5, seed: int = 0):
    """Rotation (deg) and position (m) errors, (frames, 3, 2), of OpenCV's IPPE, the estimator
    without a prediction and with one (NaN: refused), and the estimates' failures."""
    rng = np.random.default_rng(seed)
    cam = CameraModel(K=K_RENDER, width=640, height=480, line_delay=30e-6)
    s = cam.seconds_per_unit_r
    X = tag_corners(0.2)
    errors, failures = np.full((frames, 3, 2), np.nan), []
    for k in range(frames):
        R, C, om, v = _scene(rng, turn, speed)
        w, t = -s * om, s * np.cross(C, om) - s * v  # (the model's velocities per unit r)
        uv = cam.project_rs(X, R, C, w, t) + rng.normal(0, noise_px, (4, 2))
        off = rotvec_to_matrix(rng.normal(0, np.radians(1.0) / np.sqrt(3), 3))
        pred = InitialModel((off @ R, C + rng.normal(0, 0.01 / np.sqrt(3), 3), w, t))
        poses = [opencv_ippe(uv, X, cam)]
        fails = []
        for e in (estimate_rs_pose(uv, X, cam), estimate_rs_pose(uv, X, cam, initial_model=pred)):
            poses.append((e.model.R, e.model.C) if e.success else None)
            fails.append(e.failure)
        c_true = -R.T @ C
        for i, p in enumerate(poses):
            if p is not None:
                errors[k, i] = rotation_angle_deg(p[0], R), np.linalg.norm(-p[0].T @ p[1] - c_true)
        failures.append(fails)
    return errors, failures


def load_test22(folder: Path):
    """TagSLAM's ``test_22``: (camera, the tag's (4, 3) world corners, frames): each frame
    ``(stamp, (4, 2) corners px, reference camera -> world rotation (3, 3), camera position
    (3,))``, for the detections of the anchored tag (id 3) that have a reference pose. The
    rig's camera is at the rig's origin (TagSLAM's calibration: the identity)."""
    cam = CameraModel(
        K=np.array([[283.943, 0, 421.079], [0, 284.986, 400.527], [0, 0, 1]]),
        D=[0.00132, 0.03049, -0.02875, 0.0034],
        width=848,
        height=800,
        distortion_model="equidistant",
    )
    tf = json.loads((folder / "json" / "reference_final_tf.json").read_text())
    tag = next(t for t in tf if t["parent"] == "yard" and t["child"] == "tag_3")
    X = tag_corners(0.42) @ quat_matrix(tag["quat_xyzw"]).T + np.array(tag["translation"])
    ref = {}
    for line in (folder / "json" / "reference_odom.jsonl").read_text().splitlines():
        m = json.loads(line)
        ref[round(m["stamp"], 6)] = (quat_matrix(m["quat_xyzw"]), np.array(m["position"]))
    frames = []
    for line in (folder / "json" / "detections.jsonl").read_text().splitlines():
        m = json.loads(line)
        if m.get("topic") != "/detector/tags/left" or round(m["stamp"], 6) not in ref:
            continue
        for t in m["tags"]:
            if t["id"] == 3:
                frames.append((m["stamp"], np.array(t["corners"]), *ref[round(m["stamp"], 6)]))
    return cam, X, frames


def real(folder: Path = DATA / "test_22"):
    """Per frame of :func:`load_test22`: the estimate (the previous solved frame as its
    prediction), OpenCV's IPPE rotation (world -> camera), the reference's, and the estimate
    without a prediction."""
    cam, X, frames = load_test22(folder)
    out, prev = [], None
    for _stamp, uv, Rwc, _c in frames:
        e = estimate_rs_pose(uv, X, cam, initial_model=prev)
        if e.success:
            prev = InitialModel(e.model)
        out.append((e, opencv_ippe(uv, X, cam)[0], Rwc.T, estimate_rs_pose(uv, X, cam)))
    return out


def relative_errors(Rs: list, Rref: list) -> np.ndarray:
    """Errors (deg) of the rotations between consecutive frames against the reference's."""
    return np.array(
        [
            rotation_angle_deg(Rs[i + 1] @ Rs[i].T, Rref[i + 1] @ Rref[i].T)
            for i in range(len(Rs) - 1)
            if Rs[i] is not None and Rs[i + 1] is not None
        ]
    )


def _square_fit_sse(uv: np.ndarray, X: np.ndarray, camera: CameraModel) -> float:
    """Sum of squared errors (measured px^2) of the (4, 2) corners ``uv`` of one tag posed
    alone from them (the better of IPPE's two refined poses, zero velocities); NaN when a
    corner does not undistort."""
    from rs_localizer.estimation.frame import prepare_frame
    from rs_localizer.estimation.single_tag import _fits

    fr = prepare_frame(uv, X, camera, 1e6)
    if len(fr.x) < 4:
        return float("nan")
    fr.planar = True
    z = np.zeros(3)
    fits = _fits(fr, z, z, False)  # (the better first)
    return fits[0][4] * fr.f**2 if fits else float("nan")


def corner_noise(folder: Path = DATA) -> dict[str, tuple[int, float]]:
    """Per recording (``test_22``, ``test_23`` under ``folder``): (tags, corner noise sigma in
    measured px, ``sqrt(median(SSE / 2) / ln 2)``) of every tag detection posed alone
    (module docstring)."""
    from benchmarks.bench_global_shutter import d435_frames

    cam, X, frames = load_test22(folder / "test_22")
    out = {"test_22": [_square_fit_sse(uv, X, cam) for _, uv, _, _ in frames]}
    cam, frames = d435_frames(folder / "test_23")
    out["test_23"] = [
        _square_fit_sse(f.points_px[k : k + 4], f.X[k : k + 4], cam)
        for f in frames
        for k in range(0, len(f.X), 4)
    ]
    res = {}
    for name, sse in out.items():
        s = np.asarray(sse)[np.isfinite(sse)]
        res[name] = (len(s), float(np.sqrt(np.median(s / 2) / np.log(2))))
    return res


def test2_alone(folder: Path = DATA / "test_2") -> dict[str, dict]:
    """Per camera of ``test_2``: counts of its tag detections posed alone (``right`` within 5
    degrees of the reference, ``wrong``, ``refused:<reason>``) and ``rot_deg`` / ``pos_mm``,
    the median errors of the right ones."""
    rig = load_test2(folder)
    out = {}
    for name, cam in rig.cameras.items():
        cnt, right = {}, []
        for stamp, views in rig.frames:
            if stamp not in rig.reference or name not in views:
                continue
            uv, X = views[name]
            Rr, Cr = rig.reference[stamp]
            Rm, cm = rig.mounts[name]
            for k in range(0, len(uv), 4):
                e = estimate_rs_pose(uv[k : k + 4], X[k : k + 4], cam)
                if e.success:
                    r, p = errors(e.model.R, e.model.C, (Rm @ Rr, Rm @ Cr + cm))
                    c = "right" if r < 5.0 else "wrong"
                    if c == "right":
                        right.append((r, p))
                else:
                    c = "refused:" + e.failure
                cnt[c] = cnt.get(c, 0) + 1
        med = np.median(np.array(right), axis=0) if right else (np.nan, np.nan)
        out[name] = {"counts": cnt, "rot_deg": float(med[0]), "pos_mm": float(med[1])}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--turn", type=float, default=1.5, help="rad/s")
    ap.add_argument("--speed", type=float, default=0.5, help="m/s")
    ap.add_argument("--corner-noise", action="store_true", help="real tags' corner noise only")
    ap.add_argument("--test2", action="store_true", help="test_2's tags posed alone only")
    a = ap.parse_args(argv)
    one_thread()
    if a.test2:
        if not (DATA / "test_2").is_dir():
            print(f"{DATA} absent")
            return
        for name, r in test2_alone(DATA / "test_2").items():
            c = r["counts"]
            print(
                f"test_2 {name}: {sum(c.values())} tags posed alone: "
                + ", ".join(f"{k} {v}" for k, v in sorted(c.items()))
                + f"; right ones' median error {r['rot_deg']:.3f} deg, {r['pos_mm']:.1f} mm"
            )
        return
    if a.corner_noise:
        if not (DATA / "test_22").is_dir():
            print(f"{DATA} absent")
            return
        for name, (n, sigma) in corner_noise(DATA).items():
            print(f"{name}: {n} tags posed alone, corner noise {sigma:.3f} px (measured image)")
        return
    for turn, speed in ((0.0, 0.0), (a.turn, a.speed)):
        err, fails = rendered(a.frames, turn, speed)
        print(f"rendered, {turn} rad/s, {speed} m/s, {a.frames} frames:")
        for i, name in enumerate(("OpenCV IPPE", "no prediction", "with prediction")):
            ok = np.isfinite(err[:, i, 0])
            print(
                f"  {name:16s} posed {ok.sum():3d}  rotation {np.median(err[ok, i, 0]):.3f} deg"
                f"  position {100 * np.median(err[ok, i, 1]):.2f} cm"
            )
        refused = [f for pair in fails for f in pair if f]
        print(f"  refused: {', '.join(f'{r} {refused.count(r)}' for r in sorted(set(refused)))}")
    folder = DATA / "test_22"
    if not folder.is_dir():
        print(f"real: {folder} absent, skipped")
        return
    res = real(folder)
    ours = [e.model.R if e.success else None for e, _, _, _ in res]
    cv = [r for _, r, _, _ in res]
    ref = [r for _, _, r, _ in res]
    abs_ours = [rotation_angle_deg(r, q) for r, q in zip(ours, ref, strict=True) if r is not None]
    abs_cv = [rotation_angle_deg(r, q) for r, q in zip(cv, ref, strict=True)]
    alone = [e for *_, e in res]
    print(
        f"real test_22, {len(res)} frames with the tag: posed {sum(r is not None for r in ours)}"
        f" (without a prediction: {sum(e.success for e in alone)}, refused "
        f"{', '.join(sorted({e.failure for e in alone if not e.success})) or 'none'})"
    )
    print(
        f"  rotation vs reference, median: ours {np.median(abs_ours):.3f} deg, OpenCV IPPE "
        f"{np.median(abs_cv):.3f} deg; frame to frame: ours "
        f"{np.median(relative_errors(ours, ref)):.3f}, OpenCV IPPE "
        f"{np.median(relative_errors(cv, ref)):.3f} deg"
    )


if __name__ == "__main__":
    main()
