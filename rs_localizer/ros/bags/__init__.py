"""Bag tools: write and read bags (:mod:`.bag_io`, with rosbags), a bag's frames as
correspondences and its gyro (:mod:`.bag_frames`), a bag into the live graph (:mod:`.play`) and
the node offline over a bag (:mod:`.replay`)."""
