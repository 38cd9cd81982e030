"""The trajectory errors of ``rs-localizer evaluate`` against independent computations: the
Umeyama alignment recovers a known random similarity and agrees with SciPy's Kabsch fit on noisy
points; APE and RPE equal evo's definitions written out with 4x4 matrices; the share of poses
within 3 sigma of a covariance their errors were drawn from is the chi-square's."""

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rs_localizer.accuracy import (
    absolute_pose_errors,
    covariance_distances,
    error_statistics,
    relative_pose_errors,
    umeyama_alignment,
)


def _similarity(rng):
    return Rotation.random(random_state=rng).as_matrix(), rng.normal(0, 3, 3), rng.uniform(0.5, 2)


@pytest.mark.parametrize("seed", range(5))
def test_umeyama_recovers_a_known_similarity(seed):
    rng = np.random.default_rng(seed)
    R, t, s = _similarity(rng)
    x = rng.normal(0, 2, (20, 3))
    y = s * x @ R.T + t
    R_s, t_s, s_s = umeyama_alignment(x, y, with_scale=True)
    assert np.allclose(R_s, R, atol=1e-10) and np.allclose(t_s, t, atol=1e-9)
    assert s_s == pytest.approx(s, rel=1e-10)
    R_1, t_1, s_1 = umeyama_alignment(x, x @ R.T + t)  # (SE(3): scale 1)
    assert s_1 == 1.0 and np.allclose(R_1, R, atol=1e-10) and np.allclose(t_1, t, atol=1e-9)


def test_umeyama_on_noisy_points_is_scipys_kabsch_fit():
    rng = np.random.default_rng(7)
    R, t, _ = _similarity(rng)
    x = rng.normal(0, 1, (50, 3))
    y = x @ R.T + t + rng.normal(0, 0.05, (50, 3))
    R_u, t_u, _ = umeyama_alignment(x, y)
    # independent: SciPy's align_vectors on the centred points, the translation from the means
    R_k = Rotation.align_vectors(y - y.mean(0), x - x.mean(0))[0].as_matrix()
    assert np.allclose(R_u, R_k, atol=1e-9)
    assert np.allclose(t_u, y.mean(0) - R_k @ x.mean(0), atol=1e-9)
    assert np.degrees(Rotation.from_matrix(R_u @ R.T).magnitude()) < 2.0


def test_umeyama_refuses_points_on_a_line():
    x = np.outer(np.arange(5.0), [1.0, 2.0, 0.5])
    with pytest.raises(ValueError, match="one line"):
        umeyama_alignment(x, x + 1.0)
    with pytest.raises(ValueError, match="expected two"):
        umeyama_alignment(x[:2], x[:2])


def test_weighted_umeyama_is_the_fit_to_repeated_points_and_scipys_weighted_kabsch():
    rng = np.random.default_rng(11)
    R, t, s = _similarity(rng)
    x = rng.normal(0, 1, (30, 3))
    y = s * x @ R.T + t + rng.normal(0, 0.05, (30, 3))
    k = rng.integers(1, 4, 30)
    R_w, t_w, s_w = umeyama_alignment(x, y, with_scale=True, weights=k)
    R_r, t_r, s_r = umeyama_alignment(np.repeat(x, k, 0), np.repeat(y, k, 0), with_scale=True)
    assert np.allclose(R_w, R_r, atol=1e-12) and np.allclose(t_w, t_r, atol=1e-12)
    assert s_w == pytest.approx(s_r, rel=1e-12)
    # independent: SciPy's weighted align_vectors on the points about their weighted means
    mx, my = k @ x / k.sum(), k @ y / k.sum()
    R_k = Rotation.align_vectors(y - my, x - mx, weights=k)[0].as_matrix()
    assert np.allclose(R_w, R_k, atol=1e-9)
    assert np.allclose(t_w, my - s_w * R_k @ mx, atol=1e-9)


def test_umeyama_on_a_line_when_asked_gives_a_rotation_that_fits():
    d = np.array([1.0, 2.0, 0.5])
    R = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix()
    x = np.outer(np.arange(5.0), d)
    R_l, t_l, s_l = umeyama_alignment(x, 2.0 * x @ R.T + 1.0, with_scale=True, any_on_line=True)
    assert np.linalg.det(R_l) == pytest.approx(1.0) and np.allclose(R_l @ R_l.T, np.eye(3))
    assert s_l == pytest.approx(2.0) and np.allclose(2.0 * x @ R_l.T + t_l, 2.0 * x @ R.T + 1.0)


def _T(R, p):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def _angle_deg(R):
    return np.degrees(Rotation.from_matrix(R).magnitude())


