"""A readout-free twin of a simulated marker video (the mapping benchmark's floor) differs from
the rolling-shutter video in the readout only: every corner where a camera reading all its
lines at the frame's stamp sees it, and the same stamps, markers, noise and detector error."""

from dataclasses import replace

import numpy as np

from rs_localizer.mapping import FrameDetections
from rs_localizer.sim.marker_mapping import same_video_but_readout
from rs_localizer.sim.marker_room import (
    RoomWalk,
    make_marker_room,
    room_camera,
    simulate_detections,
)
from rs_localizer.sim.trajectory import project_rs

ROOM = make_marker_room(30, seed=0, size=(4.5, 4.0, 2.6))
CAMERA = room_camera(readout_time=0.03)
WALK = RoomWalk(centre=(2.25, 2.0))


def _sim(readout_free: bool, noise: float = 0.4, view_error: float = 0.3, bias: float = 0.0):
    return simulate_detections(
        ROOM,
        CAMERA,
        WALK,
        num_frames=20,
        noise_px=noise,
        seed=5,
        corner_bias_px=bias,
        view_error_px=view_error,
        view_seed=0,
        readout_free=readout_free,
    )


def test_readout_free_corners_are_the_projection_at_the_stamp():
    dets, truth = _sim(True, noise=0.0, view_error=0.0)
    rs, truth_rs = _sim(False, noise=0.0, view_error=0.0)
    at_once = replace(CAMERA, line_delay=0.0)  # an exact projector with no readout time
    assert at_once.readout_time == 0.0
    corners = ROOM.corners()
    n, moved = 0, 0.0
    for (stamp, d), (stamp_rs, d_rs) in zip(dets, rs, strict=True):
        assert stamp == stamp_rs and sorted(d) == sorted(d_rs)
        for m, uv in d.items():
            ref, ok = project_rs(at_once, WALK, stamp, corners[m])
            inside = ok  # (a corner may fall just outside the image without the readout)
            assert np.allclose(uv[inside], ref[inside], atol=1e-6)
            n += 1
            moved = max(moved, float(np.abs(d_rs[m] - uv).max()))
    assert n > 20
    assert moved > 2.0  # the rolling shutter does move the corners (the walk turns)
    for k in truth:
        assert np.array_equal(truth[k], truth_rs[k])


def test_readout_free_twin_draws_the_same_noise_and_detector_error():
    noisy, _ = _sim(True)
    clean, _ = _sim(True, noise=0.0, view_error=0.0)
    noisy_rs, _ = _sim(False)
    clean_rs, _ = _sim(False, noise=0.0, view_error=0.0)
    for a, b, c, d in zip(noisy, clean, noisy_rs, clean_rs, strict=True):
        for m in a[1]:
            assert np.allclose(a[1][m] - b[1][m], c[1][m] - d[1][m], atol=1e-9)


def test_same_video_but_readout_tells_twins_from_other_videos():
    free = [FrameDetections(s, d) for s, d in _sim(True, bias=0.19)[0]]
    rs = [FrameDetections(s, d) for s, d in _sim(False, bias=0.19)[0]]
    assert same_video_but_readout(rs, free)
    dropped = [FrameDetections(f.stamp, dict(f.corners)) for f in free]
    k = next(i for i, f in enumerate(dropped) if f.corners)
    dropped[k].corners.pop(next(iter(dropped[k].corners)))
    assert not same_video_but_readout(rs, dropped)
    shifted = [FrameDetections(f.stamp + 0.015, f.corners) for f in free]
    assert not same_video_but_readout(rs, shifted)
    moved = [FrameDetections(f.stamp, {m: c + 60.0 for m, c in f.corners.items()}) for f in rs]
    assert not same_video_but_readout(rs, moved)
