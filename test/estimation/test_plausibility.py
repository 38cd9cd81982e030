"""Estimator side of the plausibility checks: never report an implausible model as a pose.

Ground truth: the sample-like sequence of :mod:`rs_localizer.sim.trajectory` (1280x720, fx ~1000,
30 us/row, angular speed ~1.3-1.7 rad/s, walking at ~1.3 m/s). The hostile inputs are the ones
of the issue: every pixel's ``v`` equal to its ``u`` (a cloud whose two fields share an
offset), 3D points reflected through the camera centre, rows behind the camera, identical
points, pixels on one image line.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rs_localizer.estimation import (
    EstimateOptions,
    PlausibilityOptions,
    RansacOptions,
    estimate_rs_pose,
)
from rs_localizer.estimation.plausibility import (
    check_final_model,
    degenerate_points,
    depths_at_capture,
    motion_bounds,
    plausible_motion,
)
from rs_localizer.estimation.scoring import msac_evaluate
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

#: the failure reasons :func:`estimate_rs_pose` documents
REASONS = {
    "too_few_points",
    "ambiguous_tag",
    "no_hypothesis",
    "too_few_inliers",
    "degenerate_geometry",
    "implausible_motion",
    "cheirality",
}


@pytest.fixture(scope="module")
def seq():
    fr, _scene, cam, _ = generate_sequence(SequenceConfig(num_frames=10, num_points=400, seed=5))
    return fr, cam


def _opts(**bounds):
    """300 RANSAC iterations; ``bounds``: :class:`PlausibilityOptions` fields."""
    return EstimateOptions(
        ransac=RansacOptions(max_iterations=300), plausibility=PlausibilityOptions(**bounds)
    )


def test_v_equal_u_cloud_is_never_a_pose(seq):
    """Issue: a cloud whose v field has the offset of u (v == u) was solved 9 of 10 times,
    2000 km off at 35,000 rad/s. The pixels lie on one image line: degenerate geometry."""
    fr, cam = seq
    for f in fr:
        uv = f.uv.copy()
        uv[:, 1] = uv[:, 0]
        e = estimate_rs_pose(uv, f.xyz, cam, options=_opts())
        assert not e.success, (
            f.index,
            np.linalg.norm(e.pose.position - f.position),
            np.linalg.norm(e.pose.angular_velocity),
        )
        assert e.failure == "degenerate_geometry"


def test_reflected_points_are_never_a_pose(seq):
    """3D points reflected through the camera centre (X' = 2c - X) project to the same pixels
    but lie behind the camera: solved 178-180 deg off before (at ~65 rad/s)."""
    fr, cam = seq
    for f in fr:
        e = estimate_rs_pose(f.uv, 2 * f.position - f.xyz, cam, options=_opts())
        assert not e.success, (
            f.index,
            rotation_angle_deg(e.pose.orientation, f.orientation),
            np.linalg.norm(e.pose.angular_velocity),
        )
        assert e.failure in REASONS


def test_rows_behind_the_camera_are_counted_as_dropped(seq):
    """The node's ``points_dropped`` (docs/node.md) counts rows behind the camera: with 30 % of the
    rows
    reflected behind the camera the frame still solves and those rows are counted."""
    fr, cam = seq
    f = fr[2]
    n = int(0.3 * len(f.xyz))
    X = f.xyz.copy()
    X[:n] = 2 * f.position - X[:n]
    # independent check that they are behind the true camera: camera-frame z <= 0
    z_true = (X - f.position) @ f.orientation[:, 2]
    behind = z_true <= 0
    assert behind[:n].all() and not behind[n:].any()
    u = f.uv.copy()
    u[n + 5] = np.nan  # one invalid row too
    e = estimate_rs_pose(u, X, cam, options=_opts())
    assert e.success
    assert rotation_angle_deg(e.pose.orientation, f.orientation) < 0.1
    assert e.num_behind == n
    assert e.num_dropped == n + 1
    assert e.num_valid == len(X) - 1
    assert not e.inliers[:n].any()


def test_identical_points_are_degenerate(seq):
    fr, cam = seq
    f = fr[0]
    e = estimate_rs_pose(
        np.tile(f.uv[:1], (100, 1)), np.tile(f.xyz[:1], (100, 1)), cam, options=_opts()
    )
    assert not e.success and e.failure == "degenerate_geometry"
    # identical pixels, distinct 3D points
    e = estimate_rs_pose(np.tile(f.uv[:1], (100, 1)), f.xyz[:100], cam, options=_opts())
    assert not e.success and e.failure == "degenerate_geometry"


def test_pixels_on_one_line_are_degenerate(seq):
    fr, cam = seq
    f = fr[0]
    rng = np.random.default_rng(3)
    for a, b in ((0.0, 300.0), (0.4, 100.0), (-0.3, 600.0)):
        u = rng.uniform(0, 1279, 100)
        uv = np.stack([u, a * u + b + rng.normal(0, 0.2, 100)], axis=1)
        e = estimate_rs_pose(uv, f.xyz[:100], cam, options=_opts())
        assert not e.success and e.failure == "degenerate_geometry", (a, b, e.failure)
    # a vertical line too
    uv = np.stack([np.full(100, 640.0), rng.uniform(0, 719, 100)], axis=1)
    e = estimate_rs_pose(uv, f.xyz[:100], cam, options=_opts())
    assert not e.success and e.failure == "degenerate_geometry"


def test_pixels_near_one_line_are_degenerate_against_a_direct_computation():
    """:func:`degenerate_points` of world points spread in 3D: degenerate exactly when the
    pixels (or the normalized points times the focal length) lie within the threshold of one
    line."""
    rng = np.random.default_rng(0)
    u = rng.uniform(0, 1000, 200)
    line = np.stack([u, 0.5 * u + 10], axis=1)
    # distance of (u, 0.5 u + 10 + e) from the line is e / sqrt(1.25)
    off = line + np.stack([np.zeros(200), np.full(200, 3.0) * rng.choice([-1, 1], 200)], 1)
    spread = rng.uniform(0, 1000, (200, 2))
    X = rng.uniform(-2, 2, (200, 3)) + [0, 0, 6]
    every, one, focal = np.ones(200, dtype=bool), np.array([[0, 200]]), np.array([1000.0])

    def degenerate(p, threshold_px):
        return degenerate_points(X, p, p / 1000, every, focal, one, threshold_px)

    assert degenerate(line, 2.0)
    assert degenerate(off, 3.0)  # 2.68 px from the line
    assert not degenerate(off, 2.0)
    assert not degenerate(spread, 2.0)


def test_velocities_beyond_the_bounds_are_never_reported(seq):
    """The true angular velocity is 1.3-1.7 rad/s and the linear one 1.3-1.5 m/s: with bounds
    below them no success may report a velocity beyond the bounds; with the defaults every
    frame solves."""
    fr, cam = seq
    for f in fr[:4]:
        e = estimate_rs_pose(f.uv, f.xyz, cam, options=_opts())
        assert e.success
        assert np.linalg.norm(e.pose.angular_velocity - f.angular_velocity) < 0.2
        for kw, key in (
            ({"max_angular_velocity": 0.5}, "angular_velocity"),
            ({"max_linear_velocity": 0.3}, "linear_velocity"),
        ):
            e = estimate_rs_pose(f.uv, f.xyz, cam, options=_opts(**kw))
            bound = next(iter(kw.values()))
            if e.success:
                assert np.linalg.norm(getattr(e, key)) <= bound * (1 + 1e-9), (kw, e)
            else:
                assert e.failure in REASONS


def test_options_validate_the_bounds():
    for kw in (
        {"max_angular_velocity": 0.0},
        {"max_angular_velocity": float("nan")},
        {"max_linear_velocity": -1.0},
    ):
        with pytest.raises(ValueError):
            PlausibilityOptions(**kw)
    EstimateOptions(plausibility=PlausibilityOptions(max_angular_velocity=float("inf")))  # no bound


def test_plausible_motion_against_physical_velocities():
    """|w| / s and |w x C - t| / s are the camera's angular and linear speeds (the estimator's
    ``physical_velocities``)."""
    from rs_localizer.estimation.estimate import physical_velocities

    rng = np.random.default_rng(1)
    s = 3e-2
    b = motion_bounds(20.0, 30.0, s)
    assert b == pytest.approx((0.6, 0.9))
    assert motion_bounds(20.0, 30.0, 0.0) is None
    ws, Cs, ts = (
        rng.normal(0, 0.6, (500, 3)),
        rng.normal(0, 5, (500, 3)),
        rng.normal(0, 0.6, (500, 3)),
    )
    ok = plausible_motion(None, Cs, ws, ts, b)
    for k in range(500):
        om, vc, _, _ = physical_velocities(np.eye(3), Cs[k], ws[k], ts[k], s)
        assert ok[k] == (np.linalg.norm(om) <= 20.0 and np.linalg.norm(vc) <= 30.0)
    assert 0 < ok.sum() < 500
    assert not plausible_motion(None, [np.nan, 0, 0], [0, 0, 0], [0, 0, 0], None)


def test_final_check_cheirality_and_depths():
    rng = np.random.default_rng(2)
    R = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    C = np.array([0.2, -0.1, 5.0])
    w, t = np.array([0.05, 0.1, -0.02]), np.array([0.01, 0.0, 0.02])
    X = rng.uniform(-1, 1, (50, 3))
    tau = rng.uniform(-0.4, 0.4, 50)
    z = depths_at_capture(R, C, w, t, X, tau)
    for i in range(50):  # expm by the matrix exponential of the skew matrix
        from scipy.linalg import expm

        W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        p = expm(tau[i] * W) @ R @ X[i] + C + tau[i] * t
        assert z[i] == pytest.approx(p[2], rel=1e-12)
    assert (z > 0).all()
    assert check_final_model(R, C, w, t, z, None) is None
    Xb = X.copy()
    Xb[7] = R.T @ (np.array([0.0, 0.0, -1.0]) - C)  # behind the camera at the reference time
    tb = tau.copy()
    tb[7] = 0.0
    zb = depths_at_capture(R, C, w, t, Xb, tb)
    assert zb[7] == pytest.approx(-1.0) and (np.delete(zb, 7) > 0).all()
    assert check_final_model(R, C, w, t, zb, None) == "cheirality"
    assert check_final_model(R, C, w, t, np.r_[z, np.nan], None) == "cheirality"
    assert (
        check_final_model(R, C, w * 100, t, z, motion_bounds(20, 30, 0.03)) == "implausible_motion"
    )
    assert check_final_model(R, C * np.nan, w, t, z, None) == "implausible_motion"
    assert depths_at_capture(R, C, np.zeros(3), t, X, tau) == pytest.approx(
        (X @ R.T + C)[:, 2] + tau * t[2]
    )


def test_scoring_counts_points_behind_the_camera_as_outliers():
    """MSAC kernels: a point that projects exactly onto its pixel but lies behind the camera
    (the negated camera-frame point projects to the same pixel) is no inlier."""
    rng = np.random.default_rng(4)
    P = np.concatenate([rng.uniform(-1, 1, (20, 2)), rng.uniform(3, 6, (20, 1))], axis=1)
    x = P[:, :2] / P[:, 2:]
    X = P.copy()
    X[:5] *= -1  # behind, same projection
    R, C, z3 = np.eye(3), np.zeros(3), np.zeros(3)
    _, inl, c = msac_evaluate(x, X, x[:, 1].copy(), np.array([0.0, 1.0]), R, C, z3, z3, 1e-6)
    assert c == 15 and not inl[:5].any() and inl[5:].all()


@pytest.mark.parametrize("compiled", [True, False])
def test_final_check_of_a_rig_checks_each_camera_at_its_mounting(compiled):
    """A rig's model checked with its views (``final_check(..., views=)``): a point is behind
    its camera when its depth in that camera at its capture time (the rig's exact model, then
    the mounting, by the matrix exponential) is not positive; the bounds apply to the rig's
    model; a camera alone (``views=None``) is one view at the identity mounting."""
    from scipy.linalg import expm

    from rs_localizer.estimation.plausibility import final_check

    rng = np.random.default_rng(5)
    R = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    C = np.array([0.2, -0.1, 0.3])
    w, t = np.array([0.5, 1.0, -0.2]), np.array([0.1, 0.0, 0.2])
    # two cameras looking opposite ways along the rig's z, 10 cm apart
    Rm = np.stack([np.eye(3), Rotation.from_rotvec([0.0, np.pi, 0.0]).as_matrix()])
    cm = np.array([[0.05, 0.0, 0.0], [-0.05, 0.0, 0.0]])
    rows = np.array([[0, 30], [30, 50]], dtype=np.int64)
    X = rng.uniform(-8, 8, (50, 3))
    tau = rng.uniform(-0.02, 0.02, 50)
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    cam = np.repeat([0, 1], [30, 20])
    z = np.array(
        [
            (Rm[c] @ (expm(s * W) @ R @ p + C + s * t) + cm[c])[2]
            for c, p, s in zip(cam, X, tau, strict=True)
        ]
    )
    views = (Rm, cm, rows)
    mask = z > 0
    assert 0 < mask.sum() < 50
    code, behind = final_check(R, C, w, t, X, tau, mask, compiled=compiled, views=views)
    assert (code, behind) == (0, int((z <= 0).sum()))
    one_behind = mask.copy()
    one_behind[np.flatnonzero(~mask)[0]] = True
    assert final_check(R, C, w, t, X, tau, one_behind, compiled=compiled, views=views)[0] == 2
    # the rig's angular speed |w| = 1.14 rad/s against bounds of 1 and 2 rad/s
    assert final_check(R, C, w, t, X, tau, mask, 1.0, compiled=compiled, views=views) == (1, 0)
    assert final_check(R, C, w, t, X, tau, mask, 4.0, compiled=compiled, views=views)[0] == 0
    assert final_check(R * np.nan, C, w, t, X, tau, mask, compiled=compiled, views=views) == (1, 0)
    # one camera at the identity mounting: the camera's own check
    one = (np.eye(3)[None], np.zeros((1, 3)), np.array([[0, 50]], dtype=np.int64))
    z0 = np.array([(expm(s * W) @ R @ p + C + s * t)[2] for p, s in zip(X, tau, strict=True)])
    m0 = z0 > 0
    assert (
        final_check(R, C, w, t, X, tau, m0, compiled=compiled, views=one)
        == final_check(R, C, w, t, X, tau, m0, compiled=compiled)
        == (0, int((~m0).sum()))
    )


def test_a_cheirality_failure_reports_the_rows_behind_the_camera(seq, cheirality_when_behind):
    """A frame refused as ``cheirality`` reports the rows its refused fit put behind the
    camera in ``num_behind`` and ``num_dropped``, as a rig frame's does (test_rig.py): the 30 %
    of the rows reflected behind the camera, one invalid row."""
    fr, cam = seq
    f = fr[2]
    n = int(0.3 * len(f.xyz))
    X = f.xyz.copy()
    X[:n] = 2 * f.position - X[:n]
    u = f.uv.copy()
    u[n + 5] = np.nan
    e = estimate_rs_pose(u, X, cam, options=_opts())
    assert not e.success and e.failure == "cheirality"
    assert e.num_behind == n and e.num_dropped == n + 1 and e.num_valid == len(X) - 1
    assert not e.inliers.any() and e.num_inliers_per_view == (0,)
