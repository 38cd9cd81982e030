"""Plain helpers shared by the tests (the fixtures stay in ``test/conftest.py``).

:mod:`helpers.paths` names the repository's data, :mod:`helpers.ros` starts nodes and probes
them over DDS (rclpy imported only when called), :mod:`helpers.debug_frames` builds a frame with
a known pose for the debug-image tests, :mod:`helpers.rig` and :mod:`helpers.rig_node` hold the
rig tests' shared pieces and the rig node's DDS harness, :mod:`helpers.rig_bags` rig bags
edited for them (rosbags), :mod:`helpers.rig_corners` a synthetic rig video's corners for the
corner-level problems' tests. Test modules import these, never each other.
"""