def _trajectories(n, seed):
    rng = np.random.default_rng(seed)
    R_ref = Rotation.random(n, random_state=rng).as_matrix()
    p_ref = np.cumsum(rng.normal(0, 0.3, (n, 3)), 0)
    noise = Rotation.from_rotvec(rng.normal(0, 0.01, (n, 3))).as_matrix()
    return noise @ R_ref, p_ref + rng.normal(0, 0.02, (n, 3)), R_ref, p_ref


def test_ape_and_rpe_are_evos_definitions_with_4x4_matrices():
    R_e, p_e, R_r, p_r = _trajectories(23, 3)
    ape = absolute_pose_errors(R_e, p_e, R_r, p_r)
    for i in range(23):  # evo: E_i = Q_i^-1 P_i; translation part norm, rotation angle
        E = np.linalg.inv(_T(R_r[i], p_r[i])) @ _T(R_e[i], p_e[i])
        assert ape["pos_m"][i] == pytest.approx(np.linalg.norm(E[:3, 3]), abs=1e-12)
        assert ape["rot_deg"][i] == pytest.approx(_angle_deg(E[:3, :3]), abs=1e-6)
    for delta, all_pairs in ((1, False), (3, False), (3, True)):
        rpe = relative_pose_errors(R_e, p_e, R_r, p_r, delta, all_pairs)
        # evo's pairs: consecutive (0, d), (d, 2d), ...; all_pairs: (i, i + d) for every i
        ids = list(range(0, 23, delta))
        want = (
            [(i, i + delta) for i in range(23) if i + delta < 23]
            if all_pairs
            else list(itertools.pairwise(ids))
        )
        assert [tuple(p) for p in rpe["pairs"].tolist()] == want
        for k, (i, j) in enumerate(want):
            Q = np.linalg.inv(_T(R_r[i], p_r[i])) @ _T(R_r[j], p_r[j])
            P = np.linalg.inv(_T(R_e[i], p_e[i])) @ _T(R_e[j], p_e[j])
            E = np.linalg.inv(Q) @ P
            assert rpe["pos_m"][k] == pytest.approx(np.linalg.norm(E[:3, 3]), abs=1e-12)
            assert rpe["rot_deg"][k] == pytest.approx(_angle_deg(E[:3, :3]), abs=1e-6)


def test_rpe_ignores_a_rigid_change_of_map_frame_ape_does_not():
    R_e, p_e, R_r, p_r = _trajectories(15, 4)
    R, t = Rotation.from_rotvec([0.2, -0.1, 0.4]).as_matrix(), np.array([1.0, 2.0, -0.5])
    a = relative_pose_errors(R_e, p_e, R_r, p_r)
    b = relative_pose_errors(R @ R_e, p_e @ R.T + t, R_r, p_r)
    assert np.allclose(a["pos_m"], b["pos_m"]) and np.allclose(
        a["rot_deg"], b["rot_deg"], atol=1e-6
    )
    assert absolute_pose_errors(R @ R_e, p_e @ R.T + t, R_r, p_r)["pos_m"].min() > 0.5


def test_errors_drawn_from_the_covariance_are_within_3_sigma_as_often_as_chi_square_says():
    rng = np.random.default_rng(5)
    n = 4000
    R_r = Rotation.random(n, random_state=rng).as_matrix()
    p_r = rng.normal(0, 1, (n, 3))
    A = rng.normal(0, 1, (6, 6))
    C = A @ A.T * 1e-4 + np.diag([1e-4] * 3 + [1e-6] * 3)  # (a correlated 6x6 covariance)
    e = rng.multivariate_normal(np.zeros(6), C, n)
    p_e = p_r + e[:, :3]
    R_e = Rotation.from_rotvec(e[:, 3:]).as_matrix() @ R_r  # (about the map axes)
    d2 = covariance_distances(R_e, p_e, R_r, p_r, np.broadcast_to(C, (n, 6, 6)))
    from scipy.stats import chi2

    share = np.mean(d2 <= chi2.ppf(0.9973, 6))
    assert share == pytest.approx(0.9973, abs=0.003)
    assert np.mean(d2) == pytest.approx(6.0, rel=0.05)
    # a covariance stated 10x too small (in sigma) puts most poses outside
    d2_small = covariance_distances(R_e, p_e, R_r, p_r, np.broadcast_to(C / 100, (n, 6, 6)))
    assert np.mean(d2_small <= chi2.ppf(0.9973, 6)) < 0.2
    # unknown (zeros): NaN, not counted
    assert np.isnan(
        covariance_distances(R_e[:2], p_e[:2], R_r[:2], p_r[:2], np.zeros((2, 6, 6)))
    ).all()


def test_error_statistics():
    s = error_statistics([3.0, 4.0, np.nan, 0.0])
    assert s["count"] == 3 and s["median"] == 3.0 and s["max"] == 4.0
    assert s["rmse"] == pytest.approx(np.sqrt(25 / 3))
    assert error_statistics([]) == {"count": 0}
