"""Shared pieces of the rig tests (library and node): the rig videos' start stamp, a log that
records what the rig localizer says, the true mountings of simulated rig cameras, the rig's
frame accounting checked."""

from __future__ import annotations

#: the start stamp of the simulated rig videos and the cameras' camera_info (ns)
T0 = 1_700_000_000_000_000_000


class Log:
    """A logger for :class:`~rs_localizer.tracking.video.Localizer` that keeps its warnings
    (``(key, text)``) and infos."""

    def __init__(self):
        self.warnings, self.infos = [], []

    def warning(self, key, text, count=0):
        self.warnings.append((key, text))

    def info(self, text):
        self.infos.append(text)


def mounts_of(cams):
    """Each simulated rig camera's true mounting (name -> ``Mounting``)."""
    from rs_localizer.frames import Mounting

    return {c.name: Mounting.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}


def assert_balanced(rig):
    """Every camera's and the rig's accounting balances: received = solved + failed + skipped +
    pending (rig frames for the rig)."""
    for n in rig.cameras:
        c = rig.camera_counts(n)
        assert c["received"] == c["solved"] + c["failed"] + c["skipped"] + c["pending"], (n, c)
    r = rig.rig_counts()
    assert r["rig_frames"] == r["solved"] + r["failed"] + r["skipped"] + r["pending"], r
