"""rs_localizer: rolling-shutter absolute pose estimation for ROS 2.

The solvers follow Kukelova, Albl, Sugimoto, Pajdla, "Linear solution to the minimal absolute
pose rolling shutter problem", ACCV 2018 (``shared/paper/linear_rs_absolute_pose.tex``), and
Albl, Kukelova, Pajdla, "R6P - Rolling shutter absolute pose problem", CVPR 2015.

Only ``rs_localizer.ros`` imports rclpy; everything else is plain NumPy/SciPy/OpenCV.
"""

__version__ = "0.1.0"
