"""ROS 2 layer of rs_localizer: message conversions, the node and bag tools.

The node (:mod:`.node`, managed: :mod:`.lifecycle`; its one mode, a camera alone or a rig:
:mod:`.mode`, the rig's own parts :mod:`.rig_node`; the executables, one or several cameras:
:mod:`.runner`) is wiring
around ROS-free parts: :mod:`.params` (the parameters), :mod:`.param_files` (parameter files),
:mod:`.config` (parameter values -> configuration; :func:`.config.load_maps`, its maps
loaded), :mod:`.camera_input` (a camera's frames made what the localizer takes),
:mod:`.pipeline` (a frame's counters, log and checks), :mod:`.camera_info_history`,
:mod:`.frame_queue` (the worker and the frame accounting), :mod:`.image_codec` (the image
messages to numpy, for both nodes, replay and the tools), :mod:`.outputs` (a frame's messages)
and :mod:`.diagnostics`.
:mod:`.bags.replay` runs the same frame step over a bag, offline.

Importing this package does not import rclpy; :mod:`.node`, :mod:`.bags.play` and the message
builders in :mod:`.conversions` do (lazily). The bag tools in :mod:`.bags` (:mod:`.bags.bag_io`,
:mod:`.bags.bag_frames`, :mod:`.bags.play`, :mod:`.bags.replay`) need ``rosbags``;
:mod:`.pointcloud` packs and decodes ``PointCloud2``; :mod:`.process` starts the node as a
subprocess.
"""
