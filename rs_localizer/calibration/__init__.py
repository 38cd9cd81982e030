"""Calibration from data: a rig's camera mountings (:mod:`.mountings`)."""

from .mountings import MOUNTING_BIAS_SHARE, MountingEstimate, calibrate_mountings

__all__ = ["MOUNTING_BIAS_SHARE", "MountingEstimate", "calibrate_mountings"]
