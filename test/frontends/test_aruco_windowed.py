"""Windowed marker detection of the ArUco front end against full-frame detection and the
renderer's truth."""

import numpy as np
import pytest

from rs_localizer import cv_compat
from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.frontends.aruco import ArucoFrontend, merge_windows, window_share
from rs_localizer.frontends.image import to_gray
from rs_localizer.frontends.marker_detection import apriltag_binding
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
    c = fe.process(f.image, camera, prediction=carry.predict(stamp, camera))
    est = estimate_rs_pose(c.points2d, c.points, camera, "r6p_1lin")
    carry.update(stamp, est)
    return c, est, stamp


def test_windowed_corners_equal_full_frame(video):
    scene, camera, frames = video
    full = ArucoFrontend.from_scene(scene)
    win = ArucoFrontend.from_scene(scene, windowed=True, full_frame_every=0, window_max_share=1.0)
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
    np.testing.assert_allclose(c_w.points2d[i_w], c_f.points2d[i_f], atol=0.05)
    np.testing.assert_array_equal(c_w.points[i_w], c_f.points[i_f])
    # against the exact RS projection of the mapped corners: the accuracy of full frames
    motion = make_motion("shake", scene, duration=len(frames) / FPS + 0.1)
    gt, ok = Renderer(scene, camera, noise=NoiseModel()).project(
        c_w.points, motion, 1 / FPS, occlusion=False
    )
    err = np.linalg.norm(c_w.points2d - gt, axis=1)
    assert ok.all() and np.median(err) < 0.35 and np.percentile(err, 95) < 1.0


def test_fallback_after_loss_and_periodic(video):
    scene, camera, frames = video
    fe = ArucoFrontend.from_scene(scene, windowed=True, full_frame_every=3, window_max_share=1.0)
    carry = CarriedPrediction()
    kinds = []
    for k, f in enumerate(frames[:6]):
        _, est, stamp = _solve(fe, f, camera, carry)
        kinds.append(fe.last_kind)
        # (frame 3: a failed estimate)
        fe.observe(stamp, None, None if k == 3 else est)
    # first frame full; after the failure at frame 3 the next one is full; at least every
    # 3rd frame full; windowed in between
    assert kinds[0] == "full" and kinds[4] == "full"
    assert "windowed" in kinds[1:3]
    assert all("full" in kinds[i : i + 3] for i in range(len(kinds) - 2))
    assert fe.summary()["frontend_frames_global"] == kinds.count("full")
    # a stamp going back (a replayed bag): no prediction
    stamp = int(round(frames[0].t_first * 1e9))
    assert carry.predict(stamp, camera) is None
    fe.process(frames[0].image, camera, prediction=carry.predict(stamp, camera))
    assert fe.last_kind == "full"


def test_pose_accuracy_unchanged_on_video(video):
    scene, camera, frames = video
    res = run_interleaved(
        scene, camera, frames, window_margin_px=16.0, full_frame_every=4, window_max_share=1.0
    )
    full, win = res["full"], res["windowed"]
    assert win["win"].sum() >= 2
    assert np.isfinite(win["rot"]).all() and np.isfinite(full["rot"]).all()
    assert res["corner_diff"] < 0.05
    # poses against the renderer's truth: as accurate as full-frame detection
    assert np.median(win["rot"]) < 1.5 * np.median(full["rot"]) + 0.005
    assert np.median(win["pos"]) < 1.5 * np.median(full["pos"]) + 0.001


