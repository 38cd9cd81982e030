"""The benchmarks' tests' shared fixture: a TagSLAM recording's corners projected exactly from
its own solution, and a start away from it, which a joint solver of the recording's graph must
bring back (the tests of ``benchmarks.joint_reference`` and ``benchmarks.gtsam_reference``)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from benchmarks.tagslam_data import RealRig, errors, tag_corners


def _turned(R: np.ndarray, rng: np.random.Generator, deg: float) -> np.ndarray:
    return Rotation.from_rotvec(np.deg2rad(deg) * rng.normal(size=3) / np.sqrt(3)).as_matrix() @ R


def _exact_corners_perturbed(rig: RealRig, frames: int, seed: int) -> tuple[RealRig, list, dict]:
    """The first ``frames`` rig frames of ``rig`` with a reference pose, each camera's corners
    projected exactly (its camera model) from the reference's rig pose, mounting and tags; the
    start: that solution with every free pose (rig poses, mountings but the first camera's,
    tags but the anchored ones) turned by ~0.3 deg and moved by ~3 mm. Returns ``(start, the
    frames, stamp -> tag ids)``."""
    rng = np.random.default_rng(seed)
    out_frames, ids = [], {}
    for stamp, views in [f for f in rig.frames if f[0] in rig.reference][:frames]:
        R, C = rig.reference[stamp]
        out = {}
        for n, (_, X) in views.items():
            Rm, cm = rig.mounts[n]
            out[n] = (rig.cameras[n].project((X @ R.T + C) @ Rm.T + cm), X)
        out_frames.append((stamp, out))
        ids[stamp] = rig.tag_ids[stamp]
    first = next(iter(rig.cameras))
    start = RealRig(
        rig.cameras,
        {n: m if n == first else (_turned(m[0], rng, 0.3), m[1] + rng.normal(0, 0.002, 3))
         for n, m in rig.mounts.items()},
        out_frames,
        {s: (_turned(rig.reference[s][0], rng, 0.3), rig.reference[s][1]
             + rng.normal(0, 0.002, 3)) for s, _ in out_frames},
        "exact",
        tags={i: t if i in rig.anchors else (_turned(t[0], rng, 0.3),
                                             t[1] + rng.normal(0, 0.002, 3), t[2])
              for i, t in rig.tags.items()},
        tag_ids=ids,
        anchors=rig.anchors,
    )  # fmt: skip
    return start, out_frames, ids


@pytest.fixture
def exact_corners_perturbed():
    """:func:`_exact_corners_perturbed`: ``(rig, frames, seed) -> (start, frames, ids)``."""
    return _exact_corners_perturbed


def _assert_gives_back(sol, rig: RealRig, frames: list, ids: dict, deg: float, m: float) -> None:
    """``sol`` (a ``JointSolution`` solved from :func:`_exact_corners_perturbed`'s start) holds
    ``rig``'s reference rig poses of ``frames`` and its mountings within ``deg`` and ``m``, and
    the corners of every tag ``ids`` names within ``m / 100``."""
    d = np.array([errors(*sol.poses[s], rig.reference[s]) for s, _ in frames])
    assert np.max(d[:, 0]) < deg and np.max(d[:, 1]) < m
    for n, mount in rig.mounts.items():
        rot, pos = errors(*sol.mounts[n], mount)
        assert rot < deg and pos < m
    for i in {i for s, _ in frames for v in ids[s].values() for i in v}:
        R, p, side = sol.tags[i]
        moved = tag_corners(side) @ R.T + p - tag_corners(side) @ rig.tags[i][0].T - rig.tags[i][1]
        assert np.abs(moved).max() < m / 100


@pytest.fixture
def assert_gives_back():
    """:func:`_assert_gives_back`: ``(sol, rig, frames, ids, deg, m)``, asserting."""
    return _assert_gives_back
