"""Shared fixtures (plain helpers live in the ``helpers`` package beside this file).

Nothing here imports rclpy at collection time, so the non-ROS tests run without ROS.

Isolation: one random ``ROS_DOMAIN_ID`` (1..101) per test session, localhost-only discovery,
one ``rclpy.Context`` per test. Node processes get QoS overrides making their subscriptions
reliable, so lock-step replay loses nothing.
"""

from __future__ import annotations

import os

import pytest
from helpers.paths import KEYPOINTS_BAG, SAMPLE_BAG, SAMPLE_IMAGES_BAG
from helpers.ros import Probe


def pytest_collection_modifyitems(config, items):
    """Every test that joins the DDS graph (through ``ros_domain``: ``ros_context``, ``probe``)
    is marked ``ros``, so that ``pytest -m "not ros"`` leaves them out."""
    for item in items:
        if "ros_domain" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.ros)


@pytest.fixture(scope="session")
def ros_domain():
    """Random domain id for this session, exported to os.environ (restored afterwards)."""
    pytest.importorskip("rclpy")
    from rs_localizer.ros.process import random_domain_id

    keys = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY")
    saved = {k: os.environ.get(k) for k in keys}
    domain = random_domain_id()
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    yield domain
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@pytest.fixture(scope="session")
def rig_kernels():
    """The rig's kernels compiled (or loaded from numba's cache) once per session, as a rig
    node's ``warmup`` does (:func:`~rs_localizer.runtime.warmup.warm_rig`, with and without a
    gyro): a rig test over DDS times its waits for frames, not for numba's first compile of
    the rig's refinement (~30 s on a cold cache, longer on a busy machine), which would also
    go on in a node's worker thread after a test that gave up on it."""
    import numpy as np

    from rs_localizer.frames import Mounting
    from rs_localizer.runtime.warmup import warm_rig
    from rs_localizer.tracking.sequence import GyroSettings
    from rs_localizer.tracking.video import LocalizerSettings

    turn = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    mounts = {
        "a": Mounting.from_pose(np.eye(3), np.zeros(3)),
        "b": Mounting.from_pose(turn, np.array([0.1, 0.0, 0.0])),
    }
    warm_rig(LocalizerSettings(mounts))
    warm_rig(LocalizerSettings(mounts, imu=GyroSettings(R_cam_imu=np.eye(3))))


@pytest.fixture(autouse=True)
def _rig_tests_on_compiled_kernels(request):
    """Every ROS test of a rig (``rig`` in its id) runs after :func:`rig_kernels`."""
    if "rig" in request.node.nodeid and "ros_domain" in request.fixturenames:
        request.getfixturevalue("rig_kernels")


@pytest.fixture
def ros_context(ros_domain):
    """A fresh, initialized rclpy Context for one test."""
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture(scope="session")
def sample_bag():
    if not (SAMPLE_BAG / "metadata.yaml").exists():
        pytest.skip("data/sample missing (make sample-bag)")
    return SAMPLE_BAG


@pytest.fixture(scope="session")
def sample_images_bag():
    if not (SAMPLE_IMAGES_BAG / "metadata.yaml").exists():
        pytest.skip("data/sample_images missing (make sample-bag)")
    return SAMPLE_IMAGES_BAG


@pytest.fixture(scope="session")
def keypoints_bag():
    if not (KEYPOINTS_BAG / "metadata.yaml").exists():
        pytest.skip("test/data/keypoints missing (make sample-bag)")
    return KEYPOINTS_BAG


@pytest.fixture
def probe(ros_context):
    p = Probe(ros_context)
    yield p
    p.close()


@pytest.fixture
def cheirality_when_behind(monkeypatch):
    """The final model's last checks
    (:func:`~rs_localizer.estimation.finalize.last_checks`, a camera's and a rig's) refusing, as
    ``cheirality``, a fit that puts rows behind their cameras, with their own count: the
    failure a fit with an inlier behind its camera gives, on a frame whose rows behind are
    known."""
    from rs_localizer.estimation import finalize

    real = finalize.last_checks

    def refusing(*args):
        failure, behind = real(*args)
        return ("cheirality" if behind else failure), behind

    monkeypatch.setattr(finalize, "last_checks", refusing)
