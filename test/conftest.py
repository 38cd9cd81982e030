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
