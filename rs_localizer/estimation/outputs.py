"""Numba kernels for the estimator's last steps: the final inlier set and RMS error, physical
velocities and the covariance propagation (the degeneracy and plausibility tests are in
:mod:`.plausibility`). The model -> twist conversion and its Jacobian are
:func:`rs_localizer.pose.model_twist` and :func:`rs_localizer.pose.model_twist_jacobian`.

Each replaces a handful of small NumPy calls (``np.cross``, fancy indexing, 12 x 12 products:
~200 us per frame with the former SVD collinearity test, more than the final refinement itself)
by one compiled call; :mod:`rs_localizer.estimation.estimate` keeps the formulas' documentation.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from ..pose import ROS_ORDER, model_twist, model_twist_jacobian

__all__ = ["final_inliers", "output_covariance_kernel", "physical_velocities_kernel"]


@kernel
def final_inliers(e, th):
    """Inliers of the final model from its (N,) image distances ``e`` (``inf`` behind the
    camera): ``(mask e < th, count, RMS of e over the mask)`` (RMS NaN for no inlier)."""
    n = e.shape[0]
    mask = np.zeros(n, dtype=np.bool_)
    c = 0
    ss = 0.0
    for i in range(n):
        if e[i] < th:  # False for NaN and inf
            mask[i] = True
            c += 1
            ss += e[i] * e[i]
    return mask, c, np.sqrt(ss / c) if c > 0 else np.nan


@kernel
def physical_velocities_kernel(R, C, w, t, s):
    """See :func:`rs_localizer.estimation.estimate.physical_velocities` (``s > 0``): returns
    (omega_cam, v_cam, omega_world, v_world), each (3,); the camera-frame twist is
    :func:`rs_localizer.pose.model_twist`'s."""
    z = model_twist(C, w, t, s)
    om = z[3:6].copy()
    vc = z[0:3].copy()
    om_w = np.empty(3)
    vc_w = np.empty(3)
    for a in range(3):
        om_w[a] = R[0, a] * om[0] + R[1, a] * om[1] + R[2, a] * om[2]
        vc_w[a] = R[0, a] * vc[0] + R[1, a] * vc[1] + R[2, a] * vc[2]
    return om, vc, om_w, vc_w


@kernel
def _skew_into(v, J, r, c, scale):
    """J[r:r+3, c:c+3] = scale * [v]x."""
    J[r, c + 1] = -scale * v[2]
    J[r, c + 2] = scale * v[1]
    J[r + 1, c] = scale * v[2]
    J[r + 1, c + 2] = -scale * v[0]
    J[r + 2, c] = -scale * v[1]
    J[r + 2, c + 1] = scale * v[0]


@kernel
def output_covariance_kernel(cov12, R, C, w, s):
    """See :func:`rs_localizer.estimation.estimate._output_covariance`: the (12, 12)
    covariance ``J cov12 J^T`` of (camera rotation in the world, position, omega_cam, v_cam),
    the (6, 6) ROS pose block (x, y, z, rot x, rot y, rot z) and the (6, 6) ROS twist block
    (vx, vy, vz, wx, wy, wz; zeros if ``s <= 0``). The twist rows are
    :func:`rs_localizer.pose.model_twist_jacobian`'s."""
    J = np.zeros((12, 12))
    for i in range(3):
        for j in range(3):
            J[i, j] = -R[j, i]  # -R^T
            J[3 + i, 3 + j] = -R[j, i]
    # dc/ddelta = -R^T [C]x
    Cx = np.zeros((3, 3))
    _skew_into(C, Cx, 0, 0, 1.0)
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc -= R[k, i] * Cx[k, j]
            J[3 + i, j] = acc
    if s > 0:
        Jz = model_twist_jacobian(C, w, s)  # (v, omega) rows
        for i in range(3):
            for j in range(12):
                J[6 + i, j] = Jz[3 + i, j]
                J[9 + i, j] = Jz[i, j]
    out = J @ cov12 @ J.T
    pose = np.empty((6, 6))
    twist = np.zeros((6, 6))
    for a in range(6):  # (ROS order: position before rotation, v before omega)
        for b in range(6):
            pose[a, b] = out[ROS_ORDER[a], ROS_ORDER[b]]
            if s > 0:
                twist[a, b] = out[6 + ROS_ORDER[a], 6 + ROS_ORDER[b]]
    return out, pose, twist
