"""Marker mapping from a rolling-shutter video (rs_localizer.mapping.marker_ba) against the exact
ground truth of a simulated room: corners are projected with the camera pose at each line's own
capture time (rs_localizer.sim.marker_room), errors are measured in the anchor's gauge (the
anchor placed at its true pose, no best-fit alignment)."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from rs_localizer.mapping.marker_ba import FrameDetections, MappingOptions, map_markers
from rs_localizer.sim.marker_room import (
    RoomWalk,
    make_marker_room,
    room_camera,
    simulate_detections,
)

NUM_FRAMES = 90


@pytest.fixture(scope="module")
def scene():
    room = make_marker_room(28, seed=0, size=(4.5, 4.0, 2.6))
    camera = room_camera(readout_time=0.03)
    walk = RoomWalk(centre=(2.25, 2.0))
    dets, truth = simulate_detections(room, camera, walk, num_frames=NUM_FRAMES, noise_px=0.4)
    frames = [FrameDetections(s, d) for s, d in dets]
    opts = MappingOptions(
        marker_size=0.16,
        marker_sizes={int(i): float(s) for i, s in zip(room.ids, room.sides, strict=True)},
        anchor=0,
        anchor_pose=(room.R[0], room.p[0]),
    )
    return room, camera, walk, frames, truth, opts


@pytest.fixture(scope="module")
def rs_map(scene):
    _, camera, _, frames, _, opts = scene
    return map_markers(frames, camera, opts)


@pytest.fixture(scope="module")
def gs_map(scene):
    _, camera, _, frames, _, opts = scene
    return map_markers(frames, camera, replace(opts, global_shutter=True))


def corner_errors(result, room) -> np.ndarray:
    true = room.corners()
    return np.concatenate(
        [np.linalg.norm(result.corners[m] - true[m], axis=1) for m in result.corners]
    )


def test_scene_is_a_fast_hand_held_walk(scene):
    _, _, _, frames, truth, _ = scene
    rate = np.linalg.norm(truth["angular_velocity"], axis=1)
    assert 1.5 < rate.max() < 2.6
    assert np.mean([len(f.corners) for f in frames]) >= 2


def test_rs_map_matches_ground_truth(scene, rs_map):
    room, *_ = scene
    e = corner_errors(rs_map, room)
    assert len(rs_map.corners) >= 15
    assert np.median(e) < 0.05 and e.max() < 0.25
    assert rs_map.rmse_px < 0.6
    # frames: poses and the camera's own angular velocity against the trajectory
    _, _, _, _, truth, _ = scene
    k = rs_map.frame_ids
    pos = np.linalg.norm(rs_map.position - truth["position"][k], axis=1)
    assert np.median(pos) < 0.05
    werr = np.linalg.norm(rs_map.angular_velocity - truth["angular_velocity"][k], axis=1)
    assert np.median(werr) < 0.25


def test_global_shutter_adjustment_is_much_worse(scene, rs_map, gs_map):
    room, *_ = scene
    rs = np.median(corner_errors(rs_map, room))
    gs = np.median(corner_errors(gs_map, room))
    assert gs > 3 * rs
    assert np.all(gs_map.angular_velocity == 0)


def test_covariance_is_honest(scene, rs_map):
    room, *_ = scene
    inside = []
    for m, (_, p) in rs_map.marker_poses.items():
        if m == rs_map.anchor:
            assert not rs_map.marker_covariance[m].any()
            continue
        d = p - room.p[m]
        S = rs_map.marker_covariance[m][3:, 3:]
        inside.append(d @ np.linalg.solve(S, d) <= chi2.ppf(0.9973, 3))
    assert np.mean(inside) >= 0.9


def test_line_delay_is_calibrated(scene):
    _, camera, _, frames, _, opts = scene
    start = room_camera(line_delay=1.2 * camera.line_delay)
    res = map_markers(frames, start, replace(opts, calibrate_readout=True))
    assert abs(res.line_delay / camera.line_delay - 1) < 0.05
    with pytest.raises(ValueError, match="line delay"):
        map_markers(frames, camera, replace(opts, calibrate_readout=True, global_shutter=True))


def test_no_detections_is_an_error(scene):
    _, camera, _, frames, _, opts = scene
    with pytest.raises(ValueError, match="no marker detections"):
        map_markers([FrameDetections(f.stamp, {}) for f in frames], camera, opts)


def test_anchor_not_in_view_is_named(scene):
    _, camera, _, frames, _, opts = scene
    with pytest.raises(ValueError, match="anchor marker 99"):
        map_markers(frames, camera, replace(opts, anchor=99))


def views(frames) -> dict:
    out = {}
    for i, f in enumerate(frames):
        for m in f.corners:
            out.setdefault(m, []).append(i)
    return out


def test_marker_seen_once_is_left_out_and_reported(scene, rs_map):
    _, camera, _, frames, _, opts = scene
    seen = views(frames)
    m = max((k for k in seen if k != 0), key=lambda k: len(seen[k]))
    keep = seen[m][len(seen[m]) // 2]
    cut = [
        FrameDetections(f.stamp, {k: c for k, c in f.corners.items() if k != m or i == keep})
        for i, f in enumerate(frames)
    ]
    res = map_markers(cut, camera, opts)
    assert m not in res.corners
    assert "seen in 1 frame" in res.unmapped[m]
    assert set(res.corners) == set(rs_map.corners) - {m}
