"""The marker map's gravity-aligned frame (z up from the accelerometer, the walls or a floor
marker) and the calibrated line delay (its std, its verdict, its invariance to the output
frame), against the simulated room's truth (rs_localizer.sim.marker_room: world z up)."""

from dataclasses import replace

import numpy as np
import pytest

from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.mapping import MappingOptions, map_markers
from rs_localizer.mapping.marker_frame import find_up, gravity_transform
from rs_localizer.mapping.marker_model import fit_rigid
from rs_localizer.sim.marker_mapping import room_scene
from rs_localizer.sim.marker_room import make_marker_room, room_camera

UP = np.array([0.0, 0.0, 1.0])


def _tilt_error_deg(up: np.ndarray, R_true_from_est: np.ndarray) -> float:
    u = R_true_from_est @ up
    return float(np.degrees(np.arccos(np.clip(u @ UP / np.linalg.norm(u), -1, 1))))


def _room_poses(seed: int, noise_deg: float, R_w: np.ndarray) -> dict:
    """The simulated room's markers (walls, tilted ones, one on the floor) in a frame rotated
    by ``R_w`` (world -> that frame), each normal off by about ``noise_deg``."""
    room = make_marker_room(28, seed=seed, size=(4.5, 4.0, 2.6))
    rng = np.random.default_rng(seed)
    out = {}
    for i in room.ids:
        dR = rotvec_to_matrix(rng.normal(0, np.radians(noise_deg), 3))
        out[int(i)] = (R_w @ dR @ room.R[i], R_w @ room.p[i])
    return room, out


def _cameras(R_w: np.ndarray) -> dict:
    """Camera -> frame rotations of an upright camera (optical y down) turning around."""
    out = {}
    for k, yaw in enumerate(np.linspace(0, 2 * np.pi, 12, endpoint=False)):
        fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        down = -UP
        out[k] = R_w @ np.column_stack([np.cross(down, fwd), down, fwd])
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_up_from_walls_floor_and_accelerometer(seed):
    R_w = rotvec_to_matrix(np.random.default_rng(seed + 10).normal(0, 1.0, 3))
    room, poses = _room_poses(seed, 0.5, R_w)
    cams = _cameras(R_w)
    floor = [int(i) for i in room.ids if room.R[i][2, 2] > 0.9]
    # walls: the tilted markers and the floor one do not agree with them
    up, why = find_up(poses, cams, MappingOptions(0.16, frame="walls"))
    assert up is not None and up.source == "walls" and not why
    assert _tilt_error_deg(up.up, R_w.T) < 0.5
    assert not set(floor) & set(up.markers)
    # floor: flagged, then found facing the cameras' image-up
    for flagged in (tuple(floor), ()):
        o = MappingOptions(0.16, frame="floor", floor_markers=flagged)
        up, _ = find_up(poses, cams, o)
        assert up is not None and up.source == "floor" and list(up.markers) == floor
        assert _tilt_error_deg(up.up, R_w.T) < 2.0  # (one normal, 0.5 deg per axis: 4 sigma)
    # the accelerometer first in auto: up per camera, rotated into the frame by its pose
    acc = {k: R.T @ (R_w @ UP) for k, R in cams.items()}
    up, _ = find_up(poses, cams, MappingOptions(0.16, frame="auto"), acc)
    assert up.source == "imu" and _tilt_error_deg(up.up, R_w.T) < 1e-9
    # the gravity frame: z up, origin at the anchor, x out of its wall (horizontal)
    a = next(int(i) for i in room.ids if abs(room.R[i][2, 2]) < 0.05)
    R, t = gravity_transform(poses, a, up)
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R @ poses[a][1] + t, 0.0)
    x_true = room.R[a][:, 2] - room.R[a][2, 2] * UP
    assert np.degrees(np.arccos((R_w.T @ R[0]) @ x_true / np.linalg.norm(x_true))) < 1.0


def test_one_wall_and_nothing_else_is_no_up():
    R_w = np.eye(3)
    _, poses = _room_poses(0, 0.2, R_w)
    one_wall = {m: v for m, v in poses.items() if abs(v[0][0, 2] + 1.0) < 0.05}
    up, why = find_up(one_wall, _cameras(R_w), MappingOptions(0.16, frame="walls"))
    assert up is None and "walls" in why


@pytest.fixture(scope="module")
def scene():
    return room_scene(90)


@pytest.mark.slow
def test_gravity_frame_from_the_walls_and_the_accelerometer(scene):
    room, camera, _, frames, truth, opts = scene
    base = replace(opts, anchor=None, anchor_pose=None)
    acc = {k: truth["orientation"][k].T @ UP for k in range(len(frames))}
    for mode, ups in (("walls", None), ("auto", acc)):
        res = map_markers(frames, camera, replace(base, frame=mode), up_in_camera=ups)
        assert res.frame.kind == "gravity"
        assert res.frame.up_source == ("walls" if ups is None else "imu")
        ids = sorted(res.marker_poses)
        R, _ = fit_rigid(
            np.array([res.marker_poses[m][1] for m in ids]), np.array([room.p[m] for m in ids])
        )
        assert _tilt_error_deg(UP, R) < 1.0  # the map's z axis in the truth's frame
        assert np.allclose(res.marker_poses[res.anchor][1], 0.0)


@pytest.mark.slow
def test_line_delay_does_not_depend_on_the_output_frame(scene):
    """The same video with the anchor at its true pose, at a pose 10 m away (--anchor-pose)
    and without an anchor (the best-observed marker's frame): the same line delay, std and
    velocities, and maps equal up to a rigid motion (the corner model and the motion tie do
    not depend on the world frame; the last adjustment is run to convergence)."""
    _, camera, _, frames, _, opts = scene
    start = room_camera(line_delay=1.1 * camera.line_delay)
    o = replace(opts, calibrate_readout=True)
    far = (rotvec_to_matrix(np.array([0.4, -1.1, 0.6])), np.array([6.0, -8.0, 3.0]))
    a = map_markers(frames, start, o)
    b = map_markers(frames, start, replace(o, anchor=None, anchor_pose=None))
    c = map_markers(frames, start, replace(o, anchor_pose=far))
    assert a.frame.kind == c.frame.kind == "anchor" and b.frame.kind == "best-observed"
    assert np.allclose(c.marker_poses[0][1], far[1]) and np.allclose(c.marker_poses[0][0], far[0])
    for other in (b, c):
        assert abs(other.line_delay - a.line_delay) <= 1e-5 * a.line_delay
        assert abs(other.line_delay_std / a.line_delay_std - 1) < 1e-3
        # the camera's own velocities (its frame: the same numbers in every output frame)
        assert np.allclose(other.angular_velocity, a.angular_velocity, atol=1e-4)
        assert np.allclose(other.linear_velocity, a.linear_velocity, atol=1e-4)
        # the maps: one rigid motion apart (corner residual after the fit below 0.05 mm)
        ids = sorted(a.corners)
        assert sorted(other.corners) == ids
        A = np.vstack([a.corners[m] for m in ids])
        B = np.vstack([other.corners[m] for m in ids])
        R, t = fit_rigid(B, A)
        assert np.abs(B @ R.T + t - A).max() < 5e-5
    assert 0 < a.line_delay_std < 0.05 * a.line_delay and a.readout_verdict == ""
    assert abs(a.line_delay - camera.line_delay) < 3 * a.line_delay_std
    # not calibrated: no std, no verdict
    assert map_markers(frames[:40], camera, opts).readout_verdict is None
