"""The information of some parameters of a least-squares problem with the others
marginalized (a sparse Schur complement, :func:`marginal_information`): the marker map's
covariance (:mod:`rs_localizer.mapping.marker_covariance`) and the rig's mountings' (both of
their adjustments, :func:`rs_localizer.calibration.corners.marginal`) take it; and the inverse
of an information matrix where the data leave some directions unconstrained
(:func:`loose_inverse`: the mountings', the camera-IMU rotation's and gyro bias's of
:mod:`rs_localizer.calibration.readout`)."""

from __future__ import annotations

import numpy as np
from scipy.sparse.linalg import splu

__all__ = ["loose_inverse", "marginal_information"]

#: an eigenvalue of an information matrix below this share of the largest is a direction the
#: data do not constrain (:func:`loose_inverse`)
UNCONSTRAINED_RTOL = 1e-12


def marginal_information(J, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The information of the parameters ``cols`` ((k,) int, columns of the Jacobian ``J``
    (rows, n), sparse) with every other parameter marginalized: the Schur complement ``S =
    H_mm - H_om^T X`` (k, k) of the others' block in ``H = J^T J``, ``X = H_oo^-1 H_om``
    (n - k, k) (the others in column order) by a sparse LU factorization of their block
    (SciPy ``splu``). ``J_m - J_o X`` is each row's Jacobian on ``cols`` with the others' part
    projected out. Returns ``(S, X)``, None where the others' block is singular."""
    H = (J.T @ J).tocsc()
    other = np.setdiff1d(np.arange(H.shape[0]), cols)
    Hmm = H[cols][:, cols].toarray()
    Hoo = H[other][:, other].tocsc()
    Hom = H[other][:, cols].toarray()
    try:
        with np.errstate(all="raise"):
            X = splu(Hoo).solve(Hom)
        if not np.isfinite(X).all():
            raise FloatingPointError
    except (RuntimeError, FloatingPointError):
        return None
    return Hmm - Hom.T @ X, X


def loose_inverse(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pseudo-inverse (k, k) of an information matrix ``S`` (k, k) (made symmetric) and its
    loose parameters ((j,) int): those in a direction of ``S`` of eigenvalue below
    :data:`UNCONSTRAINED_RTOL` of the largest (the data do not constrain it), whose variance is
    infinite, never the zero of the pseudo-inverse."""
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    null = w <= max(float(w[-1]) if len(w) else 0.0, 0.0) * UNCONSTRAINED_RTOL
    loose = np.flatnonzero(np.sum(V[:, null] ** 2, axis=1) > 1e-6)
    return (V[:, ~null] / w[~null]) @ V[:, ~null].T, loose
