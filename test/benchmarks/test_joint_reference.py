"""The joint reference of a TagSLAM recording (benchmarks.joint_reference) on TagSLAM's test_2
(skipped when the data is absent): the bundle adjustment recovers a known solution from exact
corners, fits the recorded corners better than TagSLAM's published solution in TagSLAM's
gauge, is read back from its cache, and the rig estimator lands near it."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks.bench_real_rig import reference_residuals, rig_run, summary
from benchmarks.joint_reference import (
    halves,
    joint_reference,
    mounting_coverage,
    solve_joint,
    with_reference,
)
from benchmarks.tagslam_data import FOLDER, errors, load_test2

pytestmark = pytest.mark.skipif(not FOLDER.is_dir(), reason=f"{FOLDER} absent")


@pytest.fixture(scope="module")
def rig():
    return load_test2(FOLDER)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("joint")


@pytest.fixture(scope="module")
def joint(rig, cache):
    return joint_reference(rig, cache)


def test_exact_corners_give_back_their_solution_from_a_perturbed_start(
    rig, exact_corners_perturbed, assert_gives_back
):
    # corners projected exactly from TagSLAM's solution (the first 150 rig frames), the start
    # that solution with every free pose turned by ~0.3 deg and moved by ~3 mm: the solution
    # comes back (the anchored tag and the first camera's mounting stay where they are)
    start, frames, ids = exact_corners_perturbed(rig, 150, 3)
    sol = solve_joint(start)
    assert_gives_back(sol, rig, frames, ids, 1e-4, 1e-3)
    e = reference_residuals(with_reference(start, sol))[:, 1]
    assert np.max(e) < 1e-3


def test_the_joint_solution_fits_the_corners_better_than_tagslams(rig, joint):
    # (measured: median 0.346 -> 0.286 px, p90 0.796 -> 0.597)
    ours = reference_residuals(with_reference(rig, joint))[:, 1]
    theirs = reference_residuals(rig)[:, 1]
    assert len(ours) == len(theirs)
    assert np.median(ours) < 0.9 * np.median(theirs)
    assert np.percentile(ours, 90) < 0.8 * np.percentile(theirs, 90)
    # TagSLAM's gauge: the anchored tag and the first camera's mounting are TagSLAM's
    for i in rig.anchors:
        assert np.array_equal(joint.tags[i][0], rig.tags[i][0])
        assert np.array_equal(joint.tags[i][1], rig.tags[i][1])
    first = next(iter(rig.cameras))
    assert np.array_equal(joint.mounts[first][0], rig.mounts[first][0])
    # the two solutions are close (measured: rig poses 0.080 deg, 1.7 mm median apart)
    d = np.array([errors(*joint.poses[s], rig.reference[s]) for s in joint.poses])
    assert np.median(d[:, 0]) < 0.2 and np.median(d[:, 1]) < 4.0


def test_the_solution_is_read_back_from_its_cache(rig, joint, cache):
    assert len(list(cache.glob("test_2_*.npz"))) == 1
    again = joint_reference(rig, cache)
    assert again.info == joint.info
    for s, (R, C) in joint.poses.items():
        assert np.array_equal(again.poses[s][0], R) and np.array_equal(again.poses[s][1], C)
    for n, (R, c) in joint.mounts.items():
        assert np.array_equal(again.mounts[n][0], R) and np.array_equal(again.mounts[n][1], c)


def test_the_rig_estimator_lands_near_the_joint_solution(rig, joint):
    # the first 400 rig frames with tags, the joint solution's tag map and mountings given to
    # both methods (measured: 128 of 128 posed, 0.0014 deg and 0.036 mm median from the joint
    # solution's poses; PoseLib's generalized pose 0.024 deg and 0.53 mm; against TagSLAM's
    # solution 0.058 deg and 1.8 mm, PoseLib 0.063 deg and 1.8 mm)
    s = summary(rig_run(with_reference(rig, joint), 400))
    assert s["both"] > 100 and s["posed"] >= s["both"] - 2
    rot, pos = np.median(s["ours"], axis=0)
    assert rot < 0.01 and pos < 0.3
    assert s["ratio_rot"] < 0.3 and s["ratio_pos"] < 0.3


def test_mounting_coverage_measures_the_error_in_the_mountings_std():
    # a mounting 0.2 deg about the rig's z axis and 2.5 mm along its x axis from the
    # reference's, stated std 0.1 deg and 1 mm on every axis: k = 2.5 (the position's x),
    # NEES 2^2 + 2.5^2 = 10.25
    from rs_localizer.calibration import MountingEstimate
    from rs_localizer.frames import Mounting

    R = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()  # (rig -> camera)
    c = np.array([0.05, 0.01, -0.02])
    turn = Rotation.from_rotvec([0.0, 0.0, np.deg2rad(0.2)]).as_matrix()
    Rm = turn @ R.T  # (camera -> rig, turned in rig axes)
    pos = -R.T @ c + np.array([0.0025, 0.0, 0.0])
    C = np.diag([np.deg2rad(0.1) ** 2] * 3 + [1e-6] * 3)
    est = {"b": MountingEstimate("b", Mounting.from_pose(Rm, pos, covariance=C), 10, 0, 0, 0,
                                 0, 0)}  # fmt: skip
    out = mounting_coverage(est, {"b": (R, c)}, "a")["b"]
    assert abs(out["error_deg"] - 0.2) < 1e-9 and abs(out["error_mm"] - 2.5) < 1e-9
    assert abs(out["k"] - 2.5) < 1e-6 and abs(out["nees"] - 10.25) < 1e-6
    assert out["within"]  # (10.25 < 20.06, the 99.73 % quantile of 6 degrees of freedom)


def test_halves_measures_the_difference_in_both_halves_std():
    # two estimates of one mounting 0.3 deg apart about the rig's x axis and 4 mm apart along
    # z, each with std 0.1 deg and 1 mm on every axis: the difference's std sqrt(2) times
    # that, k = 4 / sqrt(2) (the position's z)
    from rs_localizer.calibration import MountingEstimate
    from rs_localizer.frames import Mounting

    C = np.diag([np.deg2rad(0.1) ** 2] * 3 + [1e-6] * 3)
    Ra = Rotation.from_rotvec([0.2, 0.1, -0.3]).as_matrix()
    Rb = Ra @ Rotation.from_rotvec([np.deg2rad(0.3), 0.0, 0.0]).as_matrix()
    pa = np.array([0.1, 0.0, 0.02])

    def est(R, p):
        return {"b": MountingEstimate("b", Mounting.from_pose(R, p, covariance=C), 10, 0, 0, 0,
                                      0, 0)}  # fmt: skip

    out = halves(est(Ra, pa), est(Rb, pa + [0.0, 0.0, 0.004]), "a")["b"]
    assert abs(out["diff_deg"] - 0.3) < 1e-9 and abs(out["diff_mm"] - 4.0) < 1e-9
    assert abs(out["k"] - 4.0 / np.sqrt(2)) < 1e-6
    assert abs(out["std_deg"] - 0.1 * np.sqrt(6)) < 1e-9
    assert abs(out["std_mm"] - np.sqrt(6)) < 1e-9
