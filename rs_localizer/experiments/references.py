"""Reference estimators the experiments and the benchmarks compare ours with, on synthetic
frames of :mod:`rs_localizer.sim.synthetic`: PoseLib's and OpenCV's global-shutter RANSAC
(:func:`poselib_estimate`, :func:`opencv_estimate`) and the maximum-likelihood fit on the true
inliers (:func:`ml_fit`, the best any estimator can do on a frame)."""

from __future__ import annotations

import numpy as np

from ..camera import CameraModel
from ..estimation.estimate import EstimateOptions
from ..sim.synthetic import SyntheticFrame

__all__ = ["ml_fit", "opencv_estimate", "poselib_estimate", "poselib_matched_options"]


#: PoseLib ``RansacOptions`` at the settings of :class:`EstimateOptions` (names from the
#: Python binding, ``poselib.RansacOptions()``); ``dyn_num_trials_mult`` keeps PoseLib's default
#: (3.0: it draws three times the samples its confidence bound asks for)
def poselib_matched_options(opts: EstimateOptions) -> dict:
    """PoseLib ``ransac_opt`` with our iteration bounds, threshold and confidence."""
    return {
        "max_reproj_error": opts.ransac.threshold_px,
        "min_iterations": opts.ransac.min_iterations,
        "max_iterations": opts.ransac.max_iterations,
        "success_prob": opts.ransac.confidence,
    }


def poselib_estimate(
    f: SyntheticFrame, cam: CameraModel, threshold_px: float, ransac_opt: dict | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """PoseLib ``estimate_absolute_pose`` (global shutter, the benchmarks' reference) on a
    synthetic frame ``f`` (``points_px`` (N, 2), ``X`` (N, 3)): its default ``RansacOptions``
    with our threshold (px), or ``ransac_opt``. Returns (R (3, 3) world -> camera, C (3,),
    number of inliers).

    Raises:
        ImportError: PoseLib is not installed (``pip install 'rs_localizer[bench]'``).
    """
    try:
        import poselib
    except ImportError as e:
        raise ImportError(
            "the benchmarks' global-shutter reference needs PoseLib: "
            "pip install 'rs_localizer[bench]'"
        ) from e

    K = cam.K
    camera = {
        "model": "PINHOLE",
        "width": cam.width,
        "height": cam.height,
        "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
    }
    ro = {"max_reproj_error": threshold_px} if ransac_opt is None else ransac_opt
    pose, info = poselib.estimate_absolute_pose(f.points_px, f.X, camera, ro, {})
    return np.asarray(pose.R), np.asarray(pose.t), int(info["num_inliers"])


def opencv_estimate(
    f: SyntheticFrame, cam: CameraModel, threshold_px: float
) -> tuple[np.ndarray | None, np.ndarray | None, int]:
    """``cv2.solvePnPRansac`` (P3P, global shutter, 1000 iterations) on a synthetic frame
    ``f`` at ``threshold_px``: (R (3, 3) world -> camera, C (3,), number of inliers), or
    ``(None, None, 0)`` when it finds no pose."""
    import cv2

    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        f.X,
        f.points_px,
        cam.K,
        None,
        reprojectionError=threshold_px,
        iterationsCount=1000,
        confidence=0.9999,
        flags=cv2.SOLVEPNP_P3P,
    )
    if not ok:
        return None, None, 0
    return cv2.Rodrigues(rvec)[0], tvec.ravel(), 0 if inl is None else len(inl)


def ml_fit(f):
    """(R, C, w, t) maximizing the likelihood of a synthetic frame under its Gaussian pixel
    noise: SciPy ``least_squares`` on the generator's true inliers, exact constant-velocity
    model (:func:`rs_localizer.estimation.refine.exact_residuals`), from the ground truth, run
    to convergence. The best any estimator can do on the frame."""
    from scipy.optimize import least_squares

    from ..estimation.refine import exact_jacobian, exact_residuals
    from ..geometry import rotvec_to_matrix

    X, x, tau = f.X[f.inlier], f.x[f.inlier], f.r[f.inlier] - f.r0
    theta0 = np.concatenate([np.zeros(3), f.C, f.w, f.t])
    res = least_squares(
        lambda p: exact_residuals(p, f.R, X, x, tau),
        theta0,
        jac=lambda p: exact_jacobian(p, f.R, X, x, tau),
        method="lm",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    th = res.x
    return rotvec_to_matrix(th[:3]) @ f.R, th[3:6], th[6:9], th[9:12]
