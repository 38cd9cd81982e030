"""The marker-map benchmark compares localization against two maps on the frames both solve:
a map that fails on the hard frames must not look better for it; and it measures a map's shape
after a rigid fit that a few markers far off do not turn."""

import numpy as np
from scipy.spatial.transform import Rotation

from benchmarks.bench_mapping import paired_ratios
from rs_localizer.sim.marker_mapping import robust_rigid_fit


def _result(per_frame: dict) -> dict:
    rot = [r for r, _ in per_frame.values()]
    pos = [p for _, p in per_frame.values()]
    return dict(
        frames=10,
        solved=len(per_frame),
        rotation_deg=float(np.median(rot)),
        position_cm=float(np.median(pos)),
        per_frame=per_frame,
    )


def test_ratios_are_taken_over_the_frames_both_maps_solve():
    rng = np.random.default_rng(0)
    ref = {k: (float(rng.uniform(0.1, 2.0)), float(rng.uniform(0.5, 5.0))) for k in range(10)}
    # the other map: twice the reference's errors, but it fails on the five hardest frames
    hard = sorted(ref, key=lambda k: -ref[k][0])[:5]
    other = {k: (2 * r, 2 * p) for k, (r, p) in ref.items() if k not in hard}
    rr, rp, both = paired_ratios(_result(other), _result(ref))
    assert both == 5
    assert np.isclose(rr, 2.0) and np.isclose(rp, 2.0)
    # the medians over each map's own frames would hide most of that
    naive = _result(other)["rotation_deg"] / _result(ref)["rotation_deg"]
    assert naive < 0.85 * rr


def test_no_frame_in_common_gives_nan():
    a, b = _result({0: (1.0, 1.0)}), _result({1: (1.0, 1.0)})
    rr, rp, both = paired_ratios(a, b)
    assert both == 0 and np.isnan(rr) and np.isnan(rp)


def test_robust_rigid_fit_recovers_a_known_motion_despite_gross_outliers():
    rng = np.random.default_rng(3)
    truth = rng.uniform([0, 0, 0], [4.5, 4.0, 2.6], (120, 3))  # corners of a room's markers
    R = Rotation.from_rotvec([0.02, -0.03, 0.05]).as_matrix()
    t = np.array([0.05, -0.10, 0.02])
    built = (truth - t) @ R + rng.normal(0, 0.005, truth.shape)  # truth = built @ R.T + t
    bad = rng.choice(len(truth), 8, replace=False)
    built[bad] += rng.normal(0, 0.5, (8, 3))  # a few markers far off
    Rr, tr = robust_rigid_fit(built, truth)
    assert np.degrees(Rotation.from_matrix(Rr @ R.T).magnitude()) < 0.05
    assert np.linalg.norm(tr - t) < 0.005
    good = np.setdiff1d(np.arange(len(truth)), bad)
    e = np.linalg.norm(built[good] @ Rr.T + tr - truth[good], axis=1)
    assert np.median(e) < 1.1 * 0.005 * np.sqrt(3)  # the noise alone (median ~1.54 sigma)
    # the least-squares fit of all points is turned by the outliers
    ca, cb = built.mean(0), truth.mean(0)
    rot, _ = Rotation.align_vectors(truth - cb, built - ca)
    assert np.degrees((rot * Rotation.from_matrix(R).inv()).magnitude()) > 0.2


def test_robust_rigid_fit_is_exact_without_noise():
    rng = np.random.default_rng(4)
    truth = rng.uniform(-2, 2, (40, 3))
    R = Rotation.from_rotvec([0.3, 0.1, -0.2]).as_matrix()
    t = np.array([1.0, 2.0, -0.5])
    Rr, tr = robust_rigid_fit((truth - t) @ R, truth)
    assert np.allclose(Rr, R, atol=1e-9) and np.allclose(tr, t, atol=1e-9)
