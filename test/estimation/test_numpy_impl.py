"""The estimator's NumPy implementation (rs_localizer.estimation.numpy_impl) against the
compiled one on the same frames: poses and velocities within the frames' own accuracy,
covariances of the same size, the same failure reasons on bad input; it compiles nothing (a
fresh process with an empty numba cache); ``estimate_rs_pose``'s ``implementation`` argument
and what the estimate records (the runtime's choice of it: test/runtime/test_background.py)."""

import numpy as np
import pytest
from helpers.fresh_cache import run_on_empty_cache

from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.estimate import EstimateOptions, PlausibilityOptions
from rs_localizer.estimation.gyro import GyroMeasurement
from rs_localizer.estimation.implementation import NUMPY_UNUSED
from rs_localizer.estimation.options import RefineOptions
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.synthetic import make_frame, paper_camera

#: the protocol's scene has no physical scale (see sim.synthetic.protocol_options)
OPTS = EstimateOptions(
    plausibility=PlausibilityOptions(max_angular_velocity=np.inf, max_linear_velocity=np.inf)
)


def estimate_numpy(uv, X, cam, solver="r6p_1lin", options=None):
    return estimate_rs_pose(uv, X, cam, solver, options, implementation="numpy")


def estimate_compiled(uv, X, cam, solver="r6p_1lin", options=None):
    return estimate_rs_pose(uv, X, cam, solver, options, implementation="compiled")


def _frames(n=6, points=300, rs_speed=0.5):
    return [
        make_frame(100 + k, points, rs_speed=rs_speed, noise_px=1.0, outlier_ratio=0.3)
        for k in range(n)
    ]


@pytest.mark.parametrize("solver", ["r6p_1lin", "p3p"])
def test_same_pose_as_compiled(solver):
    """Against the ground truth, the uncompiled estimate is as accurate as the compiled one
    (both fit the same exact model with a robust loss; they differ by their RANSAC samples
    and the optimizer's stopping point): each error within 1.5x the compiled one plus a
    tenth of the frame's noise-limited accuracy, and the two estimates within that of each
    other; inlier sets agree on 97 % of the points, covariance standard deviations within
    a factor 1.5."""
    cam = paper_camera()
    for f in _frames(rs_speed=0.5 if solver == "r6p_1lin" else 0.0):
        u = estimate_numpy(f.points_px, f.X, cam, solver, OPTS)
        c = estimate_compiled(f.points_px, f.X, cam, solver, OPTS)
        assert u.success and c.success
        assert (u.implementation, c.implementation) == ("numpy", "compiled")
        assert u.ignored_inputs == c.ignored_inputs == ()
        rot_u, rot_c = rotation_angle_deg(u.model.R, f.R), rotation_angle_deg(c.model.R, f.R)
        assert rot_u <= 1.5 * rot_c + 0.01
        assert rotation_angle_deg(u.model.R, c.model.R) <= 0.02 + rot_c
        pos_u = np.linalg.norm(u.pose.position - f.position)
        pos_c = np.linalg.norm(c.pose.position - f.position)
        assert pos_u <= 1.5 * pos_c + 1e-3
        assert np.mean(u.inliers == c.inliers) >= 0.97
        assert u.num_valid == c.num_valid
        sd_u = np.sqrt(np.diag(u.covariance))
        sd_c = np.sqrt(np.diag(c.covariance))
        n = 12 if solver == "r6p_1lin" else 6
        ratio = sd_u[:n] / sd_c[:n]
        assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), ratio
        assert u.pose_covariance.shape == (6, 6)
        if solver == "r6p_1lin":
            om = np.linalg.norm(f.angular_velocity)
            err_u = np.linalg.norm(u.pose.angular_velocity - f.angular_velocity) / om
            err_c = np.linalg.norm(c.pose.angular_velocity - f.angular_velocity) / om
            assert err_u <= 1.5 * err_c + 0.01
            assert u.twist_covariance.shape == (6, 6)
            np.testing.assert_allclose(u.pose_covariance, u.pose_covariance.T)
        else:
            assert u.twist_covariance is None and c.twist_covariance is None
            np.testing.assert_array_equal(u.pose.angular_velocity, 0.0)


