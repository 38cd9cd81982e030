"""Shared pieces of the rig tests (library and node): the rig videos' start stamp, a log that
records what the rig localizer says, the true mountings of simulated rig cameras."""

from __future__ import annotations

#: the start stamp of the simulated rig videos and the cameras' camera_info (ns)
T0 = 1_700_000_000_000_000_000


class Log:
    """A logger for :class:`~rs_localizer.tracking.rig.RigLocalizer` that keeps its warnings
    (``(key, text)``) and infos."""

    def __init__(self):
        self.warnings, self.infos = [], []

    def warning(self, key, text, count=0):
        self.warnings.append((key, text))

    def info(self, text):
        self.infos.append(text)


def mounts_of(cams):
    """Each simulated rig camera's true mounting (name -> ``RigMount``)."""
    from rs_localizer.tracking.rig import RigMount

    return {c.name: RigMount.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}
