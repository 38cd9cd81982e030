"""Calibration from data: a rig's camera mountings (:mod:`.mountings`) and a camera's line delay
(:mod:`.readout`)."""

from .mountings import MOUNTING_BIAS_SHARE, MountingEstimate, calibrate_mountings
from .readout import ReadoutCalibration, calibrate_line_delay, fit_line_delay, line_delay_verdict

__all__ = [
    "MOUNTING_BIAS_SHARE",
    "MountingEstimate",
    "ReadoutCalibration",
    "calibrate_line_delay",
    "calibrate_mountings",
    "fit_line_delay",
    "line_delay_verdict",
]
