"""Simulation: data with exact ground truth, for tests, demos and experiments.

* :mod:`.synthetic`: the paper's synthetic frames (sec. 4);
* :mod:`.trajectory`: continuous-time camera trajectories and correspondence sequences;
* :mod:`.render`: the rolling-shutter image renderer, scenes and motions;
* :mod:`.feature_map`: feature maps of rendered scenes.

Simulation produces data; nothing in the library imports it (the CLI and the evaluation do).
"""
