"""ROS 2 layer of rs_localizer: message conversions, the node and bag tools.

Importing this package does not import rclpy; :mod:`.node`, :mod:`.play` and the message
builders in :mod:`.conversions` do (lazily). :mod:`.bag_io` (write and read bags) and
:mod:`.replay` (the estimator over a bag, offline) need ``rosbags``; :mod:`.pointcloud` packs
and decodes ``PointCloud2``; :mod:`.process` starts the node as a subprocess.
"""