def _bad_inputs():
    """(name, pixels, points, camera) of frames that give no pose."""
    cam = paper_camera()
    rng = np.random.default_rng(7)
    f = make_frame(3, 100, rs_speed=0.5, noise_px=0.5)
    line = np.column_stack([np.linspace(-1, 1, 40), np.zeros(40), np.full(40, 5.0)])
    X_rand = rng.uniform(-2, 2, (80, 3)) + [0, 0, 6]
    nan_rows = f.points_px.copy()
    # (5 points on more than one plane: too few for any path; 6 to 11 the compiled
    # implementation poses from them alone, the NumPy one does not)
    nan_rows[: len(nan_rows) - 5] = np.nan
    return [
        ("too_few", f.points_px[:5], f.X[:5], cam),
        ("nan_rows", nan_rows, f.X, cam),
        ("collinear_3d", cam.project_rs(line, np.eye(3), np.zeros(3)), line, cam),
        (
            "pixels_on_a_line",
            np.column_stack([np.linspace(10, 900, 80), np.full(80, 400.0)]),
            X_rand,
            cam,
        ),
        ("all_outliers", rng.uniform(0, 1000, (80, 2)), X_rand, cam),
        ("identical_points", np.tile(f.points_px[:1], (30, 1)), np.tile(f.X[:1], (30, 1)), cam),
    ]


@pytest.mark.parametrize("case", _bad_inputs(), ids=lambda c: c[0])
def test_same_failure_reasons(case):
    """Bad input gives the compiled path's failure reason and row counts, never an
    exception."""
    _, uv, X, cam = case
    u = estimate_numpy(uv, X, cam, "r6p_1lin", OPTS)
    c = estimate_compiled(uv, X, cam, "r6p_1lin", OPTS)
    assert not c.success
    assert (u.implementation, c.implementation) == ("numpy", "compiled")
    assert (u.success, u.failure) == (c.success, c.failure)
    assert (u.num_valid, u.num_dropped, len(u.inliers)) == (
        c.num_valid,
        c.num_dropped,
        len(c.inliers),
    )


def test_shapes_and_solvers_raise():
    cam = paper_camera()
    with pytest.raises(ValueError):
        estimate_numpy(np.zeros((10, 3)), np.zeros((10, 3)), cam)
    with pytest.raises(ValueError, match="compiled"):
        estimate_numpy(np.zeros((10, 2)), np.zeros((10, 3)), cam, "r9p")
    with pytest.raises(ValueError, match="implementation"):
        estimate_rs_pose(np.zeros((10, 2)), np.zeros((10, 3)), cam, implementation="gpu")


def test_ignored_inputs_recorded():
    """The NumPy implementation lists the inputs it was given and could not use (and its
    estimate equals the one without them); the compiled one uses them all, except a gyro for
    the global-shutter P3P."""
    cam = paper_camera()
    f = _frames(1)[0]
    n = len(f.X)
    gyro = GyroMeasurement(np.array([0.1, 0.0, 0.0]), 1e-4 * np.eye(3))
    extra = {
        "scores": np.linspace(1.0, 0.0, n),
        "point_sigma": np.full(n, 0.01),
    }
    plain = estimate_numpy(f.points_px, f.X, cam, "r6p_1lin", OPTS)
    opts = EstimateOptions(
        plausibility=OPTS.plausibility, refine=RefineOptions(acceleration_sensitivity=True)
    )
    u = estimate_rs_pose(f.points_px, f.X, cam, "r6p_1lin", opts, implementation="numpy", **extra)
    assert u.implementation == "numpy"
    assert u.ignored_inputs == ("scores", "point_sigma")
    assert set(u.ignored_inputs) <= set(NUMPY_UNUSED)
    np.testing.assert_array_equal(u.model.R, plain.model.R)
    np.testing.assert_array_equal(u.inliers, plain.inliers)
    c = estimate_compiled(f.points_px, f.X, cam, "r6p_1lin", OPTS)
    assert c.ignored_inputs == ()
    for implementation in ("compiled", "numpy"):
        p = estimate_rs_pose(
            f.points_px, f.X, cam, "p3p", OPTS, gyro=gyro, implementation=implementation
        )
        assert p.implementation == implementation and p.ignored_inputs == ("gyro",)
        assert not p.gyro_used


