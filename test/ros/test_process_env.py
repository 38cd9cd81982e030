"""The environment of the node processes the tools start."""

import pytest

from rs_localizer.ros.process import ros_env, user_domain_id


def test_user_domain_id_is_kept_when_set():
    """A ROS_DOMAIN_ID the user set is the one the tools use (the demo no longer picks
    another); unset or empty means none; a value that is no domain id is refused."""
    assert user_domain_id({}) is None and user_domain_id({"ROS_DOMAIN_ID": " "}) is None
    assert user_domain_id({"ROS_DOMAIN_ID": "93"}) == 93
    assert user_domain_id({"ROS_DOMAIN_ID": "0"}) == 0
    for bad in ("-1", "233", "ninety", "9.5"):
        with pytest.raises(ValueError, match="ROS_DOMAIN_ID"):
            user_domain_id({"ROS_DOMAIN_ID": bad})
    env = ros_env(93, base={"ROS_DOMAIN_ID": "93", "ROS_LOCALHOST_ONLY": "1"})
    assert env["ROS_DOMAIN_ID"] == "93" and "ROS_LOCALHOST_ONLY" not in env
