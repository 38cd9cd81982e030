"""Simulation: data with exact ground truth, for tests, demos, experiments and benchmarks.

* :mod:`.synthetic`: the paper's synthetic frames (sec. 4) and the options of its protocol, and
  frames of a camera or a rig of cameras (2-4, each at its mounting) of a constant-velocity model;
* :mod:`.trajectory`: continuous-time camera trajectories and correspondence sequences, of one
  camera or a rig of unsynchronized cameras on a body;
* :mod:`.render`: the rolling-shutter image renderer (of a camera or a rig's cameras), scenes and
  motions;
* :mod:`.feature_map`: feature maps of rendered scenes, and the poses of photos to build one;
* :mod:`.gyro`: a simulated gyro over one frame's readout;
* :mod:`.noise`: correlated image noise;
* :mod:`.attacks`: correspondences no camera can produce, and true data sets;
* :mod:`.aruco_video`: a rendered marker video and the ArUco front end on it;
* :mod:`.marker_mapping`: marker maps of simulated rooms against their truth.

Simulation produces data; nothing in the library imports it (the CLI, the experiments and the
benchmarks outside the package do).
"""
