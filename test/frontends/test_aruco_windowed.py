"""Windowed marker detection of the ArUco front end against full-frame detection and the
renderer's truth."""

import numpy as np
import pytest

from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.frontends.aruco import ArucoFrontend, merge_windows
from rs_localizer.sim.aruco_video import FPS, render_video, run_interleaved
from rs_localizer.sim.render import NoiseModel, Renderer, make_motion
from rs_localizer.tracking.tracker import CarriedPrediction


@pytest.fixture(scope="module")
def video():
    return render_video("vga", 8)


def _solve(fe, f, camera, carry):
    """One frame searched from ``carry``'s prediction (the last solved frame carried to the
    stamp), the prediction then given the frame's estimate."""
    stamp = int(round(f.t_first * 1e9))
    c = fe.process(f.image, camera, stamp_ns=stamp, prediction=carry.predict(stamp, camera))
    est = estimate_rs_pose(c.pixels, c.points, camera, "r6p_1lin")
    carry.update(stamp, est)
    return c, est, stamp


def test_windowed_corners_equal_full_frame(video):
    scene, camera, frames = video
    full = ArucoFrontend.from_scene(scene)
    win = ArucoFrontend.from_scene(scene, windowed=True, full_frame_every=0)
    carry = CarriedPrediction()
    _, est, stamp = _solve(win, frames[0], camera, carry)
    assert win.last_kind == "full" and est.success  # no prediction on the first frame
    win.observe(stamp, None, est)
    f = frames[1]
    c_w, _, _ = _solve(win, f, camera, carry)
    assert win.last_kind == "windowed" and len(win.last_windows) > 1
    h, w = f.image.shape[:2]
    assert all(0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h for x0, y0, x1, y1 in win.last_windows)
    c_f = full.process(f.image, camera)
    common, i_w, i_f = np.intersect1d(c_w.ids, c_f.ids, return_indices=True)
    assert len(common) >= 0.9 * len(c_f)
    np.testing.assert_allclose(c_w.pixels[i_w], c_f.pixels[i_f], atol=0.05)
    np.testing.assert_array_equal(c_w.points[i_w], c_f.points[i_f])
    # against the exact RS projection of the mapped corners: the accuracy of full frames
    motion = make_motion("shake", scene, duration=len(frames) / FPS + 0.1)
    gt, ok = Renderer(scene, camera, noise=NoiseModel()).project(
        c_w.points, motion, 1 / FPS, occlusion=False
    )
    err = np.linalg.norm(c_w.pixels - gt, axis=1)
    assert ok.all() and np.median(err) < 0.35 and np.percentile(err, 95) < 1.0


def test_fallback_after_loss_and_periodic(video):
    scene, camera, frames = video
    fe = ArucoFrontend.from_scene(scene, windowed=True, full_frame_every=3)
    carry = CarriedPrediction()
    kinds = []
    for k, f in enumerate(frames[:6]):
        _, est, stamp = _solve(fe, f, camera, carry)
        kinds.append(fe.last_kind)
        fe.observe(stamp, None, None if k == 3 else est)  # frame 3: a failed estimate
    # first frame full; after the failure at frame 3 the next one is full; at least every
    # 3rd frame full; windowed in between
    assert kinds[0] == "full" and kinds[4] == "full"
    assert "windowed" in kinds[1:3]
    assert all("full" in kinds[i : i + 3] for i in range(len(kinds) - 2))
    assert fe.summary()["frontend_frames_global"] == kinds.count("full")
    # a stamp going back (a replayed bag): no prediction
    stamp = int(round(frames[0].t_first * 1e9))
    assert carry.predict(stamp, camera) is None
    fe.process(frames[0].image, camera, stamp_ns=stamp, prediction=carry.predict(stamp, camera))
    assert fe.last_kind == "full"


def test_pose_accuracy_unchanged_on_video(video):
    scene, camera, frames = video
    res = run_interleaved(scene, camera, frames, window_margin_px=16.0, full_frame_every=4)
    full, win = res["full"], res["windowed"]
    assert win["win"].sum() >= 2
    assert np.isfinite(win["rot"]).all() and np.isfinite(full["rot"]).all()
    assert res["corner_diff"] < 0.05
    # poses against the renderer's truth: as accurate as full-frame detection
    assert np.median(win["rot"]) < 1.5 * np.median(full["rot"]) + 0.005
    assert np.median(win["pos"]) < 1.5 * np.median(full["pos"]) + 0.001


def test_merge_windows():
    # side by side with the same rows: joined; diagonal overlap: kept apart; disjoint: apart
    assert merge_windows([[0, 0, 10, 10], [5, 0, 20, 10]]) == [(0, 0, 20, 10)]
    assert len(merge_windows([[0, 0, 10, 10], [5, 5, 20, 20]])) == 2
    assert len(merge_windows([[0, 0, 10, 10], [30, 30, 40, 40]])) == 2
    assert merge_windows([[0, 0, 10, 10], [2, 2, 8, 8]]) == [(0, 0, 10, 10)]