def test_markers_not_seen_last_frame_are_searched_where_predicted(video):
    """Markers hidden in the last frame (coming into view) get windows from the map and the
    prediction: the windowed frame finds every marker the full-frame search finds."""
    scene, camera, frames = video
    win = ArucoFrontend.from_scene(scene, windowed=True, full_frame_every=0, window_max_share=1.0)
    full = ArucoFrontend.from_scene(scene)
    carry = CarriedPrediction()
    hidden = frames[0].image.copy()
    hidden[:, hidden.shape[1] // 2 :] = 128  # the right half's markers not seen on frame 0
    stamp = int(round(frames[0].t_first * 1e9))
    c0 = win.process(hidden, camera, prediction=carry.predict(stamp, camera))
    est = estimate_rs_pose(c0.points2d, c0.points, camera, "r6p_1lin")
    assert est.success
    carry.update(stamp, est)
    win.observe(stamp, None, est)
    c_w, _, _ = _solve(win, frames[1], camera, carry)
    c_f = full.process(frames[1].image, camera)
    assert win.last_kind == "windowed"
    new = set((c_f.ids // 4).tolist()) - set((c0.ids // 4).tolist())
    assert len(new) >= 5  # markers the last frame did not see
    assert set(c_w.ids.tolist()) >= set(c_f.ids.tolist())
    _, i_w, i_f = np.intersect1d(c_w.ids, c_f.ids, return_indices=True)
    np.testing.assert_allclose(c_w.points2d[i_w], c_f.points2d[i_f], atol=0.05)


def test_a_marker_missing_where_predicted_keeps_the_windows(video):
    """A marker found in the last frame and hidden in this one, the others found where
    predicted: the next frame is searched in windows again (a full frame would not find the
    hidden one either); with the markers found far from their predicted corners (a wrong
    prediction) the next frame is searched whole."""
    scene, camera, frames = video
    kinds = {}
    for case in ("hidden", "off"):
        fe = ArucoFrontend.from_scene(
            scene, windowed=True, full_frame_every=0, window_max_share=1.0
        )
        carry = CarriedPrediction()
        _, est, stamp = _solve(fe, frames[0], camera, carry)
        fe.observe(stamp, None, est)
        f = frames[1]
        stamp = int(round(f.t_first * 1e9))
        pred = carry.predict(stamp, camera)
        full = ArucoFrontend.from_scene(scene).process(f.image, camera)
        quads = full.points2d.reshape(-1, 4, 2)
        h, w = f.image.shape[:2]
        room = np.minimum(quads.min(axis=1), [w, h] - quads.max(axis=1)).min(axis=1)
        uv = quads[np.argmax(room)]  # the marker furthest inside the image, painted over
        x0, y0 = np.floor(uv.min(axis=0)).astype(int) - 2
        x1, y1 = np.ceil(uv.max(axis=0)).astype(int) + 3
        img = f.image.copy()
        img[y0:y1, x0:x1] = 128
        if case == "off":  # the prediction turned by 11 px: within the windows, off-centre
            a = 11.0 / camera.K[0, 0]
            turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
            pred = pred._replace(R=turn @ pred.R, C=turn @ pred.C)
        c = fe.process(img, camera, prediction=pred)
        assert fe.last_kind == "windowed"
        est = estimate_rs_pose(c.points2d, c.points, camera, "r6p_1lin")
        fe.observe(stamp, None, est)
        carry.update(stamp, est)
        _solve(fe, frames[2], camera, carry)
        kinds[case] = fe.last_kind
    assert kinds == {"hidden": "windowed", "off": "full"}


def test_full_frame_when_windows_cover_most_of_it_or_the_image_is_small(video):
    """The dense ``aruco_room`` at 640x480: the windows of the markers in view cover more
    than half the frame, which is then searched whole; ``windowed_min_pixels`` above the
    image's pixels: searched whole too; either way as many corners as the windows find."""
    scene, camera, frames = video
    fes = {
        "dense": ArucoFrontend.from_scene(scene, windowed=True, full_frame_every=0),
        "small": ArucoFrontend.from_scene(
            scene,
            windowed=True,
            full_frame_every=0,
            window_max_share=1.0,
            windowed_min_pixels=640 * 480 + 1,
        ),
        "windows": ArucoFrontend.from_scene(
            scene, windowed=True, full_frame_every=0, window_max_share=1.0
        ),
    }
    n = {}
    for name, fe in fes.items():
        carry = CarriedPrediction()
        kinds = []
        for f in frames[:3]:
            c, est, stamp = _solve(fe, f, camera, carry)
            fe.observe(stamp, None, est)
            kinds.append(fe.last_kind)
        n[name] = len(c)
        if name == "windows":
            assert kinds[1:] == ["windowed", "windowed"]
            assert window_share(fe.last_windows, f.image.shape) > 0.5
        else:
            assert kinds == ["full"] * 3
    assert n["dense"] == n["small"] and n["windows"] >= 0.95 * n["dense"]


def test_merge_windows():
    # side by side with the same rows: joined; diagonal overlap: kept apart; disjoint: apart
    assert merge_windows([[0, 0, 10, 10], [5, 0, 20, 10]]) == [(0, 0, 20, 10)]
    assert len(merge_windows([[0, 0, 10, 10], [5, 5, 20, 20]])) == 2
    assert len(merge_windows([[0, 0, 10, 10], [30, 30, 40, 40]])) == 2
    assert merge_windows([[0, 0, 10, 10], [2, 2, 8, 8]]) == [(0, 0, 10, 10)]
    # the share of the frame covered, overlaps counted once
    assert window_share([(0, 0, 10, 10), (5, 0, 15, 10)], (20, 20)) == 150 / 400


@pytest.mark.skipif(apriltag_binding() is None, reason="no AprilTag library binding installed")
def test_windowed_search_uses_the_apriltag_library():
    """An AprilTag map: the windows are searched with the AprilTag library (OpenCV's detector
    never runs), with the corners of the full-frame search; the diagnostics name it."""
    # (windows on the library's decimation grid: test_marker_detection.py)
    scene, camera, frames = render_video("vga", 2, scene="apriltag_room")
    full = ArucoFrontend.from_scene(scene)
    win = ArucoFrontend.from_scene(scene, windowed=True, full_frame_every=0, window_max_share=1.0)
    assert win.detector.backend == "apriltag"
    carry = CarriedPrediction()
    _, est, stamp = _solve(win, frames[0], camera, carry)
    win.observe(stamp, None, est)
    called = []
    orig = cv_compat.MarkerDetector.detect
    cv_compat.MarkerDetector.detect = lambda *a: called.append(1) or orig(*a)
    try:
        c_w, _, _ = _solve(win, frames[1], camera, carry)
    finally:
        cv_compat.MarkerDetector.detect = orig
    assert win.last_kind == "windowed" and not called
    c_f = full.process(frames[1].image, camera)
    common, i_w, i_f = np.intersect1d(c_w.ids, c_f.ids, return_indices=True)
    assert len(common) >= 0.9 * len(c_f)
    # most tags found as in the full frame; a few differ by the library's own noise (a tag's
    # quad is fitted to its outline, which in the full frame may run on into the texture)
    diff = np.abs(c_w.points2d[i_w] - c_f.points2d[i_f]).max(axis=1)
    assert np.median(diff) < 1e-3 and np.mean(diff < 0.05) >= 0.9 and diff.max() < 0.2
    s = win.summary()
    assert s["aruco_detector"].startswith("AprilTag 3 library") and s["aruco_frames_windowed"] == 1
    assert "quad_decimate by image size" in s["aruco_detector_settings"]
    assert s["aruco_markers_duplicate"] == 0


def test_an_id_twice_in_one_image_is_dropped_and_counted(video):
    """The same marker at two places of one image (the image beside itself): its id dropped
    from that image and counted, in a full-frame and in a windowed search."""
    scene, camera, frames = video
    fe = ArucoFrontend.from_scene(scene, windowed=True, full_frame_every=0, window_max_share=1.0)
    img = frames[0].image
    twice = np.ascontiguousarray(np.concatenate([img, img[:, :200]], axis=1))
    c1 = fe.process(img, camera)
    c2 = fe.process(twice, camera)
    n = fe.summary()["aruco_markers_duplicate"]
    twin = fe.detector.last_duplicate_ids  # the ids seen in the copy too
    assert n == len(twin) >= 10 and twin <= set(c1.ids // 4) and not twin & set(c2.ids // 4)
    gray = to_gray(twice)
    h, w = img.shape[:2]
    kept = set(c1.ids // 4) & set(c2.ids // 4)
    dropped = set(c1.ids // 4) - kept
    # windows around the whole image and its copy: found in both, so dropped
    _, ids = fe._detect_windows(gray, [(0, 0, w, h), (w, 0, w + 200, h)])
    assert fe.last_duplicates == len(dropped) and not dropped & set(ids.tolist())