def test_acceleration_sensitivity_as_compiled():
    """``refine.acceleration_sensitivity`` on the NumPy implementation (the video tracker's
    twist filter needs it): the (12, 6) sensitivity within 2 % (Frobenius norm) of the
    compiled one on the same frames, with and without a gyro."""
    from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence, make_trajectory

    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=3, num_points=300, seed=2), trajectory=make_trajectory("shake")
    )
    opts = EstimateOptions(refine=RefineOptions(acceleration_sensitivity=True))
    for f in frames:
        for gyro in (None, GyroMeasurement(f.angular_velocity, 1e-5 * np.eye(3))):
            u, c = (
                estimate_rs_pose(f.uv, f.xyz, cam, options=opts, gyro=gyro, implementation=i)
                for i in ("numpy", "compiled")
            )
            assert u.ignored_inputs == ()
            G, Gc = u.acceleration_sensitivity, c.acceleration_sensitivity
            assert G.shape == (12, 6)
            assert np.linalg.norm(G - Gc) < 0.02 * np.linalg.norm(Gc)


def _truth_error(est, f):
    """(rotation error deg, position error) of an estimate against the frame's truth."""
    pos = -est.model.R.T @ est.model.C
    return rotation_angle_deg(est.model.R, f.R), float(np.linalg.norm(pos - f.position))


def _turned(f, deg):
    """The frame's true model with its rotation turned by ``deg`` about the optical axis."""
    from rs_localizer.geometry import rotvec_to_matrix
    from rs_localizer.pose import RSModel

    Rz = rotvec_to_matrix(np.array([0.0, 0.0, np.radians(deg)]))
    return RSModel(Rz @ f.R, Rz @ f.C, f.w, f.t)


def test_initial_model_on_numpy():
    """``initial_model`` on the NumPy implementation, as on the compiled one: a prediction
    near the truth (0.3 deg off) explains the frame's inliers, seeds RANSAC
    (``initial_used``, ``initial_explained`` within 3 % of the compiled count) and the
    estimate is as accurate as the cold one against the truth, with as many inliers; a wrong
    one (40 deg off) explains few points, is not used and the frame is solved cold (RANSAC
    from P3P samples) to the same accuracy."""
    from rs_localizer.estimation.options import InitialModel

    cam = paper_camera()
    for f in _frames(3):
        cold = estimate_numpy(f.points_px, f.X, cam, "r6p_1lin", OPTS)
        near = InitialModel(_turned(f, 0.3), gate_px=20.0, min_explained=100)
        wrong = InitialModel(_turned(f, 40.0), gate_px=20.0, min_explained=100)
        for init, used in ((near, True), (wrong, False)):
            u, c = (
                estimate_rs_pose(
                    f.points_px, f.X, cam, "r6p_1lin", OPTS, initial_model=init, implementation=i
                )
                for i in ("numpy", "compiled")
            )
            assert u.success and u.ignored_inputs == ()
            assert u.initial_used == c.initial_used == used
            if used:
                assert abs(u.initial_explained - c.initial_explained) <= 0.03 * c.initial_explained
                assert u.initial_explained >= 0.9 * np.count_nonzero(f.inlier)
            else:
                assert u.initial_explained < 100
            du, dc = _truth_error(u, f), _truth_error(cold, f)
            assert du[0] <= 1.5 * dc[0] + 0.02 and du[1] <= 1.5 * dc[1] + 0.002
            assert u.num_inliers >= 0.97 * cold.num_inliers


def test_gyro_on_numpy():
    """A gyro on the NumPy implementation, as on the compiled one: a right measurement (the
    simulated angular velocity) is used (``gyro_used``, not rejected) and the estimate's
    angular velocity is at least as close to the truth as the frame's own; a wrong one
    (3 rad/s off, tight covariance) is rejected by the image-alone check, and the estimate
    is the one without the gyro."""
    cam = paper_camera()
    for f in _frames(3, rs_speed=0.3):
        plain = estimate_numpy(f.points_px, f.X, cam, "r6p_1lin", OPTS)
        right = GyroMeasurement(f.angular_velocity, 1e-4 * np.eye(3))
        wrong = GyroMeasurement(f.angular_velocity + np.array([3.0, 0.0, 0.0]), 1e-4 * np.eye(3))
        u = estimate_rs_pose(
            f.points_px, f.X, cam, "r6p_1lin", OPTS, gyro=right, implementation="numpy"
        )
        c = estimate_rs_pose(f.points_px, f.X, cam, "r6p_1lin", OPTS, gyro=right)
        assert u.success and u.gyro_used and not u.gyro_rejected and u.ignored_inputs == ()
        assert c.gyro_used and not c.gyro_rejected
        e_u = np.linalg.norm(u.pose.angular_velocity - f.angular_velocity)
        e_plain = np.linalg.norm(plain.pose.angular_velocity - f.angular_velocity)
        assert e_u <= e_plain + 1e-3
        r = estimate_rs_pose(
            f.points_px, f.X, cam, "r6p_1lin", OPTS, gyro=wrong, implementation="numpy"
        )
        assert r.success and r.gyro_rejected and not r.gyro_used and r.gyro_rejection
        np.testing.assert_allclose(r.model.R, plain.model.R, atol=1e-12)


