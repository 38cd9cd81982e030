"""Diagnosis of the RS estimate on still photos of a checkerboard (issue 13 item 5).

Run from the repository root (needs test/data/photos, see fetch.sh there)::

    python -m rs_localizer.evaluation.still_boards

Prints two tables:

1. **Placebo control on the photos** (OpenCV's left01..14, 9 x 6 board, 640 x 480, nominal
   30 us line delay). Maximum-likelihood refinements from the P3P pose: global shutter (6
   parameters), rolling shutter with the true capture time (the row), and two placebo "rolling
   shutters" with the same 12 parameters but a time that no camera has: the column, and the
   rows randomly permuted. ``LR`` is the drop of the squared residuals over the RS fit's
   per-axis noise variance (likelihood ratio of the 6 velocity parameters, chi2(6) if the
   GS model were right and the noise white). If the column-timed model explains the residuals
   as well as the row-timed one, the structure the velocities absorb is a smooth image
   deformation (lens model, corner bias, board flatness), not motion during the readout.
2. **NEES on synthetic still boards**: the P3P poses of the photos, their 54 corners projected
   through the same camera with zero motion and Gaussian noise (``--noise`` px per axis),
   estimated with ``r6p_1lin`` (default options: motion prior on): the true zero twist's
   Mahalanobis distance under ``twist_covariance`` (chi2(6): mean 6, 99.73 % at 20.06) and the
   true rotation's under the rotation block of ``pose_covariance`` (chi2(3): 99.73 % at 14.16).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from ..camera import CameraModel
from ..estimation.estimate import estimate_rs_pose
from ..estimation.refine import exact_errors, refine_rs_pose
from ..frontends.boards import CheckerboardFrontend, load_board
from ..geometry import rotation_angle_deg

PHOTOS = Path("test/data/photos")
LEFT = ["01", "02", "03", "04", "05", "06", "07", "08", "09", "11", "12", "13", "14"]
LINE_DELAY = 30e-6


def _camera(photos: Path) -> CameraModel:
    fs = cv2.FileStorage(str(photos / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    D = fs.getNode("distortion_coefficients").mat().ravel()
    fs.release()
    return CameraModel(K=K, D=D, width=640, height=480, line_delay=LINE_DELAY)


def _corners(photos: Path):
    fe = CheckerboardFrontend(load_board(photos / "left_board.yaml"))
    for n in LEFT:
        img = cv2.imread(str(photos / f"left{n}.jpg"), cv2.IMREAD_GRAYSCALE)
        uv, X, _ = fe.process(img)
        yield n, uv, X


def placebo_table(photos: Path = PHOTOS) -> None:
    """Table 1 of the module doc."""
    cam = _camera(photos)
    f, th, z3 = cam.mean_focal, 2.0 / cam.mean_focal, np.zeros(3)
    print("photo  rmse(px, 2D): gs    rs(row)  rs(column)  rs(random)   "
          "LR: row  column  random   |omega| rad/s (row ML)")
    for n, uv, X in _corners(photos):
        x, r, _ = cam.normalize(uv)
        gs = estimate_rs_pose(uv, X, cam, "p3p")
        times = {"row": r - cam.r0, "column": (uv[:, 0] - cam.K[0, 2]) / cam.K[0, 0],
                 "random": np.random.default_rng(1).permutation(r - cam.r0)}
        ss = {"gs": None}
        g = refine_rs_pose(gs.R, gs.C, z3, z3, X, x, times["row"], th,
                           rolling_shutter=False, max_iterations=50)
        ss["gs"] = np.sum(exact_errors(g.R, g.C, g.w, g.t, X, x, times["row"]) ** 2) * f * f
        fits = {}
        for k, tau in times.items():
            res = refine_rs_pose(gs.R, gs.C, z3, z3, X, x, tau, th, max_iterations=50)
            fits[k] = res
            ss[k] = np.sum(exact_errors(res.R, res.C, res.w, res.t, X, x, tau) ** 2) * f * f
        N = len(x)
        s2 = ss["row"] / (2 * N - 12)
        rm = [np.sqrt(ss[k] / N) for k in ("gs", "row", "column", "random")]
        lr = [(ss["gs"] - ss[k]) / s2 for k in ("row", "column", "random")]
        print(f"left{n}  {rm[0]:17.3f}  {rm[1]:7.3f}  {rm[2]:10.3f}  {rm[3]:10.3f}   "
              f"{lr[0]:7.1f}  {lr[1]:6.1f}  {lr[2]:6.1f}   "
              f"{np.linalg.norm(fits['row'].w) / cam.seconds_per_unit_r:6.2f}")


def nees_table(photos: Path = PHOTOS, noise: float = 0.2, seeds: int = 8) -> None:
    """Table 2 of the module doc."""
    cam = _camera(photos)
    q6, q3 = chi2.ppf(0.9973, 6), chi2.ppf(0.9973, 3)
    m6, m3, err = [], [], []
    for n, uv, X in _corners(photos):
        gs = estimate_rs_pose(uv, X, cam, "p3p")
        clean = cam.project_rs(X, gs.R, gs.C)
        for seed in range(seeds):
            u = clean + np.random.default_rng(seed).normal(0, noise, clean.shape)
            rs = estimate_rs_pose(u, X, cam, "r6p_1lin")
            tw = np.r_[rs.linear_velocity, rs.angular_velocity]
            m6.append(tw @ np.linalg.solve(rs.twist_covariance, tw))
            phi = Rotation.from_matrix(rs.R.T @ gs.R).as_rotvec()
            m3.append(phi @ np.linalg.solve(rs.pose_covariance[3:, 3:], phi))
            err.append(rotation_angle_deg(rs.R, gs.R))
    m6, m3, err = map(np.asarray, (m6, m3, err))
    print(f"synthetic still boards, {len(m6)} frames, noise {noise} px per axis:")
    print(f"  twist NEES mean {m6.mean():.1f} (chi2(6): 6), median {np.median(m6):.1f}, "
          f"within 99.73 % ({q6:.2f}): {np.mean(m6 <= q6):.3f}, max {m6.max():.1f}")
    print(f"  rotation NEES mean {m3.mean():.2f} (chi2(3): 3), within 99.73 % ({q3:.2f}): "
          f"{np.mean(m3 <= q3):.3f}; rotation error median {np.median(err):.2f} deg, "
          f"max {err.max():.2f} deg")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--photos", type=Path, default=PHOTOS, help="folder of left01..14.jpg")
    p.add_argument("--noise", type=float, default=0.2, help="synthetic noise, px per axis")
    p.add_argument("--seeds", type=int, default=8, help="noise draws per synthetic pose")
    a = p.parse_args(argv)
    placebo_table(a.photos)
    nees_table(a.photos, a.noise, a.seeds)


if __name__ == "__main__":
    main()
