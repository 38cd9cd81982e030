"""The mirrored tilt the marker-map initialization also tries is the other planar solution of
a square seen from about one direction: OpenCV's IPPE gives the same two poses."""

import cv2
import numpy as np

from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.mapping import marker_corners_local
from rs_localizer.mapping.marker_init import ippe_candidates, mirrored_tilt

OBJ = marker_corners_local(0.16)


def _normal_angle_deg(Ra, Rb):
    return float(np.degrees(np.arccos(np.clip(Ra[:, 2] @ Rb[:, 2], -1.0, 1.0))))


def _views(seed=3, n=5):
    """``n`` (marker -> world R, marker centre p, camera centre c, camera -> world Rcw, exact
    normalized corners (4, 2)): a camera 3 m away, 30-50 deg off the marker's face normal,
    looking at it."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        R = rotvec_to_matrix(rng.normal(scale=0.4, size=3))
        p = rng.normal(size=3)
        off = np.radians(rng.uniform(30, 50))
        c = p + 3.0 * (R @ np.array([np.sin(off), 0.0, np.cos(off)]))
        z = (p - c) / np.linalg.norm(p - c)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        Rcw = np.stack([x, np.cross(z, x), z], axis=1)
        Xc = (OBJ @ R.T + p - c) @ Rcw
        yield R, p, c, Rcw, Xc[:, :2] / Xc[:, 2:]


def test_mirrored_tilt_is_the_other_ippe_solution():
    rng = np.random.default_rng(4)
    for R, p, c, Rcw, uv in _views():
        # 1e-4 (normalized) is 0.05 px at f = 500 px
        uv = uv + rng.normal(scale=1e-4, size=uv.shape)
        n, rvecs, _, _ = cv2.solvePnPGeneric(
            OBJ, uv.reshape(-1, 1, 2), np.eye(3), None, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
        sols = [Rcw @ rotvec_to_matrix(np.ravel(r)) for r in rvecs[:n]]
        delta = mirrored_tilt(R, (c - p)[None])
        R_alt = rotvec_to_matrix(delta) @ R
        # one IPPE solution is the truth, the other the mirrored tilt
        errs = sorted(min(_normal_angle_deg(S, T) for S in sols) for T in (R, R_alt))
        assert errs[1] < 2.0
        assert _normal_angle_deg(R, R_alt) > 30.0


def test_ippe_candidates_are_finite_on_exact_corners():
    """The initialization's two planar solutions of exact (noise-free) corners: finite, the
    true pose among them (the last of these views puts OpenCV 4.6's square solver on a branch
    that returns NaN; the general planar solver then gives them)."""
    for R, _p, _c, Rcw, uv in _views():
        cands = ippe_candidates(OBJ, uv)
        assert len(cands) == 2
        assert all(np.isfinite(Rc).all() and np.isfinite(tc).all() for Rc, tc in cands)
        assert min(_normal_angle_deg(Rcw @ Rc, R) for Rc, _ in cands) < 0.01


def test_head_on_has_no_mirror():
    R = np.eye(3)
    assert mirrored_tilt(R, np.array([[0.0, 0.0, 2.0]])) is None
