"""Accuracy against ground truth in another frame than the estimate's: the rigid fit of the
frames (rs_localizer.accuracy.frame_fit_summary) recovers a known transform and the errors
after it, against an independent construction."""

import numpy as np
from scipy.spatial.transform import Rotation

from rs_localizer.accuracy import align_frames, frame_fit_summary


def _trajectory(n: int, seed: int) -> list:
    rng = np.random.default_rng(seed)
    return [
        (Rotation.random(random_state=rng).as_matrix(), rng.normal(0, 1.0, 3)) for _ in range(n)
    ]


def test_ground_truth_in_another_frame_is_found_and_fitted():
    est = _trajectory(40, 0)
    R = Rotation.from_rotvec([0.3, -1.2, 2.0]).as_matrix()  # (120 deg apart)
    t = np.array([2.0, -1.0, 0.5])
    rng = np.random.default_rng(1)
    gt = []
    for Re, pe in est:  # the truth: the estimate in another frame, plus 0.1 deg / 1 cm noise
        dR = Rotation.from_rotvec(rng.normal(0, np.radians(0.1), 3)).as_matrix()
        gt.append((dR @ R @ Re, R @ pe + t + rng.normal(0, 0.01, 3)))
    Rf, tf = align_frames(est, gt)
    assert np.degrees(Rotation.from_matrix(Rf @ R.T).magnitude()) < 0.1
    assert np.linalg.norm(tf - t) < 0.01
    fit = frame_fit_summary(est, gt)
    assert (
        fit["other_frame"]
        and abs(fit["rot_deg"] - np.degrees(np.linalg.norm([0.3, -1.2, 2.0]))) < 0.1
    )
    assert fit["aligned"]["rot_deg"]["median"] < 0.3 and fit["aligned"]["pos_m"]["median"] < 0.03
    # the same frame: no offset said
    same = frame_fit_summary(est, [(Re, pe) for Re, pe in est])
    assert not same["other_frame"] and same["aligned"]["pos_m"]["max"] < 1e-12
    assert frame_fit_summary(est[:2], gt[:2]) is None
