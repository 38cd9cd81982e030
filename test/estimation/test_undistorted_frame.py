"""A frame of points already undistorted (:func:`undistorted_frame`, what a rig frame posed by
one camera's few points builds from the rig's own undistortion) against the frame of the
estimator's own preparation (:func:`prepare_frame`, which undistorts them itself), and the
few-points estimate from either: the same values to the bit, or None where the preparation
leaves a row out."""

from __future__ import annotations

import numpy as np
import pytest

from rs_localizer.camera import CameraModel
from rs_localizer.estimation.estimate import EstimateOptions, InitialModel, few_points_pose
from rs_localizer.estimation.frame import prepare_frame, undistorted_frame
from rs_localizer.estimation.ransac import SeededShuffle
from rs_localizer.geometry import rotvec_to_matrix

K = np.array([[600.0, 0.0, 640.0], [0.0, 604.0, 400.0], [0.0, 0.0, 1.0]])
CAMERAS = {
    "pinhole": CameraModel(np.array([[600.0, 0, 640], [0, 600, 400], [0, 0, 1]]), width=1280,
                           height=800),
    "plumb_bob_rs": CameraModel(K, [-0.2, 0.05, 1e-3, -2e-3, 0.0], 1280, 800, line_delay=3e-5,
                                readout="bottom_to_top"),
    "equidistant": CameraModel(K, [-0.02, -0.003, 0.007, -0.003], 1280, 800,
                               distortion_model="equidistant", line_delay=2e-5,
                               readout="left_to_right"),
    "fx_fy": CameraModel(K, width=1280, height=800),
}  # fmt: skip


def _corners(rng, n):
    """n points of one tag (n = 4) or of two tags on two planes, seen from 1 m."""
    s = 0.08
    tag = np.array([[-s, s, 0], [s, s, 0], [s, -s, 0], [-s, -s, 0]], dtype=float)
    if n > 4:
        other = tag @ rotvec_to_matrix(np.array([0.0, 1.2, 0.0])).T + [0.3, 0.0, 0.1]
        tag = np.concatenate([tag, other])[:n]
    R = rotvec_to_matrix(rng.normal(0, 0.2, 3))
    C = np.array([0.05, -0.02, 1.0]) + rng.normal(0, 0.05, 3)
    return tag, R, C


def _frame_fields(fr):
    names = ("x", "X", "r", "r0e", "r0", "d", "f", "rows", "num_rows", "compiled", "u_px", "W")
    return {k: getattr(fr, k) for k in names}


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_undistorted_frame_is_the_prepared_frame(name):
    """Every field of the frame of undistorted points (the undistorted points and pixel
    Jacobians of every row in their given order, shuffled by the same seed) equals the prepared
    frame's, with and without the Jacobians given, for 4 to 8 points."""
    cam = CAMERAS[name]
    rng = np.random.default_rng(3)
    for n in (4, 5, 8):
        X, R, C = _corners(rng, n)
        uv = cam.project_rs(X, R, C) + rng.normal(0, 0.3, (n, 2))
        x = cam.undistort(uv)
        A = cam.pixel_jacobian_exact(x).reshape(-1, 4)
        want = _frame_fields(prepare_frame(uv, X, cam, 1e3, SeededShuffle(n)))
        for jac in (A, None):
            fr = undistorted_frame(uv, X, x, jac, cam, 1e3, SeededShuffle(n))
            got = _frame_fields(fr)
            for k, v in want.items():
                assert type(got[k]) is type(v), k
                if isinstance(v, np.ndarray):
                    assert got[k].dtype == v.dtype and np.array_equal(got[k], v), (name, n, k)
                else:
                    assert got[k] == v, (name, n, k)


def test_undistorted_frame_refuses_what_the_preparation_leaves_out():
    """A row the preparation leaves out (a NaN pixel, a point beyond the norm bound, a NaN
    undistorted point) or mismatched shapes give None: the caller prepares the frame."""
    cam = CAMERAS["plumb_bob_rs"]
    X, R, C = _corners(np.random.default_rng(5), 4)
    uv = cam.project_rs(X, R, C)
    x = cam.undistort(uv)
    assert undistorted_frame(uv, X, x, None, cam, 1e3) is not None
    bad_uv = uv.copy()
    bad_uv[1, 0] = np.nan
    far = X.copy()
    far[2, 2] = 2e3
    bad_x = x.copy()
    bad_x[3] = np.nan
    assert undistorted_frame(bad_uv, X, x, None, cam, 1e3) is None
    assert undistorted_frame(uv, far, x, None, cam, 1e3) is None
    assert undistorted_frame(uv, X, bad_x, None, cam, 1e3) is None
    assert undistorted_frame(uv, X, x[:3], None, cam, 1e3) is None
    assert undistorted_frame(uv[:, :1], X, x, None, cam, 1e3) is None


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_few_points_pose_of_undistorted_points_is_the_same(name):
    """``few_points_pose`` given the undistorted points and the pixel Jacobians returns the same
    fields to the bit as without them (its own preparation), on one tag, two tags and with a
    prediction; a NaN row falls back to the preparation (still the same)."""
    cam = CAMERAS[name]
    rng = np.random.default_rng(11)
    opts = EstimateOptions()
    seen = 0
    for n, pred, nan in ((4, False, False), (4, True, False), (8, False, False), (8, True, True)):
        X, R, C = _corners(rng, n)
        uv = cam.project_rs(X, R, C) + rng.normal(0, 0.2, (n, 2))
        if nan:
            uv[0] = np.nan
        x = cam.undistort(uv)
        A = None if cam.distortion_model == "equidistant" else cam.pixel_jacobian_exact(x)
        A = None if A is None else A.reshape(-1, 4)
        im = InitialModel((R, C, np.full(3, 1e-4), np.full(3, -1e-4))) if pred else None
        want = few_points_pose(uv, X, cam, opts, im)
        got = few_points_pose(uv, X, cam, opts, im, undistorted=(x, A))
        assert (want is None) == (got is None)
        if want is None:
            continue
        seen += want.success
        for k, a, b in zip(want._fields, want, got, strict=True):
            if k == "model" and a is not None:
                assert all(np.array_equal(p, q) for p, q in zip(a, b, strict=True)), k
            elif isinstance(a, np.ndarray):
                assert np.array_equal(a, b), k
            else:
                assert a == b or (a != a and b != b), k
    assert seen >= 3


def test_arrays_of_another_layout_give_the_same_frame():
    """Read-only or Fortran-ordered arrays (taken in NumPy, not by the compiled call) give the
    same frame to the bit as C-ordered writeable ones, with and without the Jacobians."""
    cam = CAMERAS["plumb_bob_rs"]
    rng = np.random.default_rng(7)
    X, R, C = _corners(rng, 8)
    uv = cam.project_rs(X, R, C) + rng.normal(0, 0.3, (8, 2))
    x = cam.undistort(uv)
    A = cam.pixel_jacobian_exact(x).reshape(-1, 4)
    for jac in (A, None):
        want = _frame_fields(undistorted_frame(uv, X, x, jac, cam, 1e3, SeededShuffle(1)))
        ro = [a.copy() for a in (uv, X, x)]
        for a in ro:
            a.flags.writeable = False
        for u2, X2, x2 in (ro, [np.asfortranarray(a) for a in (uv, X, x)]):
            fr = undistorted_frame(u2, X2, x2, jac, cam, 1e3, SeededShuffle(1))
            for k, v in _frame_fields(fr).items():
                if isinstance(v, np.ndarray):
                    assert np.array_equal(v, want[k]) and v.dtype == want[k].dtype, k
                else:
                    assert v == want[k], k
