"""The fit-consistency check (``inconsistent_fit``): a wall of a 3D scene seen from behind.

Mirrored images, maps in a mirrored frame and correspondences reflected through the camera fit
one wall of a 3D scene exactly from outside the scene; the estimator must refuse them, and
never a true fit (corridor sequences with outliers, planar scenes)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rs_localizer.estimation import PlausibilityOptions, estimate_rs_pose
from rs_localizer.estimation.degeneracy import far_side_fraction
from rs_localizer.estimation.result import FAILURE_REASONS, INCONSISTENT_FIT
from rs_localizer.sim.attacks import (
    ATTACKS,
    TRUE_SETS,
    attack,
    corridor_frames,
    count,
)

FRAMES = 8


@pytest.fixture(scope="module")
def corridor():
    return corridor_frames(FRAMES, seed=7)


def test_far_side_fraction_counts_the_points_beyond_the_plane():
    rng = np.random.default_rng(0)
    wall = np.c_[rng.uniform(-2, 2, (50, 2)), np.zeros(50)]  # the plane z = 0
    near = np.c_[rng.uniform(-2, 2, (30, 2)), rng.uniform(0.5, 3.0, 30)]  # camera side
    far = np.c_[rng.uniform(-2, 2, (10, 2)), -rng.uniform(0.5, 3.0, 10)]
    on = np.c_[rng.uniform(-2, 2, (20, 2)), np.zeros(20)]  # on the plane: not counted
    X = np.concatenate([wall, near, far, on])
    inliers = np.arange(len(X)) < len(wall)
    assert far_side_fraction(X, inliers, np.array([0.0, 0.0, 5.0])) == pytest.approx(10 / 40)
    assert far_side_fraction(X, inliers, np.array([0.0, 0.0, -5.0])) == pytest.approx(30 / 40)
    assert far_side_fraction(wall, np.ones(50, bool), np.array([0.0, 0.0, 5.0])) == 0.0
    assert far_side_fraction(X, np.arange(len(X)) < 2, np.zeros(3)) == 0.0  # < 3 inliers
    with pytest.raises(ValueError):
        far_side_fraction(X, inliers[:-1], np.zeros(3))


def test_the_reason_is_documented():
    assert INCONSISTENT_FIT in FAILURE_REASONS
    assert f"`{INCONSISTENT_FIT}`" in (Path(__file__).parents[2] / "docs" / "node.md").read_text()


@pytest.mark.parametrize("kind", ATTACKS)
def test_mirrored_or_reflected_correspondences_give_no_pose(corridor, kind):
    """p3p fits a wall of these frames from behind unless the check refuses it; r6p_1lin
    must not succeed either."""
    frames = [attack(f, kind) for f in corridor]
    p3p = count(frames, "p3p", unchecked=True)
    assert p3p["success"] == 0
    assert p3p["unchecked"] >= FRAMES // 2  # (the check is what stops them)
    assert p3p["inconsistent"] == p3p["unchecked"]
    assert count(frames, "r6p_1lin")["success"] == 0


@pytest.mark.parametrize("name", list(TRUE_SETS))
def test_true_fits_are_never_refused(name):
    frames = list(TRUE_SETS[name](6, 3))
    for solver in ("r6p_1lin", "p3p"):
        for f in frames:
            e = estimate_rs_pose(f.points_px, f.points3d, f.camera, solver, f.options)
            assert e.failure != INCONSISTENT_FIT, (name, solver)


def test_the_check_can_be_turned_off(corridor):
    f = attack(corridor[0], "mirror_world")
    off = replace(f.options, plausibility=PlausibilityOptions(consistent_fit=False))
    on = estimate_rs_pose(f.points_px, f.points3d, f.camera, "p3p", f.options)
    unchecked = estimate_rs_pose(f.points_px, f.points3d, f.camera, "p3p", off)
    assert on.failure == INCONSISTENT_FIT
    assert unchecked.success and unchecked.inliers.mean() < 0.15  # one wall, from behind
    assert np.linalg.norm(unchecked.pose.position - f.position) > 1.0
