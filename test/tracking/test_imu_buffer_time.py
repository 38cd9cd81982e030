"""IMU time handling: a bad stamp never locks the gyro buffer, a time reset empties it, and the
diagnostics say when no usable IMU sample arrives."""

from __future__ import annotations

import numpy as np

from rs_localizer.tracking.gyro import (
    IMU_NEW_TIMELINE_SAMPLES,
    IMU_SAMPLE_REJECTIONS,
    ImuBuffer,
)

W = (0.1, -0.2, 0.3)
S = 1_000_000_000  # 1 s in ns
DT = 5_000_000  # 200 Hz


def _feed(buf: ImuBuffer, t0: int, n: int) -> list:
    return [buf.add(t0 + k * DT, W) for k in range(n)]


def test_a_sample_far_ahead_before_any_frame_is_dropped_when_the_stream_goes_on():
    buf = ImuBuffer(span=10.0)
    assert _feed(buf, 100 * S, 20) == [None] * 20
    assert buf.add(105 * S, W) is None  # 5 s ahead: nothing to judge it by yet
    # the next regular sample goes back before it: the lone jump is dropped, the stream goes on
    assert _feed(buf, 100 * S + 20 * DT, 20) == [None] * 20
    t = [s for s, _ in buf.samples()]
    assert t[-1] == 100 * S + 39 * DT and len(t) == 40 and buf.dropped == 1
    g, why = buf.measurement((100 * S + DT, 100 * S + 30 * DT), np.eye(3), np.zeros(3), 0.003, 0)
    assert why == "" and np.allclose(g.angular_velocity, W)


def test_samples_far_from_the_frames_time_are_rejected_without_poisoning_the_buffer():
    buf = ImuBuffer(span=10.0, max_skew=1.0)
    _feed(buf, 100 * S, 20)
    buf.note_frame(100 * S + 10 * DT)
    assert buf.add(105 * S, W) == "stamp_far_from_frames"  # 5 s ahead
    assert buf.add(365 * 86400 * S, W) == "stamp_far_from_frames"  # a year ahead
    assert buf.add(90 * S, W) == "stamp_far_from_frames"  # 10 s behind
    assert buf.add(1, W) == "stamp_far_from_frames"
    assert _feed(buf, 100 * S + 20 * DT, 10) == [None] * 10  # the gyro goes on
    assert buf.rate_hz() > 0 and buf.received == 34 and buf.accepted == 30
    assert "stamp_far_from_frames" in IMU_SAMPLE_REJECTIONS
    # the frames' time follows wait_until and measurement (IMU clock)
    buf.wait_until(100 * S + 25 * DT, 0.0)
    assert buf.add(102 * S, W) == "stamp_far_from_frames"
    # a frame that takes 3 s to solve: the stream that went on meanwhile is kept
    assert _feed(buf, 100 * S + 30 * DT, 600) == [None] * 600
    assert buf.add(100 * S + 30 * DT + 600 * DT + 2 * S, W) == "stamp_far_from_frames"


def test_a_clock_that_goes_back_starts_a_new_timeline():
    buf = ImuBuffer(span=10.0)
    _feed(buf, 100 * S, 40)
    # a bag played again: its samples are before the newest; after a few, the buffer starts over
    out = _feed(buf, 50 * S, IMU_NEW_TIMELINE_SAMPLES + 5)
    assert out[: IMU_NEW_TIMELINE_SAMPLES - 1] == ["stamp_not_increasing"] * (
        IMU_NEW_TIMELINE_SAMPLES - 1
    )
    assert out[IMU_NEW_TIMELINE_SAMPLES - 1 :] == [None] * 6
    t = [s for s, _ in buf.samples()]
    assert t[0] == 50 * S and len(t) == IMU_NEW_TIMELINE_SAMPLES + 5 and buf.resets == 1


def test_duplicates_and_a_single_step_back_are_still_rejected():
    buf = ImuBuffer(span=10.0)
    _feed(buf, 100 * S, 10)
    assert buf.add(100 * S + 9 * DT, W) == "stamp_not_increasing"
    assert buf.add(100 * S + 3 * DT, W) == "stamp_not_increasing"
    assert buf.add(100 * S + 10 * DT, W) is None
    assert len(buf) == 11 and buf.resets == 0


def test_reset_forgets_the_samples_and_the_frames_time():
    buf = ImuBuffer(span=10.0)
    _feed(buf, 100 * S, 20)
    buf.note_frame(100 * S)
    buf.reset()
    assert len(buf) == 0 and buf.resets == 1
    g, why = buf.measurement((0, DT), np.eye(3), np.zeros(3), 0.003, 0.0)
    assert g is None and why == "no_samples"
    buf.reset()  # (the measurement noted a frame time; a reset forgets it too)
    # the new timeline (earlier) is accepted at once
    assert _feed(buf, 5 * S, 5) == [None] * 5
    assert buf.received == 25 and buf.accepted == 25


def test_idle_seconds_counts_from_the_last_usable_sample():
    buf = ImuBuffer()
    assert buf.idle_seconds() >= 0.0 and buf.last_accepted is None
    buf.add(S, W)
    assert buf.idle_seconds() < 1.0
    buf._created -= 100.0  # (as if made long ago: the last sample still counts)
    assert buf.idle_seconds() < 1.0


def test_diagnostics_warn_when_no_usable_imu_sample_arrives():
    from dataclasses import replace

    from helpers.camera_node import CameraNode
    from helpers.ros import camera_status

    from rs_localizer.ros.config import build_config
    from rs_localizer.ros.diagnostics import IMU_IDLE_WARN_S, OK, WARN
    from rs_localizer.ros.params import default_values

    cfg = build_config({**default_values(), "imu.enabled": True})
    stats = CameraNode(cfg).stats
    for _ in range(50):
        stats.add("imu_rejected")
    idle = stats.snapshot()
    snap = replace(idle, counts={**idle.counts, "received": 10, "solved": 10})
    args = (snap, {}, "camera_info", 0, [0.01], [0.02], 0.0, None, False)
    level, message, values = camera_status(cfg, *args, IMU_IDLE_WARN_S + 1.0)
    assert level == WARN and "no usable IMU sample" in message and "50" in message, message
    assert values["imu_idle_s"] == f"{IMU_IDLE_WARN_S + 1.0:.1f}"
    assert camera_status(cfg, *args, 0.1)[0] == OK
    # without frames (nothing to solve) or without imu.enabled: no warning about the IMU
    assert camera_status(cfg, idle, *args[1:], 100.0)[0] == OK
    off = build_config(default_values())
    assert camera_status(off, *args, 100.0)[0] == OK
