"""benchmarks.reference_fit against ground truth: on a synthetic pinhole camera seeing tags with
independent corner noise, the delta chi-square of the true pose is chi-square of 6 degrees of
freedom; on TagSLAM's test_2 (skipped when absent) the joint solution's poses are its corners'
best fit, and the rig's covariance with the corners grouped by tag holds TagSLAM's poses within
3 sigma more often than the independent corners' (the estimator's shared-shift covariance itself
is tested against ground truth in test/estimation/test_noise_model.py)."""

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from benchmarks.joint_reference import joint_reference, with_reference
from benchmarks.reference_fit import K6, delta_chi2, measure
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


def _delta_chi2s(rng, s_n, trials=300):
    """Per trial: the true pose's delta chi-square (independent corners of noise ``s_n``)."""
    out = []
    for _ in range(trials):
        _, e, _, e_truth = _trial(rng, 0.0, s_n)
        out.append(delta_chi2(e_truth, e))
    return np.array(out)


def test_delta_chi2_of_the_truth_is_chi_square_6():
    """Independent Gaussian corners: the true pose's delta chi-square has mean ~6 and lies
    below the 99.73 % quantile in nearly every frame; the best fit's own is 0."""
    rng = np.random.default_rng(0)
    n = _delta_chi2s(rng, 0.5)
    assert 5.0 < n.mean() < 7.5
    assert np.mean(n <= K6) >= 0.97
    e = rng.normal(size=(40, 2))
    assert delta_chi2(e, e) == 0.0


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
    assert m["within"]["joint"].mean() >= 0.95 and m["within_groups"]["joint"].mean() >= 0.95
    assert m["within_groups"]["tagslam"].mean() >= m["within"]["tagslam"].mean() + 0.2