_NO_COMPILE = """
import numpy as np
from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.gyro import GyroMeasurement
from rs_localizer.estimation.options import InitialModel
from rs_localizer.sim.synthetic import make_frame, paper_camera
cam = paper_camera()
out = []
for k in range(3):
    f = make_frame(k, 200, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
    e = estimate_rs_pose(f.points_px, f.X, cam, implementation="numpy")
    out.append(bool(e.success) and e.implementation == "numpy")
# a prediction (pulled in: 60 px off at the gate) and a gyro
f = make_frame(5, 200, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
init = InitialModel((f.R, f.C + [0.02, 0, 0], f.w, f.t), gate_px=200.0, min_explained=100)
gyro = GyroMeasurement(f.angular_velocity, 1e-4 * np.eye(3))
e = estimate_rs_pose(f.points_px, f.X, cam, initial_model=init, gyro=gyro,
                     implementation="numpy")
out.append(bool(e.success) and e.initial_used and e.gyro_used)
result = {"solved": out}
"""


def test_compiles_nothing(tmp_path):
    """In a fresh process with an empty numba cache (besides what the package's own
    ``__pycache__`` seeds into it, jit_cache.seed_cache), the NumPy implementation solves frames
    (one with an initial model and a gyro) and numba compiles no kernel (numba's compile
    events, jit_cache.compile_progress) nor loads one (no numba dispatcher of the package has
    a compiled version)."""
    res = run_on_empty_cache(_NO_COMPILE, tmp_path, timeout=120)
    assert res["result"]["solved"] == [True, True, True, True]
    assert res["kernels"] == []
    assert res["used"] == []  # (no kernel compiled or loaded from the cache)


@pytest.mark.parametrize("scene", ["plane", "board"])
def test_planar_frames_as_accurate(scene):
    """On planar frames (a plane of points with 20 % outliers, a calibration board) both paths
    are maximum a posteriori with the motion prior; against the ground truth the NumPy
    path's median rotation, position and angular-velocity errors over five frames are within
    1.5x the compiled path's (plus 0.05 deg, 2 mm, 5 %)."""
    from rs_localizer.sim.planar import make_planar_frame

    errs = {"u": [], "c": []}
    for k in range(5):
        f = make_planar_frame(k, scene, outlier_ratio=0.2 if scene == "plane" else 0.0)
        u = estimate_numpy(f.points_px, f.X, f.camera)
        c = estimate_compiled(f.points_px, f.X, f.camera)
        for key, e in (("u", u), ("c", c)):
            assert e.success and e.motion_prior_used
            om = np.linalg.norm(f.angular_velocity)
            errs[key].append(
                (
                    rotation_angle_deg(e.model.R, f.R),
                    np.linalg.norm(e.pose.position - f.position),
                    np.linalg.norm(e.pose.angular_velocity - f.angular_velocity) / om,
                )
            )
        assert u.num_inliers == c.num_inliers
    med_u, med_c = np.median(errs["u"], axis=0), np.median(errs["c"], axis=0)
    assert np.all(med_u <= 1.5 * med_c + np.array([0.05, 0.002, 0.05])), (med_u, med_c)


