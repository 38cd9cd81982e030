"""ROS 2 layer of rs_localizer: message conversions, the node and bag tools.

Importing this package does not import rclpy; :mod:`.node` and the message builders in
:mod:`.conversions` do (lazily), :mod:`.bag` needs ``rosbags``.
"""
