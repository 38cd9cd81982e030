"""Image front ends on rendered frames: ArUco corners and natural-feature matches."""

import numpy as np
import pytest

from rs_localizer.frontends import ArucoFrontend, make_frontend, to_gray
from rs_localizer.maps.markers import write_marker_map
from rs_localizer.sim.render import NoiseModel, Renderer, camera_preset, load_scene, make_motion

T_FRAME = 0.35


@pytest.fixture(scope="module")
def aruco_frame():
    scene = load_scene("aruco_room")
    camera = camera_preset("vga")
    motion = make_motion("shake", scene, duration=2.0)
    r = Renderer(scene, camera, noise=NoiseModel())
    return scene, camera, motion, r, r.render(motion, T_FRAME, rng=1)


def test_aruco_corners_match_ground_truth(aruco_frame):
    scene, camera, motion, r, f = aruco_frame
    fe = ArucoFrontend.from_scene(scene)
    uv, X, ids = fe.process(f.image, camera)
    assert len(uv) >= 200 and uv.shape == (len(ids), 2) and X.shape == (len(ids), 3)
    # ids = 4 * marker id + corner, every corner of a detected marker, 3D from the map
    mids = ids // 4
    assert set(ids % 4) == {0, 1, 2, 3} and len(np.unique(ids)) == len(ids)
    assert all(np.count_nonzero(mids == m) == 4 for m in np.unique(mids))
    corners = scene.marker_corners()
    np.testing.assert_allclose(X, [corners[m][c] for m, c in zip(mids, ids % 4, strict=False)])
    # detected corners vs the exact RS projection of the 3D corners
    gt, ok = r.project(X, motion, T_FRAME, occlusion=False)
    assert ok.all()
    err = np.linalg.norm(uv - gt, axis=1)
    assert np.median(err) < 0.35 and np.percentile(err, 95) < 1.0
    # mono and bgr inputs give the same detections; markers not in the map are ignored
    _uv2, _, ids2 = fe.process(to_gray(f.image), camera)
    np.testing.assert_array_equal(ids2, ids)
    _uv3, _, ids3 = fe.process(np.ascontiguousarray(f.image[:, :, ::-1]), camera, encoding="bgr8")
    np.testing.assert_array_equal(ids3, ids)
    keep = {m: c for m, c in corners.items() if m % 2 == 0}
    _, _, ids4 = ArucoFrontend(keep, scene.dictionary).process(f.image, camera)
    assert len(ids4) > 0 and np.all((ids4 // 4) % 2 == 0)


def test_aruco_groups_are_each_corners_marker(aruco_frame):
    """Each correspondence's group is the marker whose 4 map corners it is one of (the
    estimator's covariance takes a marker's corners to share a shift): 4 rows per group,
    their 3D points that marker's corners; the windowed detection alike."""
    scene, camera, _, _, f = aruco_frame
    corners = scene.marker_corners()
    for fe in (ArucoFrontend.from_scene(scene), ArucoFrontend.from_scene(scene, windowed=True)):
        c = fe.process(f.image, camera)
        g = c.groups
        assert g.dtype == np.int64 and len(g) == len(c) >= 200
        for m in np.unique(g):
            assert np.count_nonzero(g == m) == 4
            np.testing.assert_array_equal(c.points[g == m], corners[int(m)])
    assert ArucoFrontend.from_scene(scene).process(np.full((48, 64), 128, np.uint8)).groups is None


def test_aruco_from_map_file(aruco_frame, tmp_path):
    scene, camera, _, _, f = aruco_frame
    write_marker_map(
        tmp_path / "markers.yaml", scene.dictionary, scene.marker_corners(), scene=scene.name
    )
    a = make_frontend("aruco", tmp_path / "markers.yaml").process(f.image, camera)
    b = make_frontend("aruco", "aruco_room").process(f.image, camera)
    np.testing.assert_array_equal(a[2], b[2])
    np.testing.assert_allclose(a[1], b[1], atol=1e-6)
    with pytest.raises(ValueError):
        make_frontend("sonar", "x")
    empty = make_frontend("aruco", "aruco_room").process(np.full((48, 64), 128, np.uint8))
    assert empty[0].shape == (0, 2) and empty[1].shape == (0, 3) and empty[2].shape == (0,)


def test_to_gray_takes_the_channel_order_from_the_encoding():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (6, 5, 3), dtype=np.uint8)
    bgr = rgb[:, :, ::-1]
    np.testing.assert_array_equal(to_gray(bgr, "bgr8"), to_gray(rgb, "rgb8"))
    gray = to_gray(rgb, "rgb8")  # (ITU-R BT.601 luma, as OpenCV computes it)
    luma = rgb.astype(float) @ np.array([0.299, 0.587, 0.114])
    assert np.abs(gray.astype(float) - luma).max() <= 1.0


def test_feature_matches_mostly_correct(tmp_path):
    """Paper protocol: map from global-shutter renders with known depth, RS frame matched to
    it with the ratio test; the matched 3D points project (exact RS model) onto the matched
    pixels."""
    from rs_localizer.frontends.features import FeatureFrontend
    from rs_localizer.maps.features import FeatureMap
    from rs_localizer.sim.feature_map import build_feature_map

    scene = load_scene("textured_room")
    camera = camera_preset("vga")
    motion = make_motion("shake", scene, duration=2.0)
    fmap = build_feature_map(
        scene, camera, (motion, np.linspace(0.0, 2.0, 6)), kind="orb", n_features=1500
    )
    assert fmap.num_landmarks > 1000 and np.isfinite(fmap.points).all()
    path = fmap.save(tmp_path / "map.npz")
    fm2 = FeatureMap.load(path)
    np.testing.assert_array_equal(fm2.descriptors, fmap.descriptors)
    r = Renderer(scene, camera, noise=NoiseModel())
    f = r.render(motion, 0.8, rng=3)
    fe = FeatureFrontend(fm2)
    uv, X, ids = fe.process(f.image, camera)
    assert len(uv) >= 200 and len(np.unique(ids)) == len(ids)
    assert len(fe.last_scores) == len(uv)
    gt, ok = r.project(X, motion, 0.8, occlusion=True)
    err = np.where(ok, np.linalg.norm(uv - np.nan_to_num(gt), axis=1), np.inf)
    assert np.mean(err < 3.0) > 0.85
    assert np.median(err[err < 3.0]) < 1.0
    with pytest.raises(ValueError):
        FeatureMap.load(_bad_npz(tmp_path))


def _bad_npz(tmp_path):
    p = tmp_path / "bad.npz"
    np.savez(p, foo=np.zeros(3))
    return p