def test_numpy_helpers_agree_with_the_compiled_ones():
    """The NumPy copies of the prepare stage's helpers (frame, degeneracy and planarity
    tests, condition number) give what the compiled ones give: the same rows and
    normalization, the same verdicts, the same values to rounding."""
    from rs_localizer.estimation.degeneracy import condition_number, planarity
    from rs_localizer.estimation.frame import prepare_frame
    from rs_localizer.estimation.ransac import seeded_rng

    cam = paper_camera()
    rng = np.random.default_rng(5)
    for k in range(4):
        f = make_frame(300 + k, 120, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
        uv = f.points_px.copy()
        uv[:3] = np.nan
        a = prepare_frame(uv, f.X, cam, 1e3, seeded_rng(k))
        b = prepare_frame(uv, f.X, cam, 1e3, seeded_rng(k), compiled=False)
        np.testing.assert_array_equal(a.rows, b.rows)
        np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(b.r, a.r, rtol=0, atol=1e-12)
        np.testing.assert_allclose(b.r0e, a.r0e, rtol=0, atol=1e-12)
        for mask in (np.ones(len(a.x), bool), rng.random(len(a.x)) < 0.5, np.arange(len(a.x)) < 3):
            assert a.degenerate(mask, 2.0) == a.degenerate(mask, 2.0, compiled=False)
            np.testing.assert_allclose(
                planarity(a.X, mask, compiled=False), planarity(a.X, mask), rtol=1e-9, atol=1e-7
            )
    line = np.column_stack([np.linspace(-1, 1, 20), np.zeros(20), np.full(20, 5.0)])
    fr = prepare_frame(cam.project_rs(line, np.eye(3), np.zeros(3)), line, cam, 1e3)
    assert fr.degenerate(np.ones(20, bool), 2.0) and fr.degenerate(np.ones(20, bool), 2.0, False)
    A = rng.normal(size=(12, 12))
    H = A @ A.T
    np.testing.assert_allclose(condition_number(H, compiled=False), condition_number(H), rtol=1e-8)
    H[3, 3] = 0.0
    assert condition_number(H, compiled=False) == condition_number(H) == np.inf


def test_numpy_samples_are_the_compiled_samples():
    """The NumPy implementation draws RANSAC's samples as the compiled sources do: the same
    (K, s) indices from the same uniforms (pools from a minimal sample's size up, uniforms
    at both ends of [0, 1))."""
    from rs_localizer.estimation.sampling import draw_samples, draw_samples_numpy

    rng = np.random.default_rng(3)
    for pool, s in ((3, 3), (6, 6), (7, 6), (30, 6), (300, 6), (300, 3)):
        u = rng.random((400, s))
        u[:5], u[5:10] = 0.0, np.nextafter(1.0, 0.0)
        np.testing.assert_array_equal(draw_samples_numpy(u, pool), draw_samples(u, pool))


def test_numpy_final_checks_agree_with_the_compiled_ones():
    """The final stage's NumPy forms (finalize.final_estimate with compiled=False) give what
    the compiled kernels give on the same models: the plausibility and cheirality verdict and
    the count behind the camera, the image errors, the physical velocities and the propagated
    covariances (to rounding)."""
    from rs_localizer.estimation.frame import prepare_frame
    from rs_localizer.estimation.plausibility import final_model_check, final_model_check_numpy
    from rs_localizer.estimation.result import output_covariance, physical_velocities

    cam = paper_camera()
    rng = np.random.default_rng(11)
    f = make_frame(41, 80, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
    fr = prepare_frame(f.points_px, f.X, cam, 1e3, np.random.default_rng(0))
    fr.spr = cam.seconds_per_unit_r
    est = estimate_compiled(f.points_px, f.X, cam, "r6p_1lin", OPTS)
    R, C, w, t = (np.array(a, dtype=float) for a in est.model)
    tau = fr.r - fr.r0
    inl = rng.random(len(fr.x)) < 0.7
    flipped = (np.diag([1.0, -1.0, -1.0]) @ R, -C, w, t)  # (the scene behind the camera)
    for model, bounds in (((R, C, w, t), (np.inf, np.inf)), ((R, C, w, t), (1e-12, 1e-12))):
        args = (*model, fr.X, tau, inl, *bounds)
        assert final_model_check_numpy(*args) == tuple(final_model_check(*args))
    args = (*(np.ascontiguousarray(a) for a in flipped), fr.X, tau, inl, np.inf, np.inf)
    assert final_model_check_numpy(*args) == tuple(final_model_check(*args))
    assert final_model_check_numpy(*args)[0] == 2
    e_c, e_n = fr.errors((R, C, w, t)), fr.errors((R, C, w, t), compiled=False)
    np.testing.assert_allclose(e_n, e_c, rtol=1e-9, atol=1e-12)
    for a, b in zip(
        physical_velocities(R, C, w, t, fr.spr, compiled=False),
        physical_velocities(R, C, w, t, fr.spr),
        strict=True,
    ):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    A = rng.normal(size=(12, 12))
    cov = 1e-6 * A @ A.T
    for s in (fr.spr, 0.0):
        u, c = (
            output_covariance(cov, R, C, w, s, compiled=False),
            output_covariance(cov, R, C, w, s),
        )
        for a, b in zip(u, c, strict=True):
            if b is None:
                assert a is None
            else:
                np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-18)
