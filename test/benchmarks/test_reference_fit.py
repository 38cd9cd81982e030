"""benchmarks.reference_fit against ground truth: on a synthetic pinhole camera seeing tags whose
corners carry a shift common to each tag plus their own noise, the delta chi-square of the true
pose is chi-square of 6 degrees of freedom, the random-effect variances are recovered, and the
sandwich covariance covers the truth where the independent corners' covariance does not; on
TagSLAM's test_2 (skipped when absent) the joint solution's poses are its corners' best fit."""

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from benchmarks.joint_reference import joint_reference, with_reference
from benchmarks.reference_fit import (
    K6,
    delta_chi2,
    measure,
    shift_covariance,
    tag_shift_variances,
)
from benchmarks.tagslam_data import FOLDER, RealRig, load_test2, tag_corners

F = 600.0  # px


def _scene(rng, tags=8):
    """(4 tags, 3) corners of ``tags`` 0.16 m tags 1.5-3 m in front of the camera, turned."""
    out = []
    for _ in range(tags):
        R = Rotation.from_rotvec(rng.normal(scale=0.4, size=3)).as_matrix()
        p = np.r_[rng.uniform(-1, 1, 2), rng.uniform(1.5, 3.0)]
        out.append(tag_corners(0.16) @ R.T + p)
    return np.concatenate(out)


def _project(theta, X):
    R = Rotation.from_rotvec(theta[:3]).as_matrix()
    P = X @ R.T + theta[3:]
    return F * P[:, :2] / P[:, 2:]


def _trial(rng, s_t, s_n):
    """One frame: the least-squares pose's error (6,), its residuals (N, 2), its Jacobian."""
    X = _scene(rng)
    truth = np.r_[rng.normal(scale=0.05, size=3), rng.normal(scale=0.05, size=3)]
    shift = np.repeat(rng.normal(scale=s_t, size=(len(X) // 4, 2)), 4, axis=0)
    uv = _project(truth, X) + shift + rng.normal(scale=s_n, size=(len(X), 2))
    fit = least_squares(lambda th: (_project(th, X) - uv).ravel(), truth, xtol=1e-14, ftol=1e-14)
    e = (_project(fit.x, X) - uv).reshape(-1, 2)
    return fit.x - truth, e, fit.jac, (_project(truth, X) - uv)


def _nees(rng, s_t, s_n, trials=300):
    """Per trial: the truth's NEES (6 dof) in the sandwich covariance and in the independent
    corners' ``sigma^2 (J^T J)^-1``, and the true pose's delta chi-square."""
    out = []
    for _ in range(trials):
        d, e, J, e_truth = _trial(rng, s_t, s_n)
        s_n2, s_t2 = tag_shift_variances(e.reshape(-1, 4, 2))
        s2 = float((e**2).sum()) / (e.size - 6)
        shifted = shift_covariance(J, s_n2, s_t2)
        plain = shift_covariance(J, s2, 0.0)
        out.append((d @ np.linalg.solve(shifted, d), d @ np.linalg.solve(plain, d),
                    delta_chi2(e_truth, e)))  # fmt: skip
    return np.array(out)


def test_delta_chi2_of_the_truth_is_chi_square_6():
    """Independent Gaussian corners: the true pose's delta chi-square has mean ~6 and lies
    below the 99.73 % quantile in nearly every frame; the best fit's own is 0."""
    rng = np.random.default_rng(0)
    n = _nees(rng, 0.0, 0.5)
    assert 5.0 < n[:, 2].mean() < 7.5
    assert np.mean(n[:, 2] <= K6) >= 0.97
    e = rng.normal(size=(40, 2))
    assert delta_chi2(e, e) == 0.0


def test_tag_shift_variances_recover_known_variances():
    """Residuals of 2000 tags with a known shift (0.3 px) and own noise (0.2 px): both
    variances within 10 %; without a shift the shift's variance is near 0."""
    rng = np.random.default_rng(1)
    E = rng.normal(scale=0.3, size=(2000, 1, 2)) + rng.normal(scale=0.2, size=(2000, 4, 2))
    s_n2, s_t2 = tag_shift_variances(E, n_free=0)
    assert s_n2 == pytest.approx(0.04, rel=0.1) and s_t2 == pytest.approx(0.09, rel=0.1)
    s_n2, s_t2 = tag_shift_variances(rng.normal(scale=0.2, size=(2000, 4, 2)), n_free=0)
    assert s_n2 == pytest.approx(0.04, rel=0.1) and s_t2 < 0.002


def test_sandwich_covers_the_truth_with_a_tag_shift():
    """Each tag's corners shifted together (0.3 px) plus their own noise (0.15 px): the truth
    within 3 sigma (NEES of 6 dof below its 99.73 % quantile) in >= 90 % of frames and the mean
    NEES within [0.5, 2] x 6 with the shift's covariance; the independent corners' covariance
    falls short (< 90 %, mean NEES > 2 x 6). Without a shift both are right."""
    rng = np.random.default_rng(2)
    n = _nees(rng, 0.3, 0.15)
    assert np.mean(n[:, 0] <= K6) >= 0.9 and 3.0 <= n[:, 0].mean() <= 12.0
    assert np.mean(n[:, 1] <= K6) < 0.9 and n[:, 1].mean() > 12.0
    n = _nees(rng, 0.0, 0.3)
    for k in (0, 1):
        assert np.mean(n[:, k] <= K6) >= 0.9 and 3.0 <= n[:, k].mean() <= 12.0


@pytest.mark.skipif(not FOLDER.is_dir(), reason=f"{FOLDER} absent")
def test_the_joint_solutions_poses_are_its_corners_best_fit(tmp_path):
    """On the joint solution's map and mountings the rig estimator lands on its poses (delta
    chi-square near 0: both minimize the same corners' errors), within 3 sigma of them."""
    rig = load_test2(FOLDER)
    joint = with_reference(rig, joint_reference(rig, tmp_path))
    part = RealRig(joint.cameras, joint.mounts, joint.frames[::8], joint.reference, joint.name,
                   tags=joint.tags, tag_ids=joint.tag_ids)  # fmt: skip
    m = measure(part, {"joint": joint.reference, "tagslam": rig.reference})
    assert m["frames"] >= 20
    assert np.median(m["delta_chi2"]) < 0.5
    assert m["within"]["joint"].mean() >= 0.95
