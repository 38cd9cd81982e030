"""The node's diagnostics values from its counters, without a node."""

from rs_localizer.ros.config import build_config
from rs_localizer.ros.diagnostics import diagnostic_status
from rs_localizer.ros.frame_queue import FrameCounts
from rs_localizer.ros.params import default_values
from rs_localizer.ros.pipeline import FramePipeline


def _values(stamp_ages):
    cfg = build_config(default_values())
    snap = FramePipeline(cfg).stats.snapshot()
    frames = FrameCounts(received=len(stamp_ages), solved=len(stamp_ages))
    args = (cfg, frames, snap, {}, "camera_info", 0, [0.01] * len(stamp_ages), stamp_ages)
    return diagnostic_status(*args, 0.0, None, False, 0.0)[2]


def test_stamp_age_leaves_out_stamps_of_another_clock():
    """A recorded bag played without use_sim_time: its stamps are days older than the node's
    clock. Their age is no delay of the node: counted apart, not averaged in."""
    live = _values([0.010, 0.012, 0.014])
    assert live["stamp_age_ms_median"] == "12.000" and live["stamps_off_clock"] == 0
    recorded = _values([95.6e6, 95.6e6 + 0.033])
    assert recorded["stamp_age_ms_median"] == "nan" and recorded["stamps_off_clock"] == 2
    mixed = _values([0.010, 95.6e6, -3600.0, 0.020])
    assert mixed["stamp_age_ms_last"] == "20.000" and mixed["stamp_age_ms_median"] == "15.000"
    assert mixed["stamps_off_clock"] == 2
