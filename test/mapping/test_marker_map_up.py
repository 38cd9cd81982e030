"""The gravity-aligned frame's up in a room whose markers fit more than one up (front wall,
two side walls, the floor and a leaning panel: with a horizontal axis as up the front and
floor markers still hang on "walls" and the side walls' lie "level"): the proposals are
checked against the cameras' image-up, and an up the cameras cannot tell apart from another
is said to be unknown, never picked. Truth: rs_localizer.sim.marker_room (world z up)."""

import numpy as np
import pytest

from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.mapping import FrameDetections, MappingOptions, map_markers
from rs_localizer.mapping.marker_frame import find_up
from rs_localizer.mapping.marker_model import fit_rigid
from rs_localizer.sim.marker_room import (
    OneSpot,
    make_front_room,
    room_camera,
    simulate_detections,
)

UP = np.array([0.0, 0.0, 1.0])


def _cameras(pitch_deg: float, R_w: np.ndarray) -> dict:
    """Camera -> frame rotations of cameras panning across the front wall (+x), pitched
    down by ``pitch_deg``, optical y down when level."""
    out = {}
    p = np.radians(pitch_deg)
    for k, yaw in enumerate(np.linspace(-0.8, 0.8, 15)):
        fwd = np.array([np.cos(yaw) * np.cos(p), np.sin(yaw) * np.cos(p), -np.sin(p)])
        right = np.cross(fwd, UP)
        right /= np.linalg.norm(right)
        out[k] = R_w @ np.column_stack([right, np.cross(fwd, right), fwd])
    return out


def _poses(R_w: np.ndarray, noise_deg: float = 0.5) -> dict:
    room = make_front_room(side=0.3)
    rng = np.random.default_rng(1)
    return {
        int(i): (
            R_w @ rotvec_to_matrix(rng.normal(0, np.radians(noise_deg), 3)) @ room.R[i],
            R_w @ room.p[i],
        )
        for i in room.ids
    }


@pytest.mark.parametrize("seed", [0, 1])
def test_up_is_the_room_axis_the_cameras_hold_upright(seed):
    R_w = rotvec_to_matrix(np.random.default_rng(seed).normal(0, 1.0, 3))
    poses = _poses(R_w)
    up, why = find_up(poses, _cameras(15.0, R_w), MappingOptions(0.3, frame="auto"))
    assert up is not None and up.source == "walls" and not why
    assert np.degrees(np.arccos(np.clip((R_w.T @ up.up) @ UP, -1, 1))) < 1.0
    # the side walls hang on walls, the floor markers lie level, the leaning panel neither
    assert {4, 5, 6, 7} <= set(up.markers) and set(up.level) == {8, 9}
    assert 10 not in set(up.markers) | set(up.level)
    assert "2 on the floor" in up.note


def test_up_the_cameras_cannot_tell_apart_is_unknown():
    """Cameras looking 45 deg down hold their image-up halfway between the room's up and its
    front axis, which the markers fit as well: up is unknown, said plainly."""
    R_w = np.eye(3)
    up, why = find_up(_poses(R_w), _cameras(45.0, R_w), MappingOptions(0.3, frame="auto"))
    assert up is None and "up ambiguous" in why


def test_up_from_cameras_turning_about_their_axis_is_unknown():
    """Cameras rolled through a full turn about their optical axis over the video: their
    image-up says nothing about up, no proposal is picked."""
    R_w = np.eye(3)
    cams = {
        k: R @ rotvec_to_matrix([0.0, 0.0, roll])
        for (k, R), roll in zip(
            _cameras(0.0, R_w).items(), np.linspace(0, 2 * np.pi, 15, endpoint=False), strict=True
        )
    }
    up, why = find_up(_poses(R_w), cams, MappingOptions(0.3, frame="walls"))
    assert up is None and why.startswith("up unknown")


@pytest.mark.slow
def test_front_room_video_maps_with_z_up():
    """60 frames from one spot panning across the front wall (the video that once put z
    along the room's side axis, stated to 5.3 deg): the map's z axis is the truth's up, and
    every wall marker's normal is horizontal within 2 deg plus 3 of its stated sigmas."""
    room = make_front_room(side=0.3)
    camera = room_camera()
    walk = OneSpot(duration=2.0, spot=(1.0, 2.0, 1.5), yaw_from=-1.0, yaw_to=1.0, pitch=0.3)
    dets, _ = simulate_detections(
        room, camera, walk, num_frames=60, view_error_px=0.3, corner_bias_px=0.19
    )
    frames = [FrameDetections(t, d) for t, d in dets]
    res = map_markers(frames, camera, MappingOptions(0.3, frame="auto", calibrate_readout=True))
    assert res.frame.kind == "gravity" and res.frame.up_source == "walls", res.frame.note
    ids = sorted(res.marker_poses)
    R, _ = fit_rigid(
        np.array([res.marker_poses[m][1] for m in ids]), np.array([room.p[m] for m in ids])
    )
    assert np.degrees(np.arccos(np.clip((R @ UP) @ UP, -1, 1))) < 2.0
    for m in ids:
        if abs(room.R[m][2, 2]) < 0.1:  # a wall marker
            tilt = np.degrees(np.arcsin(min(1.0, abs(res.marker_poses[m][0][2, 2]))))
            std = np.degrees(np.sqrt(np.linalg.eigvalsh(res.marker_covariance[m][:3, :3])[-1]))
            assert tilt < 2.0 + 3 * std, (m, tilt, std)
