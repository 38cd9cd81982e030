"""The mirrored tilt the marker-map initialization also tries is the other planar solution of
a square seen from about one direction: OpenCV's IPPE gives the same two poses."""

import cv2
import numpy as np

from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.mapping.marker_ba import _mirrored_tilt, marker_corners_local


def _normal_angle_deg(Ra, Rb):
    return float(np.degrees(np.arccos(np.clip(Ra[:, 2] @ Rb[:, 2], -1.0, 1.0))))


def test_mirrored_tilt_is_the_other_ippe_solution():
    rng = np.random.default_rng(3)
    obj = marker_corners_local(0.16)
    for _ in range(5):
        R = rotvec_to_matrix(rng.normal(scale=0.4, size=3))  # marker -> world
        p = rng.normal(size=3)
        # a camera 3 m away, 30-50 deg off the marker's face normal, looking at it
        off = np.radians(rng.uniform(30, 50))
        d = R @ np.array([np.sin(off), 0.0, np.cos(off)])
        c = p + 3.0 * d
        z = (p - c) / np.linalg.norm(p - c)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        Rcw = np.stack([x, np.cross(z, x), z], axis=1)  # camera -> world
        Xc = (obj @ R.T + p - c) @ Rcw
        uv = Xc[:, :2] / Xc[:, 2:]
        n, rvecs, _, _ = cv2.solvePnPGeneric(
            obj, uv.reshape(-1, 1, 2), np.eye(3), None, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
        sols = [Rcw @ rotvec_to_matrix(np.ravel(r)) for r in rvecs[:n]]
        delta = _mirrored_tilt(R, (c - p)[None])
        R_alt = rotvec_to_matrix(delta) @ R
        # one IPPE solution is the truth, the other the mirrored tilt
        errs = sorted(min(_normal_angle_deg(S, T) for S in sols) for T in (R, R_alt))
        assert errs[1] < 2.0
        assert _normal_angle_deg(R, R_alt) > 30.0


def test_head_on_has_no_mirror():
    R = np.eye(3)
    assert _mirrored_tilt(R, np.array([[0.0, 0.0, 2.0]])) is None
