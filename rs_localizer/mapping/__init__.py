"""Maps from the user's own data, for the front ends and the node's ``frontend_map``.

Without ROS. Above ``estimation/`` and ``frontends/`` (it uses the estimator and the detectors),
below ``ros/`` and ``cli/``.
"""

__all__: list[str] = []
