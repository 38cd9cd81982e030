"""Marker mapping from a rolling-shutter video (rs_localizer.mapping) against the exact
ground truth of a simulated room: corners are projected with the camera pose at each line's own
capture time (rs_localizer.sim.marker_room), errors are measured in the anchor's gauge (the
anchor placed at its true pose, no best-fit alignment)."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2

from rs_localizer.mapping import FrameDetections, map_markers
from rs_localizer.mapping.marker_covariance import _marker_covariance
from rs_localizer.mapping.marker_problem import MarkerProblem
from rs_localizer.sim.marker_mapping import (
    drive_detections,
    localization_errors,
    map_errors,
    map_through_file,
    room_scene,
)
from rs_localizer.sim.marker_room import (
    room_camera,
)

#: the bundle adjustments of these tests take 10-70 s each
pytestmark = pytest.mark.slow

NUM_FRAMES = 90


@pytest.fixture(scope="module")
def scene():
    return room_scene(NUM_FRAMES)


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
    # unbiased corners: the corner offset found stays small (this walk sees the markers from
    # a narrow range of distances, which fixes it only to a few tenths of a pixel)
    assert abs(rs_map.corner_offset_px) < 0.3
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


def test_shape_std_is_honest_after_a_rigid_fit(scene, rs_map):
    # the shape-only std states each corner's error relative to the others: the corners'
    # errors after the best rigid fit of all of them onto the truth (SciPy, independent of the
    # adjustment's covariance), not their errors in the anchor's frame
    from scipy.spatial.transform import Rotation

    from rs_localizer.sim.marker_mapping import corner_sigmas

    room, *_ = scene
    ids = sorted(rs_map.corners)
    est = np.concatenate([rs_map.corners[m] for m in ids])
    true = np.concatenate([room.corners()[m] for m in ids])
    rot, _ = Rotation.align_vectors(true - true.mean(0), est - est.mean(0))
    err = np.linalg.norm((est - est.mean(0)) @ rot.as_matrix().T + true.mean(0) - true, axis=1)
    s = np.concatenate([rs_map.marker_shape_std[m] for m in ids])
    assert s.shape == err.shape and np.all(s > 0)  # (the anchor too: it is not the gauge)
    assert np.mean(err**2 <= s**2 * chi2.ppf(0.9973, 3)) >= 0.9  # (s: per axis)
    # the frame's uncertainty, common to all markers, is left out
    full = np.concatenate([corner_sigmas(rs_map)[m] for m in ids])
    assert np.median(s) < np.median(full)


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


@pytest.fixture(scope="module")
def bad_input(scene):
    """The video with two faults: marker ``once`` kept in one frame only, and one id printed
    twice (marker ``b``'s detections carry marker ``a``'s id; same size, never seen in the
    same frame)."""
    room, camera, _, frames, _, opts = scene
    seen = views(frames)
    a, b = next(
        (a, b)
        for a in sorted(seen)
        for b in sorted(seen)
        if 0 not in (a, b)
        and a != b
        and room.sides[a] == room.sides[b]
        and min(len(seen[a]), len(seen[b])) >= 5
        and not set(seen[a]) & set(seen[b])
    )
    once = min(
        (k for k in seen if k not in (0, a, b) and len(seen[k]) >= 3), key=lambda k: len(seen[k])
    )
    keep = seen[once][len(seen[once]) // 2]
    bad = []
    for i, f in enumerate(frames):
        c = {k: v for k, v in f.corners.items() if k != once or i == keep}
        if b in c:
            c[a] = c.pop(b)
        bad.append(FrameDetections(f.stamp, c))
    return map_markers(bad, camera, opts), once, a, b


def test_marker_seen_once_is_left_out_and_reported(bad_input):
    res, once, _, _ = bad_input
    assert once not in res.corners
    assert "seen in 1 frame" in res.unmapped[once]


def test_one_id_at_two_places_is_reported_not_averaged(scene, rs_map, bad_input):
    room, *_ = scene
    res, once, a, b = bad_input
    assert a not in res.corners and b not in res.corners
    places = res.inconsistent[a]
    assert len(places) == 2
    # each true place is near one reported place (not their mean)
    for m in (a, b):
        assert min(np.linalg.norm(p - room.p[m]) for p in places) < 0.2
    # the rest of the map is not bent (fewer detections: somewhat less accurate)
    assert set(res.corners) == set(rs_map.corners) - {a, b, once}
    assert np.median(corner_errors(res, room)) < 2 * np.median(corner_errors(rs_map, room))


def test_marker_covariance_is_the_dense_inverse(scene):
    """The markers' block of (J^T J)^-1, found by marginalizing the frames (sparse Schur
    complement), equals the same block of the dense pseudo-inverse."""
    room, camera, _, frames, truth, opts = scene
    obs = {k: f.corners for k, f in enumerate(frames) if f.corners}
    fr = sorted(obs)
    init = SimpleNamespace(
        frames={
            k: (truth["orientation"][k].T, -truth["orientation"][k].T @ truth["position"][k])
            for k in fr
        },
        markers={int(m): (room.R[m], room.p[m]) for m in room.ids},
        stamps={k: frames[k].stamp for k in fr},
    )
    seen = sorted({m for d in obs.values() for m in d} - {0})
    for o in (opts, replace(opts, calibrate_readout=True)):
        prob = MarkerProblem(init, obs, camera, o, fr, seen, 0)
        sol = prob.solve(prob.x0(init, camera.line_delay))
        n_rep = 8 * len(prob.det)
        fast = _marker_covariance(sol.jac, n_rep, 0.4, prob)
        J = sol.jac.toarray()
        J[:n_rep] /= 0.4
        m = slice(prob.moff, prob.moff + 6 * prob.nm)
        dense = np.linalg.pinv(J.T @ J, rcond=1e-12, hermitian=True)[m, m]
        assert fast.shape == dense.shape == (6 * len(seen), 6 * len(seen))
        np.testing.assert_allclose(fast, dense, rtol=0, atol=1e-6 * np.abs(dense).max())


@pytest.fixture(scope="module")
def sweep_scene():
    """The walk opened by 30 frames in front of the anchor."""
    return room_scene(NUM_FRAMES, anchor_frames=30)


@pytest.fixture(scope="module")
def sweep_map(sweep_scene):
    _, camera, _, frames, _, opts = sweep_scene
    return map_markers(frames, camera, opts)


def test_views_of_the_anchor_at_an_angle_fix_the_map(scene, rs_map, sweep_scene, sweep_map):
    """Most of a walk's map error as built is the map turning about the anchor; views of the
    anchor from several directions fix that turn: the map as built is then close to its
    best-fit alignment."""
    room, *_ = scene
    walk_only = map_errors(rs_map, room.corners(), {int(i): room.p[i] for i in room.ids})
    sweep = map_errors(sweep_map, room.corners(), {int(i): room.p[i] for i in room.ids})
    # (the converged adjustment of this seed: 29.7 mm as built, 18.4 after the fit; seeds 1-3
    # of room_scene: 1.3x, 5.3x, 3.9x)
    assert walk_only["median_mm"] > 1.5 * walk_only["aligned_median_mm"]
    assert sweep["median_mm"] < 0.8 * walk_only["median_mm"]
    assert sweep["median_mm"] < 2 * sweep["aligned_median_mm"]
    assert sweep["honest"] >= 0.9
    # the sweep's frames come first, with their own truth
    _, _, _, frames, truth, _ = sweep_scene
    assert len(frames) == len(truth["position"]) == NUM_FRAMES + 30
    k = sweep_map.frame_ids
    assert np.median(np.linalg.norm(sweep_map.position - truth["position"][k], axis=1)) < 0.03


def test_localization_against_the_built_map(sweep_scene, sweep_map):
    """A second video (a robot driving a loop) localized frame by frame against the map as the
    node reads it (written, loaded): close to the same frames against the true map; the
    global-shutter map of the same detections does worse."""
    room, camera, _, frames, _, opts = sweep_scene
    dets, truth = drive_detections(room, camera, num_frames=120)
    # (the frames of three or more markers, the 12 points the default solver's RANSAC needs:
    # fewer coplanar corners are posed by IPPE from the map's corners of one or two markers
    # alone, which is not what this comparison of whole maps is about)
    true = localization_errors(dets, truth, room.corners(), camera, min_markers=3)
    built = localization_errors(dets, truth, map_through_file(sweep_map), camera, min_markers=3)
    gs_map = map_markers(frames, camera, replace(opts, global_shutter=True)).corners
    gs = localization_errors(dets, truth, gs_map, camera, min_markers=3)
    for r in (true, built, gs):
        assert r["solved"] + sum(r["failed"].values()) == r["frames"] > 30
    assert true["solved"] >= 30 and built["solved"] >= 0.9 * true["solved"]
    assert true["rotation_deg"] < 1.0 and true["position_cm"] < 3.0
    assert built["rotation_deg"] < 3 * true["rotation_deg"]
    # (this seed: 5.3 cm against 1.5 cm on the true map; seeds 1-3 of room_scene: 2.3x, 2.0x,
    # 1.6x; the map's own error, within its stated std, is what the drive sees)
    assert built["position_cm"] < 4 * true["position_cm"]
    assert gs["rotation_deg"] > 1.5 * built["rotation_deg"]


def test_an_inward_corner_bias_is_estimated_and_removed():
    """Corners detected 0.25 px inside their squares (as OpenCV's subpixel refinement does on
    blurred images) make every marker look smaller, so further away; the adjustment finds the
    offset (shrunk towards zero by its prior where the views fix it loosely) and the map's shape
    is better than without it, its covariance honest."""
    room, camera, _, frames, _, opts = room_scene(NUM_FRAMES, anchor_frames=30, corner_bias_px=0.25)
    centres = {int(i): room.p[i] for i in room.ids}
    with_offset = map_markers(frames, camera, opts)
    without = map_markers(frames, camera, replace(opts, corner_offset=False))
    assert 0.1 < with_offset.corner_offset_px < 0.35
    assert without.corner_offset_px == 0.0
    e_with = map_errors(with_offset, room.corners(), centres)
    e_without = map_errors(without, room.corners(), centres)
    assert e_with["aligned_median_mm"] < 0.8 * e_without["aligned_median_mm"]
    assert e_with["honest"] >= 0.9
