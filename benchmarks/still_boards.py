"""Diagnosis of the RS estimate on still photos of a checkerboard.

Run from the repository root (needs test/data/photos, see fetch.sh there)::

    python -m benchmarks.still_boards

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
3. **Correlated image error** (:mod:`rs_localizer.estimation.noise_model`): its restricted
   maximum-likelihood fit on the 13 still photos (their P3P poses), then per photo the RS
   estimate (``r6p_1lin``, default options) against P3P: rotation difference (deg), the
   twist's Mahalanobis distance from zero under ``twist_covariance`` and that of the P3P pose
   under the RS ``pose_covariance`` (6 dof; and ``|omega|``, the same with and without:
   the option changes the covariance only), with white noise only (``before``), with the
   correlated error fitted on all 13 photos (``after``) and fitted on the 12 others
   (``loo``, leave-one-out). chi2(6) 99.73 % bound: 20.06.
4. **Synthetic still boards with that error**: as table 2, the image error drawn from the
   fitted model (white + correlated), estimated without and with ``correlated_noise_px``; and
   white noise only with the option on (how conservative it is where there is no correlated
   error), plus the fit on white-noise-only views (should find none).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from rs_localizer.camera import CameraModel
from rs_localizer.estimation.estimate import CorrelatedNoise, EstimateOptions, estimate_rs_pose
from rs_localizer.estimation.noise_model import fit_correlated_noise
from rs_localizer.estimation.refine import RefineSettings, exact_errors, refine_rs_pose
from rs_localizer.frontends.boards import CheckerboardFrontend
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.maps.boards import load_board
from rs_localizer.sim.noise import correlated_field

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
    print(
        "photo  rmse(px, 2D): gs    rs(row)  rs(column)  rs(random)   "
        "LR: row  column  random   |omega| rad/s (row ML)"
    )
    for n, uv, X in _corners(photos):
        x, r, _ = cam.normalize(uv)
        gs = estimate_rs_pose(uv, X, cam, "p3p")
        times = {
            "row": r - cam.r0,
            "column": (uv[:, 0] - cam.K[0, 2]) / cam.K[0, 0],
            "random": np.random.default_rng(1).permutation(r - cam.r0),
        }
        ss = {"gs": None}
        g = refine_rs_pose(
            (gs.model.R, gs.model.C, z3, z3),
            X,
            x,
            times["row"],
            th,
            RefineSettings(rolling_shutter=False, max_iterations=50),
        )
        ss["gs"] = np.sum(exact_errors(g.R, g.C, g.w, g.t, X, x, times["row"]) ** 2) * f * f
        fits = {}
        for k, tau in times.items():
            res = refine_rs_pose(
                (gs.model.R, gs.model.C, z3, z3), X, x, tau, th, RefineSettings(max_iterations=50)
            )
            fits[k] = res
            ss[k] = np.sum(exact_errors(res.R, res.C, res.w, res.t, X, x, tau) ** 2) * f * f
        N = len(x)
        s2 = ss["row"] / (2 * N - 12)
        rm = [np.sqrt(ss[k] / N) for k in ("gs", "row", "column", "random")]
        lr = [(ss["gs"] - ss[k]) / s2 for k in ("row", "column", "random")]
        print(
            f"left{n}  {rm[0]:17.3f}  {rm[1]:7.3f}  {rm[2]:10.3f}  {rm[3]:10.3f}   "
            f"{lr[0]:7.1f}  {lr[1]:6.1f}  {lr[2]:6.1f}   "
            f"{np.linalg.norm(fits['row'].w) / cam.seconds_per_unit_r:6.2f}"
        )


def nees_table(photos: Path = PHOTOS, noise: float = 0.2, seeds: int = 8) -> None:
    """Table 2 of the module doc."""
    cam = _camera(photos)
    q6, q3 = chi2.ppf(0.9973, 6), chi2.ppf(0.9973, 3)
    m6, m3, err = [], [], []
    for _n, uv, X in _corners(photos):
        gs = estimate_rs_pose(uv, X, cam, "p3p")
        clean = cam.project_rs(X, gs.model.R, gs.model.C)
        for seed in range(seeds):
            u = clean + np.random.default_rng(seed).normal(0, noise, clean.shape)
            rs = estimate_rs_pose(u, X, cam, "r6p_1lin")
            tw = np.r_[rs.pose.linear_velocity, rs.pose.angular_velocity]
            m6.append(tw @ np.linalg.solve(rs.twist_covariance, tw))
            phi = Rotation.from_matrix(rs.model.R.T @ gs.model.R).as_rotvec()
            m3.append(phi @ np.linalg.solve(rs.pose_covariance[3:, 3:], phi))
            err.append(rotation_angle_deg(rs.model.R, gs.model.R))
    m6, m3, err = map(np.asarray, (m6, m3, err))
    print(f"synthetic still boards, {len(m6)} frames, noise {noise} px per axis:")
    print(
        f"  twist NEES mean {m6.mean():.1f} (chi2(6): 6), median {np.median(m6):.1f}, "
        f"within 99.73 % ({q6:.2f}): {np.mean(m6 <= q6):.3f}, max {m6.max():.1f}"
    )
    print(
        f"  rotation NEES mean {m3.mean():.2f} (chi2(3): 3), within 99.73 % ({q3:.2f}): "
        f"{np.mean(m3 <= q3):.3f}; rotation error median {np.median(err):.2f} deg, "
        f"max {err.max():.2f} deg"
    )


def _photo_views(photos: Path):
    cam = _camera(photos)
    return cam, [(n, uv, X, estimate_rs_pose(uv, X, cam, "p3p")) for n, uv, X in _corners(photos)]


def _distances(rs, gs):
    """(rotation difference deg, twist Mahalanobis, pose Mahalanobis of gs under rs)."""
    tw = np.r_[rs.pose.linear_velocity, rs.pose.angular_velocity]
    phi = Rotation.from_matrix(gs.model.R.T @ rs.model.R).as_rotvec()  # world-axes rotation error
    dp = np.r_[gs.pose.position - rs.pose.position, phi]
    return (
        rotation_angle_deg(rs.model.R, gs.model.R),
        float(tw @ np.linalg.solve(rs.twist_covariance, tw)),
        float(dp @ np.linalg.solve(rs.pose_covariance, dp)),
    )


def correlated_table(photos: Path = PHOTOS, loo: bool = True):
    """Table 3 of the module doc; returns the fit on all photos."""
    cam, views = _photo_views(photos)
    fit = fit_correlated_noise(cam, [(uv, X, g.model.R, g.model.C) for _, uv, X, g in views])
    print(
        f"correlated image error fitted on {fit.views} photos ({fit.points} corners): white "
        f"{fit.white_px:.3f} px, correlated {fit.correlated_px:.3f} px, length "
        f"{fit.length_px:.0f} px, log-likelihood ratio vs white {fit.log_likelihood_ratio:.1f}"
    )
    print(
        "photo  rot diff deg  |omega| rad/s  twist M: before  after   loo    pose M: before  "
        "after   loo   rot sd deg (after)"
    )
    rows = []
    for k, (n, uv, X, gs) in enumerate(views):
        fits = {"before": None, "after": fit}
        if loo:
            fits["loo"] = fit_correlated_noise(
                cam,
                [(u, Y, g.model.R, g.model.C) for j, (_, u, Y, g) in enumerate(views) if j != k],
            )
        d = {}
        for key, f in fits.items():
            o = (
                EstimateOptions()
                if f is None
                else EstimateOptions(
                    correlated_noise=CorrelatedNoise(
                        sigma_px=f.correlated_px, length_px=f.length_px
                    )
                )
            )
            rs = estimate_rs_pose(uv, X, cam, "r6p_1lin", o)
            d[key] = _distances(rs, gs)
            if key == "after":
                sd = np.degrees(np.sqrt(np.linalg.eigvalsh(rs.pose_covariance[3:, 3:]).max()))
                om = np.linalg.norm(rs.pose.angular_velocity)
        lo = d.get("loo", (np.nan,) * 3)
        rows.append((d["before"][1], d["after"][1], lo[1], d["before"][2], d["after"][2], lo[2]))
        print(
            f"left{n}  {d['after'][0]:12.2f}  {om:13.2f}  {d['before'][1]:14.1f}  "
            f"{d['after'][1]:5.1f}  "
            f"{lo[1]:5.1f}   {d['before'][2]:13.1f}  {d['after'][2]:5.1f}  {lo[2]:5.1f}   "
            f"{sd:6.2f}"
        )
    r = np.array(rows)
    q6 = chi2.ppf(0.9973, 6)
    print(
        f"max twist M: before {r[:, 0].max():.1f}, after {r[:, 1].max():.1f}, loo "
        f"{np.nanmax(r[:, 2]) if loo else np.nan:.1f}; photos above {q6:.2f}: before "
        f"{np.sum(r[:, 0] > q6)}, after {np.sum(r[:, 1] > q6)}, loo "
        f"{np.sum(r[:, 2] > q6) if loo else -1}; max pose M: before {r[:, 3].max():.1f}, "
        f"after {r[:, 4].max():.1f}, loo {np.nanmax(r[:, 5]) if loo else np.nan:.1f}"
    )
    return fit


def synthetic_correlated(photos: Path, fit, seeds: int = 8):
    """Table 4 of the module doc: {case: (mean twist M, fraction within 99.73 %)}."""
    cam, views = _photo_views(photos)
    q6 = chi2.ppf(0.9973, 6)
    on = EstimateOptions(
        correlated_noise=CorrelatedNoise(sigma_px=fit.correlated_px, length_px=fit.length_px)
    )
    cases = {
        "field, option off": (fit.correlated_px, EstimateOptions()),
        "field, option on": (fit.correlated_px, on),
        "white only, option off": (0.0, EstimateOptions()),
        "white only, option on": (0.0, on),
    }
    out = {}
    white_views = []
    for name, (s_px, opts) in cases.items():
        m6 = []
        for k, (_, _uv, X, gs) in enumerate(views):
            clean = cam.project_rs(X, gs.model.R, gs.model.C)
            for seed in range(seeds):
                rng = np.random.default_rng((k, seed))
                u = clean + correlated_field(clean, fit.white_px, s_px, fit.length_px, rng)
                rs = estimate_rs_pose(u, X, cam, "r6p_1lin", opts)
                tw = np.r_[rs.pose.linear_velocity, rs.pose.angular_velocity]
                m6.append(tw @ np.linalg.solve(rs.twist_covariance, tw))
                if s_px == 0 and seed == 0 and opts is on:
                    white_views.append((u, X, gs.model.R, gs.model.C))
        m6 = np.asarray(m6)
        out[name] = (float(m6.mean()), float(np.mean(m6 <= q6)))
        print(
            f"synthetic still boards, {name}: twist M mean {m6.mean():.1f} (chi2(6): 6), "
            f"median {np.median(m6):.1f}, within 99.73 %: {np.mean(m6 <= q6):.3f}"
        )
    wf = fit_correlated_noise(cam, white_views)
    print(
        f"fit on white-noise-only views ({fit.white_px:.3f} px): white {wf.white_px:.3f} px, "
        f"correlated {wf.correlated_px:.3f} px, log-likelihood ratio "
        f"{wf.log_likelihood_ratio:.1f}"
    )
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--photos", type=Path, default=PHOTOS, help="folder of left01..14.jpg")
    p.add_argument("--noise", type=float, default=0.2, help="synthetic noise, px per axis")
    p.add_argument("--seeds", type=int, default=8, help="noise draws per synthetic pose")
    p.add_argument("--no-loo", action="store_true", help="skip the leave-one-out fits")
    a = p.parse_args(argv)
    placebo_table(a.photos)
    nees_table(a.photos, a.noise, a.seeds)
    fit = correlated_table(a.photos, loo=not a.no_loo)
    synthetic_correlated(a.photos, fit, a.seeds)


if __name__ == "__main__":
    main()
